"""Compile work linear in the model's size (issue 27), counted, never timed; and the linear
CSE (bgc.lower.cse) against the pairwise one and against substitution.

The work is the number of Python function calls a compile makes (cProfile's count: it does
not depend on the machine's load) and the expression nodes the linear CSE visits. For three
sizes n, 2n, 4n of one family the increments must grow as the size does: a quadratic piece
would make the second increment four times the first, a linear one twice."""
from __future__ import annotations

import cProfile
import itertools
import pstats
import random
from pathlib import Path

import numpy as np
import pytest
import sympy as sp

from bgc.backends.load import load_module
from bgc.format.parse import parse_file
from bgc.lower import cse as lcse
from bgc.run.driver import compile_model

ROOT = Path(__file__).resolve().parent.parent


def ladder(n: int) -> str:
    """An n-node RC ladder, written here (not bgc's): source, then R and C per node."""
    els = ['  src: {type: Se, effort: "V0 * sin(w * t)"}']
    bonds = []
    for i in range(n):
        left = "src" if i == 0 else f"n{i - 1}"
        els += [f'  s{i}: {{type: "1"}}', f"  r{i}: {{type: R, resistance: R}}",
                f'  n{i}: {{type: "0"}}', f"  c{i}: {{type: C, compliance: C}}"]
        bonds += [f"  - [{left}, s{i}]", f"  - [s{i}, r{i}]", f"  - [s{i}, n{i}]",
                  f"  - [n{i}, c{i}]"]
    return "\n".join(["bgc: 1", f"name: ladder{n}", "parameters:",
                      "  R: {value: 1.0, unit: Ohm}", "  C: {value: 0.01, unit: F}",
                      "  V0: {value: 1.0, unit: V}", "  w: {value: 6.0, unit: 1/s}",
                      "elements:"] + els + ["bonds:"] + bonds + ["outputs:", f'  v_end: {{expr: "e(c{n - 1})", unit: V}}']) + "\n"


def link_chain(n: int) -> str:
    """n spatial links of the 3R2S (its `link` and `tcoupling` components) end to end."""
    import yaml

    base = yaml.safe_load((ROOT / "tests" / "data" / "3r2s_before_library.yaml").read_text())
    el = {"ground": {"type": "Sf", "flow": "[0, 0, 0]"},
          "tip": {"type": "Se", "effort": "[0, 0, 0]"}}
    bonds = []
    for i in range(n):
        el[f"l{i}"] = {"type": "link", "m": 0.5, "l": "d", "rC0": f"[{i + 0.5} * d, 0, 0]"}
        el[f"j{i}"] = {"type": "tcoupling", "k": 1.0e6, "r": 10.0}
        bonds += [{"from": "ground" if i == 0 else f"l{i - 1}.P", "to": f"j{i}.a", "n": 3},
                  {"from": f"j{i}.b", "to": f"l{i}.Q", "n": 3}]
    bonds.append({"from": "tip", "to": f"l{n - 1}.P", "n": 3})
    return yaml.safe_dump({
        "bgc": 1, "name": f"links{n}", "parameters": {"d": {"value": 0.05, "unit": "m"}},
        "components": {k: base["components"][k] for k in ("link", "tcoupling")},
        "elements": el, "bonds": bonds, "outputs": {"v_tip": f"f(l{n - 1}.P)"}},
        sort_keys=False)


def _work(path: Path) -> tuple[int, int]:
    """(Python calls, CSE nodes) of one compile from a cold sympy cache."""
    sp.core.cache.clear_cache()
    lcse.stats["nodes"] = 0
    prof = cProfile.Profile()
    prof.enable()
    compile_model(parse_file(path))
    prof.disable()
    calls = sum(v[1] for v in pstats.Stats(prof).stats.values())
    return calls, lcse.stats["nodes"]


def _increments_linear(tmp_path, make, sizes, monkeypatch):
    monkeypatch.setattr(lcse, "LINEAR_ABOVE", 0)  # every body through the counted pass
    work = []
    for n in sizes:
        p = tmp_path / f"m{n}.yaml"
        p.write_text(make(n))
        if not work:
            _work(p)  # once first: what a process does once (imports, templates) is not size
        work.append(_work(p))
    for k in range(2):  # calls, nodes
        d1 = work[1][k] - work[0][k]
        d2 = work[2][k] - work[1][k]
        assert d1 > 0
        assert d2 <= 2.2 * d1, (k, work)  # linear: 2; quadratic: 4


def test_ladder_compile_work_is_linear(tmp_path, monkeypatch):
    _increments_linear(tmp_path, ladder, (20, 40, 80), monkeypatch)


@pytest.mark.slow
def test_link_chain_compile_work_is_linear(tmp_path, monkeypatch):
    _increments_linear(tmp_path, link_chain, (1, 2, 4), monkeypatch)


def _random_exprs(rng: random.Random, k: int) -> list:
    xs = sp.symbols("a b c d e", real=True)
    pool = list(xs)
    for _ in range(40):  # shared subtrees: built from the pool, reused by later ones
        a, b = rng.choice(pool), rng.choice(pool)
        op = rng.choice([lambda u, v: u + v, lambda u, v: u * v, lambda u, v: sp.sin(u) - v,
                         lambda u, v: u / (1 + v ** 2), lambda u, v: sp.exp(u / 7) * v])
        pool.append(op(a, b))
    return [rng.choice(pool[5:]) + rng.choice(pool) for _ in range(k)], xs


@pytest.mark.parametrize("seed", range(5))
def test_linear_cse_means_the_same(seed):
    rng = random.Random(seed)
    exprs, xs = _random_exprs(rng, 12)
    names = (sp.Symbol(f"_t{i}", real=True) for i in itertools.count())
    repl, reduced = lcse.linear_cse(exprs, lambda: next(names))
    # back-substitution (sympy's xreplace, in reverse order of definition) gives the originals
    back = dict(repl)
    for s, _ in reversed(repl):
        back = {k: v.xreplace({s: back[s]}) for k, v in back.items()}
    pt = {x: rng.uniform(0.5, 1.5) for x in xs}
    for e, r in zip(exprs, reduced):
        full = r.xreplace(back)
        assert full.free_symbols <= set(xs)
        assert abs(complex(full.evalf(subs=pt)) - complex(e.evalf(subs=pt))) < 1e-12 * (
            1 + abs(complex(e.evalf(subs=pt))))
    # each temporary defined once, each used at least twice (else it would not be one)
    assert len({e for _, e in repl}) == len(repl)
    uses = {s: 0 for s, _ in repl}
    for e in [e for _, e in repl] + reduced:
        for node in sp.preorder_traversal(e):
            if node in uses:
                uses[node] += 1
    assert all(u >= 2 for u in uses.values()), uses


def test_linear_cse_module_equals_pairwise(tmp_path, monkeypatch):
    """A link chain's module through the linear CSE against symengine's: same rhs, Jacobian
    and outputs at random points (1e-12)."""
    p = tmp_path / "links2.yaml"
    p.write_text(link_chain(2))
    pair = compile_model(parse_file(p))
    monkeypatch.setattr(lcse, "LINEAR_ABOVE", 0)
    lin = compile_model(parse_file(p))
    assert lin.source != pair.source  # (the test compares two different modules)
    a, b = load_module(pair.source, "links2_pair"), load_module(lin.source, "links2_lin")
    rng = np.random.default_rng(3)
    x0 = np.asarray(a.X0, dtype=float)
    for _ in range(4):
        x = x0 + 0.05 * np.maximum(np.abs(x0), 0.1) * rng.standard_normal(x0.shape)
        t = float(rng.uniform(0, 1))
        for f in ("rhs", "jacobian"):
            ra, rb = getattr(a, f)(t, x), getattr(b, f)(t, x)
            np.testing.assert_allclose(rb, ra, rtol=1e-12, atol=1e-12 * (1 + np.abs(ra).max()))
        oa, ob = a.outputs(t, x), b.outputs(t, x)
        for k in oa:
            np.testing.assert_allclose(ob[k], oa[k], rtol=1e-12, atol=1e-12)


def test_survey_tells_binary_bodies():
    a, b, c = sp.symbols("a b c", real=True)
    assert lcse.survey([a / b - c, -2 * a, a ** 2 + b, sp.sin(a) - b / c], 100) == (17, True)
    assert not lcse.survey([a * b * c], 100)[1]  # a product of three: pairwise pays
    assert not lcse.survey([a - b, sp.cos(a + b + c)], 100)[1]


def test_large_ladder_takes_the_linear_pass_and_means_the_ladder(tmp_path, monkeypatch):
    """A 400-node ladder's rhs and Jacobian bodies (over BINARY_ABOVE nodes of sums and
    quotients of two operands) go through the linear CSE; the module's rhs and Jacobian are the
    ladder's, written here from Kirchhoff's laws (q_i' = (v_(i-1) - v_i)/R - (v_i -
    v_(i+1))/R, v_i = q_i/C, v_(-1) = V0 sin(w t), nothing beyond the last node)."""
    n, R, C, V0, w = 400, 1.0, 0.01, 1.0, 6.0
    p = tmp_path / "ladder.yaml"
    p.write_text(ladder(n))
    seen = []
    real = lcse.linear_cse
    monkeypatch.setattr(lcse, "linear_cse", lambda e, m: seen.append(len(e)) or real(e, m))
    c = compile_model(parse_file(p))
    assert len(seen) >= 2  # rhs and Jacobian
    mod = load_module(c.source, "ladder_linear_pass")
    rng = np.random.default_rng(5)
    x, t = rng.standard_normal(n), 0.37
    v = x / C
    left = np.concatenate(([V0 * np.sin(w * t)], v[:-1]))
    right = np.concatenate((v[1:], [np.nan]))
    want = (left - v) / R - np.where(np.arange(n) < n - 1, (v - np.nan_to_num(right)) / R, 0)
    np.testing.assert_allclose(mod.rhs(t, x), want, rtol=1e-12, atol=1e-9)
    J = np.zeros((n, n))
    for i in range(n):
        J[i, i] = -(2.0 if i < n - 1 else 1.0) / (R * C)
        if i > 0:
            J[i, i - 1] = 1 / (R * C)
        if i < n - 1:
            J[i, i + 1] = 1 / (R * C)
    np.testing.assert_allclose(np.asarray(mod.jacobian(t, x)), J, rtol=1e-12)
