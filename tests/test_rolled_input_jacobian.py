"""The vectorised (re-rolled) input Jacobian of the numpy module: the linearisation's B
printed over the runs of a model of repeated structure (bgc.backends.numpy.rolled, kind
"ujac"), and ``linearize`` that returns it.

The model: an RC ladder fed at every node. Node i holds a capacitor C_i (state: its charge
q_i, voltage v_i = q_i / C_i), is fed by its own source u_i (an input) through its own
resistor Rs_i, and is joined to node i-1 by a resistor R. By hand (Kirchhoff at node i):

    dq_i/dt = (u_i - v_i) / Rs_i + [i > 0] (v_{i-1} - v_i) / R - [i < n-1] (v_i - v_{i+1}) / R

so B = diag(1 / Rs_i), and A is tridiagonal: A_ii = -1/(Rs_i C_i) - k_i/(R C_i) (k_i the
number of neighbours), A_i,i±1 = 1/(R C_i±1). The outputs v_i (C = diag(1/C_i), D = 0) and
the source currents is_i = (u_i - v_i) / Rs_i (C = diag(-1/(Rs_i C_i)), D = diag(1/Rs_i)).
These closed forms, central differences of the module's rhs in each u_i, and the same module
printed line by line (re-rolling off) are the answers the rolled B is held to.
"""
from __future__ import annotations

import functools
import tempfile
from pathlib import Path

import numpy as np
import pytest

from bgc.backends.load import load_module
from bgc.format.parse import parse_file
from bgc.lower import reroll as rr
from bgc.run.driver import compile_model

N = 30
R, V0, W = 1.0, 1.0, 6.0


def _rs(i: int) -> float:
    return 1.0 + 0.1 * i


def _cap(i: int) -> float:
    return 0.01 / (1.0 + 0.05 * i)


def fed_ladder(n: int, own: bool, reverse: bool = False) -> str:
    """The ladder fed at every node; ``own``: every node its own Rs_i and C_i (parameters
    gathered per instance), else one Rs and one C for all; ``reverse``: the inputs declared
    last node first (B's columns then run against its rows: u_i is column n-1-i)."""
    par = [f"  R: {{value: {R}, unit: Ohm}}", f"  V0: {{value: {V0}, unit: V}}",
           f"  w: {{value: {W}, unit: 1/s}}"]
    if not own:
        par += [f"  Rs: {{value: {_rs(0)}, unit: Ohm}}", f"  C: {{value: {_cap(0)}, unit: F}}"]
    inputs, els, bonds, outs = [], [], [], []
    for i in range(n):
        rs, c = (f"Rs{i}", f"C{i}") if own else ("Rs", "C")
        if own:
            par += [f"  Rs{i}: {{value: {_rs(i)}, unit: Ohm}}",
                    f"  C{i}: {{value: {_cap(i)}, unit: F}}"]
        inputs.append(f'  u{i}: {{default: "V0 * sin(w * t + {i})", unit: V}}')
        els += [f'  n{i}: {{type: "0"}}', f"  c{i}: {{type: C, compliance: {c}}}",
                f'  f{i}: {{type: "1"}}', f"  src{i}: {{type: Se, effort: u{i}}}",
                f"  rs{i}: {{type: R, resistance: {rs}}}"]
        bonds += [f"  - [src{i}, f{i}]", f"  - [f{i}, rs{i}]", f"  - [f{i}, n{i}]",
                  f"  - [n{i}, c{i}]"]
        outs += [f'  v{i}: {{expr: "e(c{i})", unit: V}}',
                 f'  is{i}: {{expr: "f(rs{i})", unit: A}}']
        if i:
            els += [f'  s{i}: {{type: "1"}}', f"  r{i}: {{type: R, resistance: R}}"]
            bonds += [f"  - [n{i - 1}, s{i}]", f"  - [s{i}, r{i}]", f"  - [s{i}, n{i}]"]
    return "\n".join(["bgc: 1", f"name: fed_ladder{n}{'_own' if own else ''}", "parameters:"]
                     + par + ["inputs:"] + (inputs[::-1] if reverse else inputs)
                     + ["elements:"] + els + ["bonds:"] + bonds + ["outputs:"] + outs) + "\n"


def closed_form(n: int, rs, cap, reverse: bool = False):
    """(A, B, C, D) by hand (the module's docstring), rows of C and D as v0..v_n-1 then
    is0..is_n-1, columns of B and D in the inputs' order; rs and cap: arrays (n,) of the
    nodes' Rs_i and C_i."""
    A = np.zeros((n, n))
    for i in range(n):
        A[i, i] = -1 / (rs[i] * cap[i]) - ((i > 0) + (i < n - 1)) / (R * cap[i])
        if i:
            A[i, i - 1] = 1 / (R * cap[i - 1])
        if i < n - 1:
            A[i, i + 1] = 1 / (R * cap[i + 1])
    B = np.diag(1 / rs)
    C = np.vstack([np.diag(1 / cap), np.diag(-1 / (rs * cap))])
    D = np.vstack([np.zeros((n, n)), np.diag(1 / rs)])
    if reverse:
        B, D = B[:, ::-1], D[:, ::-1]
    return A, B, C, D


#: the cases: (own Rs_i and C_i, inputs declared in reverse)
CASES = [(True, True), (True, False), (False, False)]


@functools.cache
def _modules(own: bool, reverse: bool):
    """(rolled, flat) numpy modules of one compile: printed at the defaults (MIN_RUN,
    MIN_COVER) with B vectorised, and again with re-rolling off."""
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "fed.yaml"
        p.write_text(fed_ladder(N, own, reverse))
        comp = compile_model(parse_file(p))
    text = comp.printer(True, True)
    ujac = text[text.index("\ndef input_jacobian("):text.index("\ndef output_jacobian(")]
    assert "_Bv = np.empty" in ujac and "_B[_IX[" in ujac  # the rolled B path is taken
    if own:
        assert "_pa[" in ujac  # the Rs_i gathered per instance
    saved = rr.MIN_RUN
    rr.MIN_RUN = 10 ** 9
    try:
        flat_text = comp.printer(True, True)
    finally:
        rr.MIN_RUN = saved
    assert "_Bv" not in flat_text
    name = f"{comp.model.name}_{int(reverse)}"
    return load_module(text, f"{name}_rolled"), load_module(flat_text, f"{name}_flat")


def _nodes(own: bool, p=None):
    rs = np.array([_rs(i) if own else _rs(0) for i in range(N)])
    cap = np.array([_cap(i) if own else _cap(0) for i in range(N)])
    for k, v in (p or {}).items():
        if k.startswith("Rs"):
            rs[int(k[2:]) if own else slice(None)] = v
        elif k.startswith("C"):
            cap[int(k[1:]) if own else slice(None)] = v
    return rs, cap


def _rows(mod) -> list[int]:
    labels = list(mod.OUTPUT_LABELS)
    return [labels.index(f"v{i}") for i in range(N)] + [labels.index(f"is{i}") for i in range(N)]


@pytest.mark.parametrize("own, reverse", CASES)
def test_rolled_b_is_the_closed_form_and_the_unrolled_b(own, reverse):
    rolled, flat = _modules(own, reverse)
    order = [f"u{i}" for i in range(N)]
    assert list(rolled.INPUT_LABELS) == (order[::-1] if reverse else order)
    rng = np.random.default_rng(4)
    x = 1e-3 * rng.standard_normal(N)
    t = 0.37
    rs, cap = _nodes(own)
    A0, B0, C0, D0 = closed_form(N, rs, cap, reverse)
    B = rolled.input_jacobian(t, x)
    assert B.shape == (N, N)
    np.testing.assert_allclose(B, B0, rtol=1e-14, atol=0)
    np.testing.assert_array_equal(B, flat.input_jacobian(t, x))
    # linearize: all four against the closed forms
    A, B2, C, D = rolled.linearize(t, x)
    np.testing.assert_array_equal(B2, B)
    np.testing.assert_allclose(A, A0, rtol=1e-13, atol=1e-13 * np.abs(A0).max())
    rows = _rows(rolled)
    np.testing.assert_allclose(C[rows], C0, rtol=1e-13, atol=0)
    np.testing.assert_allclose(D[rows], D0, rtol=1e-14, atol=0)
    for got, want in zip(rolled.linearize(t, x), flat.linearize(t, x)):
        np.testing.assert_allclose(got, want, rtol=1e-14, atol=0)


@pytest.mark.parametrize("own, reverse", CASES)
def test_rolled_b_is_the_rhs_central_difference_in_each_input(own, reverse):
    """The rhs is linear in u: a central difference of the module's own rhs in u_j (the
    inputs held at values) is column j of B to rounding."""
    rolled, _ = _modules(own, reverse)
    rng = np.random.default_rng(9)
    x, t = 1e-3 * rng.standard_normal(N), 0.81
    u0 = rng.uniform(-1, 1, N)
    h = 1e-3

    def rhs(u):
        return rolled.rhs(t, x, None, {name: (lambda _t, v=u[j]: v)
                                       for j, name in enumerate(rolled.INPUT_LABELS)})
    fd = np.empty((N, N))
    for j in range(N):
        e = np.zeros(N)
        e[j] = h
        fd[:, j] = (rhs(u0 + e) - rhs(u0 - e)) / (2 * h)
    B = rolled.input_jacobian(t, x)
    np.testing.assert_allclose(B, fd, rtol=1e-9, atol=1e-9 * np.abs(B).max())


@pytest.mark.parametrize("own, reverse", CASES)
def test_rolled_b_over_batches_of_states_and_parameters(own, reverse):
    """A batch of states, a batch of parameters (of the gathered Rs_i, or the shared Rs),
    and both: B per instance is the closed form of that instance, and the unrolled B."""
    rolled, flat = _modules(own, reverse)
    rng = np.random.default_rng(12)
    names = ("Rs3", "C7") if own else ("Rs", "C")
    p = {names[0]: np.array([0.5, 2.0, 4.0]), names[1]: np.array([0.02, 0.01, 0.005])}
    for xs, pp in (((3,), None), ((), p), ((3,), p), ((2, 3), p)):
        x = 1e-3 * rng.standard_normal((N,) + xs)
        B = rolled.input_jacobian(0.5, x, pp)
        want_shape = (N, N) + np.broadcast_shapes(xs, (3,) if pp else ())
        assert B.shape == want_shape
        np.testing.assert_array_equal(B, flat.input_jacobian(0.5, x, pp))
        for k in range(3):
            inst = {n: v[k] for n, v in pp.items()} if pp else None
            rs, _ = _nodes(own, inst)
            Bk = B[(slice(None), slice(None)) + ((0,) if len(xs) == 2 else ()) + (k,)]
            want = np.diag(1 / rs)
            np.testing.assert_allclose(Bk, want[:, ::-1] if reverse else want, rtol=1e-14,
                                       atol=0)
