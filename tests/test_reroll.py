"""Loop re-rolling (bgc.lower.reroll, issue 27): repeated structure printed as C loops.

The answers come from outside the pass: the unrolled C module (the pass switched off), the
ladder's node equations written here by hand, and the original lowered lines themselves
(a rolled function, expanded iteration by iteration, must give back every line in its order).
"""
from __future__ import annotations

import math
import re
import sys
from pathlib import Path

import numpy as np
import pytest
import sympy as sp

from bgc.backends.c import build as cbuild
from bgc.backends.c.parts import PartContext
from bgc.backends.load import c_files, load_c
from bgc.format.parse import parse_file
from bgc.lower import reroll as rr
from bgc.lower.ir import Line
from bgc.run.driver import compile_model

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_compile_scale import link_chain  # noqa: E402  (the 3-D link chain, 3R2S links)

ROOT = Path(__file__).resolve().parent.parent
HAVE_CC = cbuild.available() and bool(cbuild.runtime_sources())
R, C, V0, W = 1.0, 0.01, 1.0, 6.0


def ladder(n: int, mixed: bool = False) -> str:
    """An n-node RC ladder. ``mixed``: every section its own R_i and C_i, and every third
    node a leak resistor to ground (two kinds of instances, interleaved)."""
    par = [f"  R: {{value: {R}, unit: Ohm}}", f"  C: {{value: {C}, unit: F}}",
           f"  V0: {{value: {V0}, unit: V}}", f"  w: {{value: {W}, unit: 1/s}}"]
    els = ['  src: {type: Se, effort: "V0 * sin(w * t)"}']
    bonds = []
    for i in range(n):
        left = "src" if i == 0 else f"n{i - 1}"
        r, c = (f"R{i}", f"C{i}") if mixed else ("R", "C")
        if mixed:
            par += [f"  R{i}: {{value: {_r(i)}, unit: Ohm}}",
                    f"  C{i}: {{value: {_c(i)}, unit: F}}"]
        els += [f'  s{i}: {{type: "1"}}', f"  r{i}: {{type: R, resistance: {r}}}",
                f'  n{i}: {{type: "0"}}', f"  c{i}: {{type: C, compliance: {c}}}"]
        bonds += [f"  - [{left}, s{i}]", f"  - [s{i}, r{i}]", f"  - [s{i}, n{i}]",
                  f"  - [n{i}, c{i}]"]
        if mixed and i % 3 == 2:
            els.append(f"  g{i}: {{type: R, resistance: R}}")
            bonds.append(f"  - [n{i}, g{i}]")
    return "\n".join(["bgc: 1", f"name: ladder{n}{'m' if mixed else ''}", "parameters:"]
                     + par + ["elements:"] + els + ["bonds:"] + bonds
                     + ["outputs:", f'  v_end: {{expr: "e(c{n - 1})", unit: V}}']) + "\n"


def _r(i):
    return 1.0 / (i + 1)


def _c(i):
    return 0.01 / (1 + 0.1 * i)


def ladder_rhs(t, q, mixed=False):
    """The ladder's node equations, by hand: dq_i/dt = i_in - i_out (- v_i/R at a leak)."""
    n = len(q)
    cs = np.array([_c(i) for i in range(n)]) if mixed else np.full(n, C)
    rs = np.array([_r(i) for i in range(n)]) if mixed else np.full(n, R)
    v = q / cs
    left = np.concatenate(([V0 * math.sin(W * t)], v[:-1]))
    i_in = (left - v) / rs
    i_out = np.concatenate((i_in[1:], [0.0]))
    dq = i_in - i_out
    if mixed:
        leak = np.arange(n) % 3 == 2
        dq[leak] -= v[leak] / R
    return dq


def _compiled(tmp_path, text: str):
    p = tmp_path / "m.yaml"
    p.write_text(text)
    return compile_model(parse_file(p))


def _pair(compiled, monkeypatch, min_run: int):
    """(rolled, unrolled) C modules of one compiled model."""
    monkeypatch.setattr(rr, "MIN_RUN", min_run)
    files, wrapper = c_files(compiled)
    name = compiled.model.name
    rolled = load_c(files, wrapper, f"{name}_rolled")
    assert any("for (int bgc_i" in t for f, t in files.items())  # (it did roll)
    monkeypatch.setattr(rr, "MIN_RUN", 10 ** 9)
    files, wrapper = c_files(compiled)
    assert not any("for (int bgc_i" in t for f, t in files.items())
    return rolled, load_c(files, wrapper, f"{name}_flat")


def _same(a, b, x0, seed=5, rounds=4):
    """rhs and Jacobian of a and b at random points: equal to 1e-13 relative."""
    rng = np.random.default_rng(seed)
    for _ in range(rounds):
        x = x0 + 0.1 * np.maximum(np.abs(x0), 0.1) * rng.standard_normal(x0.shape)
        t = float(rng.uniform(0, 2))
        for f in ("rhs", "jacobian"):
            ra, rb = np.asarray(getattr(a, f)(t, x)), np.asarray(getattr(b, f)(t, x))
            np.testing.assert_allclose(ra, rb, rtol=1e-13, atol=1e-13 * np.abs(rb).max())


@pytest.mark.skipif(not HAVE_CC, reason="no C compiler")
@pytest.mark.parametrize("mixed", [False, True])
def test_ladder_rolled_equals_unrolled_and_hand_written(tmp_path, monkeypatch, mixed):
    n = 30
    comp = _compiled(tmp_path, ladder(n, mixed))
    rolled, flat = _pair(comp, monkeypatch, 4 if mixed else rr.MIN_RUN)
    x0 = np.zeros(n)
    _same(rolled, flat, x0)
    rng = np.random.default_rng(2)
    for _ in range(3):
        q = 0.01 * rng.standard_normal(n)
        t = float(rng.uniform(0, 2))
        ref = ladder_rhs(t, q, mixed)
        np.testing.assert_allclose(rolled.rhs(t, q), ref, rtol=1e-12,
                                   atol=1e-12 * np.abs(ref).max())


@pytest.mark.slow
@pytest.mark.skipif(not HAVE_CC, reason="no C compiler")
def test_link_chain_rolled_equals_unrolled(tmp_path, monkeypatch):
    """Four 3-D links: with runs of three (the vectors' x, y, z) and four (the links)
    rolled, against the unrolled module."""
    comp = _compiled(tmp_path, link_chain(4))
    rolled, flat = _pair(comp, monkeypatch, 3)
    _same(rolled, flat, np.asarray(flat.X0, dtype=float), rounds=3)


def _expanded(roll: rr.Rolled, states, params) -> list:
    """The rolled body run out again: (target or ("out", k), expression) per line, in the
    order the loops execute them, with every read replaced by what it reads."""
    slot_of = {k: s for s, k in roll.values.items()}
    arrays = {"x": list(states), "p": list(params)}

    def at(ix, i):
        return ix.table[i] if ix.table else ix.start + ix.stride * i
    out = []
    for it in roll.items:
        if isinstance(it, Line):
            out.append((it.target, it.expr))
        elif isinstance(it, rr.Result):
            out.append((("out", it.key), it.expr))
        else:
            for i in range(it.count):
                for st in it.body:
                    sub = {r.name: (slot_of if r.array == "v" else arrays[r.array])[
                        at(r.index, i)] for r in st.reads}
                    tgt = slot_of[at(st.index, i)] if st.array == "v" else \
                        ("out", at(st.index, i))
                    out.append((tgt, st.expr.xreplace(sub)))
    return out


@pytest.mark.parametrize("mixed", [False, True])
def test_loops_run_the_lines_in_their_order(tmp_path, mixed):
    """Every function of the ladders: the loops, run out, give back exactly the lowered
    lines and results in their order (no statement reads what a later one writes)."""
    low = _compiled(tmp_path, ladder(40, mixed)).lowered
    ctx = PartContext(low)
    loops = 0
    for fn in (low.rhs, low.jac, low.outs):
        roll = rr.reroll(fn, ctx.state_syms, ctx.param_syms, min_run=4)
        loops += roll.loops
        want = [(ln.target, ln.expr) for ln in fn.lines]
        want += [(("out", k), r) for k, (_, r) in enumerate(fn.results)]
        got = _expanded(roll, ctx.state_syms, ctx.param_syms)
        assert [g[0] for g in got] == [w[0] for w in want]
        for (tgt, e), (_, ref) in zip(got, want):
            assert sp.expand(e - ref) == 0, (tgt, e, ref)
    assert loops >= 3


def _part_text(files: dict) -> tuple[int, int, int]:
    """(lines of the part units without the index tables' rows, for loops, part files)."""
    lines = loops = 0
    for name, text in files.items():
        if not name.startswith("model_part"):
            continue
        for ln in text.splitlines():
            if re.fullmatch(r"\s*\d+(, \d+)*,?", ln):  # a row of an index table
                continue
            lines += 1
            loops += ln.lstrip().startswith("for (")
    return lines, loops, sum(f.startswith("model_part") for f in files)


def test_rolled_ladder_source_size_independent_of_n(tmp_path, monkeypatch):
    monkeypatch.setattr(rr, "MIN_RUN", 8)
    sizes = {}
    for n in (30, 120):
        sizes[n] = _part_text(c_files(_compiled(tmp_path, ladder(n)))[0])
    assert sizes[30] == sizes[120], sizes
    assert sizes[30][1] >= 3  # rhs, its results, the Jacobian
    monkeypatch.setattr(rr, "MIN_RUN", 10 ** 9)
    flat = _part_text(c_files(_compiled(tmp_path, ladder(120)))[0])
    assert flat[0] > 5 * sizes[120][0]


def test_no_repetition_no_change(monkeypatch):
    """A model without runs of MIN_RUN: the same C text with the pass on and off."""
    comp = compile_model(parse_file(ROOT / "models" / "quarter_car.yaml"))
    ctx = PartContext(comp.lowered)
    for fn in (comp.lowered.rhs, comp.lowered.jac):
        roll = rr.reroll(fn, ctx.state_syms, ctx.param_syms)
        assert roll.loops == 0 and not roll.values
    on = c_files(comp)
    monkeypatch.setattr(rr, "MIN_RUN", 10 ** 9)
    assert c_files(comp) == on


def test_index_affine_or_table():
    assert rr.Index.of([4, 7, 10, 13]) == rr.Index(4, 3)
    assert rr.Index.of([9, 8, 7]) == rr.Index(9, -1)
    assert rr.Index.of([0, 1, 3]) == rr.Index(0, 0, (0, 1, 3))


def test_runs_need_min_run_whole_blocks():
    seq = [9, 1, 2, 1, 2, 1, 2, 1, 2, 1, 7]
    assert rr._runs(seq, 4) == [(1, 2, 4)]
    assert rr._runs(seq, 5) == []
    assert rr._runs([1] * 10, 3) == [(0, 1, 10)]


@pytest.mark.skipif(not HAVE_CC, reason="no C compiler")
def test_fmu_of_a_rolled_ladder_simulates_like_the_numpy_module(tmp_path):
    """The FMU prints the same parts: its loops, run by FMPy, against the (unrolled) numpy
    module's Radau at a tight tolerance."""
    import zipfile

    fmpy = pytest.importorskip("fmpy")
    from bgc.backends.load import load_module
    from bgc.run.fmu import export_fmu

    p = tmp_path / "ladder12.yaml"
    p.write_text(ladder(12))
    fmu = tmp_path / "ladder12.fmu"
    export_fmu(p, fmu)
    with zipfile.ZipFile(fmu) as zf:
        parts = [zf.read(n).decode() for n in zf.namelist() if "model_part" in n]
    assert parts and any("for (int bgc_i" in t for t in parts)
    t1 = 0.5
    r = fmpy.simulate_fmu(str(fmu), fmi_type="CoSimulation", stop_time=t1,
                          output_interval=t1 / 100, relative_tolerance=1e-8, output=["v_end"])
    mod = load_module(compile_model(parse_file(p)).source, "ladder12_np")
    ref = mod.simulate((0.0, t1), t_eval=r["time"], method="Radau", rtol=1e-11, atol=1e-14)
    yr = np.asarray(ref.y["v_end"]).ravel()
    scale = np.abs(yr).max()
    assert scale > 1e-6
    assert np.abs(np.asarray(r["v_end"]).ravel() - yr).max() <= 1e-5 * scale


# ---------------------------------------------------------------------------------------------
# The numpy module: the same runs printed as vectorised statements (bgc.backends.numpy.rolled)

def _np_pair(comp, monkeypatch, min_run: int, cover: float | None = None):
    """(rolled, unrolled) numpy modules of one compiled model, and the rolled text."""
    from bgc.backends.load import load_module
    from bgc.backends.numpy import rolled as nr

    monkeypatch.setattr(rr, "MIN_RUN", min_run)
    if cover is not None:
        monkeypatch.setattr(nr, "MIN_COVER", cover)
    text = comp.printer(True, True)  # printed again (not the compile's text)
    assert "_w[" in text and "_g0 = " in text  # (it did roll)
    name = comp.model.name
    rolled = load_module(text, f"{name}_np_rolled")
    monkeypatch.setattr(rr, "MIN_RUN", 10 ** 9)
    flat_text = comp.printer(True, True)
    assert "_g0 = " not in flat_text
    return rolled, load_module(flat_text, f"{name}_np_flat"), text


def _same_np(a, b, x0, seed=7, rounds=3, p=None):
    """rhs, Jacobian and outputs of two numpy modules at random points, one instance and a
    batch of three (parameters too, where ``p`` is given): equal to 1e-13 relative."""
    rng = np.random.default_rng(seed)
    for _ in range(rounds):
        for shape in ((), (3,)):
            x = x0.reshape(x0.shape + (1,) * len(shape)) + 0.1 * np.maximum(
                np.abs(x0), 0.1).reshape(x0.shape + (1,) * len(shape)) * \
                rng.standard_normal(x0.shape + shape)
            t = float(rng.uniform(0, 2))
            for f in ("rhs", "jacobian"):
                ra, rb = getattr(a, f)(t, x, p), getattr(b, f)(t, x, p)
                assert ra.shape == rb.shape
                np.testing.assert_allclose(ra, rb, rtol=1e-13, atol=1e-13 * np.abs(rb).max())
            ya, yb = a.outputs(t, x, p), b.outputs(t, x, p)
            for k in yb:
                np.testing.assert_allclose(ya[k], yb[k], rtol=1e-13,
                                           atol=1e-13 * np.abs(yb[k]).max())


@pytest.mark.parametrize("mixed", [False, True])
def test_numpy_ladder_rolled_equals_unrolled_and_hand_written(tmp_path, monkeypatch, mixed):
    """The plain ladder rolls at the defaults (MIN_RUN, MIN_COVER); the mixed one (two kinds
    of instances, a parameter per section) with runs of 4 and every run vectorised."""
    n = 30
    comp = _compiled(tmp_path, ladder(n, mixed))
    rolled, flat, text = _np_pair(comp, monkeypatch, 4 if mixed else rr.MIN_RUN,
                                  0.0 if mixed else None)
    if mixed:
        assert "_pa[" in text  # per-instance parameters gathered from the parameter array
    _same_np(rolled, flat, np.zeros(n))
    _same_np(rolled, flat, np.zeros(n), p={"R": np.array([0.5, 1.0, 2.0])})
    rng = np.random.default_rng(3)
    for _ in range(3):
        q = 0.01 * rng.standard_normal(n)
        t = float(rng.uniform(0, 2))
        ref = ladder_rhs(t, q, mixed)
        np.testing.assert_allclose(rolled.rhs(t, q), ref, rtol=1e-12,
                                   atol=1e-12 * np.abs(ref).max())


@pytest.mark.slow
def test_numpy_link_chain_rolled_equals_unrolled(tmp_path, monkeypatch):
    """Four 3-D links, every run of three or more vectorised (or kept a loop where it reads
    what it writes), against the unrolled module."""
    comp = _compiled(tmp_path, link_chain(4))
    rolled, flat, _ = _np_pair(comp, monkeypatch, 3, 0.0)
    _same_np(rolled, flat, np.asarray(flat.X0, dtype=float), rounds=2)


def _np_functions(text: str) -> list[str]:
    """The lines of the module's rhs, jacobian and outputs."""
    body = text[text.index("\ndef rhs("):text.index("\ndef input_jacobian(")]
    return body.splitlines()


def test_numpy_rolled_ladder_size_independent_of_n(tmp_path, monkeypatch):
    """The vectorised functions of a 30- and a 120-node ladder have the same lines (only the
    numbers in their slices differ); the unrolled 120-node functions are far longer."""
    texts = {n: _compiled(tmp_path, ladder(n)).module_text() for n in (30, 120)}
    lines = {n: _np_functions(t) for n, t in texts.items()}
    assert len(lines[30]) == len(lines[120])
    strip = [re.sub(r"\d+", "N", ln) for ln in lines[30]]
    assert strip == [re.sub(r"\d+", "N", ln) for ln in lines[120]]
    monkeypatch.setattr(rr, "MIN_RUN", 10 ** 9)
    flat = _np_functions(_compiled(tmp_path, ladder(120)).module_text())
    assert len(flat) > 5 * len(lines[120])


def test_vector_order_moves_statements_after_what_they_read():
    """A statement that reads a value a later statement wrote in an earlier iteration runs
    after it; one that reads its own values from an earlier iteration is a recurrence."""
    from bgc.backends.numpy.rolled import _vector_order

    a, b = sp.Dummy("a"), sp.Dummy("b")
    m = 5
    # s0: v[10+i] = v[20+i-1] (s1's value, one iteration back; v[19] written before)
    # s1: v[20+i] = x[i]
    s0 = rr.Stmt(a, (rr.Read(a, "v", rr.Index(19, 1)),), "v", rr.Index(10, 1))
    s1 = rr.Stmt(2 * b, (rr.Read(b, "x", rr.Index(0, 1)),), "v", rr.Index(20, 1))
    assert _vector_order(rr.Loop(m, (s0, s1), frozenset()), {}) == [1, 0]
    # v[20+i] = 2 v[19+i]: each iteration reads the one before
    rec = rr.Stmt(2 * a, (rr.Read(a, "v", rr.Index(19, 1)),), "v", rr.Index(20, 1))
    assert _vector_order(rr.Loop(m, (rec,), frozenset()), {}) is None


def test_numpy_recurrence_stays_a_loop(tmp_path):
    """A run that is a true recurrence printed as a Python loop, in order: the module's
    function gives the same values as the lines it replaces."""
    from bgc.backends.numpy.printer import BgcPrinter, Function, Line
    from bgc.backends.numpy.rolled import Tables, rolled_function
    from bgc.lower.ir import Function as LFunction
    from bgc.lower.ir import Line as LLine

    x = sp.symbols("x0:12")
    v = sp.symbols("v0:12")
    k = sp.Symbol("k")
    # v0 = x0; v_i = k*v_{i-1} + x_i (a running sum): 11 alike lines after the first
    lines = [LLine(v[0], x[0])] + [LLine(v[i], k * v[i - 1] + x[i]) for i in range(1, 12)]
    results = tuple((i, v[i]) for i in range(12))
    fn = LFunction(("k",), (), tuple(str(s) for s in x), tuple(lines), results, 0)
    got = rolled_function(fn, BgcPrinter(), Line, Function, list(x), [k], "rhs", Tables())
    assert got is not None and got.rolled
    code = "\n".join(f"    {ln.target} = {ln.code}" if ln.target else f"    {ln.code}"
                     for ln in got.lines)
    assert "for _i in range(" in code
    src = ("import numpy as np\nxp = np\n_device = lambda x: None\n"
           "def f(x, k):\n    _bs = x.shape[1:]\n    _dx = np.empty((12,) + _bs)\n"
           f"{code}\n    return _dx\n")
    ns: dict = {}
    exec(compile(src, "<recurrence>", "exec"), ns)  # noqa: S102 (text made by this test)
    xv = np.random.default_rng(0).standard_normal(12)
    want = np.empty(12)
    acc = 0.0
    for i in range(12):
        acc = 0.7 * acc + xv[i] if i else xv[0]
        want[i] = acc
    np.testing.assert_allclose(ns["f"](xv, 0.7), want, rtol=1e-14)


def test_numpy_rolled_ladder_run_matches_hand_written_scipy(tmp_path):
    """A whole run of the 120-node ladder's vectorised module (Radau, sparse LU, steps held
    at max_step) against the hand-written node equations integrated by scipy's Radau; the
    steps held at max_step reuse their LUs (fewer factorisations than steps)."""
    from scipy.integrate import solve_ivp

    from bgc.backends.load import load_module

    n, t1 = 120, 2.0
    comp = _compiled(tmp_path, ladder(n))
    text = comp.module_text()
    assert "_g0 = " in text
    mod = load_module(text, "ladder120_np")
    ts = np.linspace(0.0, t1, 41)
    r = mod.simulate((0.0, t1), t_eval=ts, method="Radau", rtol=1e-8, atol=1e-12,
                     max_step=0.01)
    assert r.stats["nlu"] < r.stats["nsteps"]
    ref = solve_ivp(lambda t, q: ladder_rhs(t, q), (0.0, t1), np.zeros(n), method="Radau",
                    rtol=1e-11, atol=1e-14, t_eval=ts)
    assert ref.status == 0
    scale = np.abs(ref.y).max()
    assert scale > 1e-4
    assert np.abs(np.asarray(r.x) - ref.y).max() <= 1e-6 * scale


def test_a_function_is_rolled_once_whichever_printer_asks(tmp_path, monkeypatch):
    """The C parts and the numpy module printed from one compile share the rolls: each
    function of the IR is rolled once (the numpy module, printed after the C sources, finds
    the rhs's and the Jacobian's rolls made for them), and the rolled texts are the same as
    from a fresh roll."""
    (tmp_path / "m.yaml").write_text(ladder(30))
    comp = compile_model(parse_file(tmp_path / "m.yaml"), target="c")
    calls = []
    real = rr._reroll
    monkeypatch.setattr(rr, "_reroll", lambda fn, *a: (calls.append(fn), real(fn, *a))[1])
    files = c_files(comp)[0]
    low = comp.lowered
    assert sum(f is low.rhs for f in calls) == 1 and sum(f is low.jac for f in calls) == 1
    source = comp.source  # the numpy module: rhs, Jacobian and outputs vectorised
    assert "_w[" in source
    assert sum(f is low.rhs for f in calls) == 1 and sum(f is low.jac for f in calls) == 1
    assert len(calls) == len({id(f) for f in calls})  # no function rolled twice
    ctx = PartContext(low)
    assert rr.reroll(low.rhs, ctx.state_syms, ctx.param_syms) is \
        rr.reroll(low.rhs, ctx.state_syms, ctx.param_syms)
    rr._DONE.clear()  # a fresh roll of everything prints the same text
    assert c_files(comp)[0] == files


def _ladder_1000() -> str:
    """bench/bench_scale.py's 1000-node ladder, each capacitor charged at the start (q = C V0:
    initial_state reads parameters) and each resistor's current an output (f(r_k) = (v_k-1 -
    v_k) / R: C has two entries per output, D one for the source's)."""
    sys.path.insert(0, str(ROOT / "bench"))
    from bench_scale import ladder_yaml

    n = 1000
    text = ladder_yaml(n).replace('compliance: "C"}', 'compliance: "C", initial: "C * V0"}')
    assert text.count('initial: "C * V0"') == n
    return text + "".join(f'  i{k}: "f(r{k})"\n' for k in range(n))


@pytest.mark.slow
def test_numpy_ladder_1000_initial_state_and_b_c_d_rolled_equal_unrolled(tmp_path, monkeypatch):
    """initial_state, input_jacobian and output_jacobian of the 1000-node ladder, vectorised
    at the defaults (MIN_RUN, MIN_COVER), equal the unrolled printing to 1e-13 (one instance
    and a batch, default and batched parameters); and the closed forms: q0 = C V0, B = e_0 / R,
    C = (e_k-1 - e_k) / (R C) per current, D = 1/R for the first current only."""
    n, R_, C_, V0_ = 1000, 1.0, 0.01, 1.0
    comp = _compiled(tmp_path, _ladder_1000())
    rolled, flat, text = _np_pair(comp, monkeypatch, rr.MIN_RUN)
    init = text[text.index("\ndef initial_state("):text.index("\ndef rhs(")]
    assert len(init.splitlines()) < 40  # (it did roll: not a line per state)
    assert "_Yv = np.empty" in text
    rng = np.random.default_rng(11)
    for p in (None, {"C": np.array([0.01, 0.02, 0.05]), "V0": np.array([1.0, -2.0, 3.0])}):
        a, b = rolled.initial_state(p), flat.initial_state(p)
        assert a.shape == b.shape
        np.testing.assert_allclose(a, b, rtol=1e-13, atol=0)
        for shape in ((), (3,)):
            x = rng.standard_normal((n,) + shape)
            t = float(rng.uniform(0, 2))
            for f in ("input_jacobian", "output_jacobian"):
                ra, rb = getattr(rolled, f)(t, x, p), getattr(flat, f)(t, x, p)
                for ma, mb in zip(*((ra, rb) if f == "output_jacobian" else ((ra,), (rb,)))):
                    assert ma.shape == mb.shape
                    np.testing.assert_allclose(ma, mb, rtol=1e-13, atol=0)
    np.testing.assert_allclose(rolled.initial_state(), np.full(n, C_ * V0_), rtol=1e-15)
    B = rolled.input_jacobian(0.0, rolled.X0)
    want_b = np.zeros((n, 1))
    want_b[0, 0] = 1 / R_
    np.testing.assert_allclose(B, want_b, rtol=1e-14)
    Cm, D = rolled.output_jacobian(0.0, rolled.X0)
    rows = [rolled.OUTPUT_LABELS.index(f"i{k}") for k in range(n)]
    want_c = np.zeros((n, n))
    for k in range(n):
        want_c[k, k] = -1 / (R_ * C_)
        if k:
            want_c[k, k - 1] = 1 / (R_ * C_)
    np.testing.assert_allclose(Cm[rows], want_c, rtol=1e-13)
    want_d = np.zeros((n, 1))
    want_d[0, 0] = 1 / R_
    np.testing.assert_allclose(D[rows], want_d, rtol=1e-14)


def _covered(fn, states, params) -> int:
    roll = rr.reroll(fn, states, params)
    return sum(it.count * len(it.body) for it in roll.items if isinstance(it, rr.Loop))


def _synthetic(rng, n: int):
    """A function of n lines over a few states and parameters: short random stretches and
    planted runs (one block of 1-6 lines repeated 5-12 times, over other states)."""
    from bgc.lower.ir import Function

    xs, ps = sp.symbols("x0:40", real=True), sp.symbols("p0:8", real=True)
    lines, k = [], 0

    def one(j):
        kind = rng.integers(4)
        a, b = xs[int(j) % 40], ps[int(rng.integers(8))]
        return [a * b, a + b, sp.sin(a) * b, a / b - a][kind]

    while len(lines) < n:
        if rng.random() < 0.5:
            block = [int(rng.integers(40)) for _ in range(int(rng.integers(1, 7)))]
            shapes = [int(rng.integers(4)) for _ in block]
            for rep in range(int(rng.integers(5, 13))):
                for j, s in zip(block, shapes):
                    x = xs[(j + rep) % 40]
                    e = [x * ps[0], x + ps[1], sp.sin(x) * ps[2], x / ps[3] - x][s]
                    lines.append(Line(sp.Symbol(f"v{k}"), e))
                    k += 1
        else:
            lines.append(Line(sp.Symbol(f"v{k}"), one(rng.integers(40))))
            k += 1
    results = tuple((i, ln.target) for i, ln in enumerate(lines[-3:]))
    return Function((), (), (), tuple(lines), results, 0), list(xs), list(ps)


def test_may_cover_bounds_what_reroll_covers(monkeypatch):
    """bgc.backends.numpy.rolled.may_cover is an upper bound: wherever reroll's loops cover
    c items, may_cover(fn, c) holds (random functions with planted runs, several MIN_RUN);
    and on the 3R2S, whose rhs, Jacobian and outputs reroll covers well below MIN_COVER, it
    tells so without rerolling."""
    from bgc.backends.numpy import rolled as nr

    rng = np.random.default_rng(27)
    refused = 0
    for min_run in (2, 3, 5, 8):
        monkeypatch.setattr(rr, "MIN_RUN", min_run)
        for _ in range(12):
            fn, xs, ps = _synthetic(rng, int(rng.integers(20, 160)))
            c = _covered(fn, xs, ps)
            assert nr.may_cover(fn, c)
            refused += not nr.may_cover(fn, len(fn.lines) + len(fn.results))
    assert refused > 10  # (the bound is no constant: most functions are not all loops)
    monkeypatch.undo()
    comp = compile_model(parse_file(ROOT / "models" / "3r2s.yaml"))
    eq, low = comp.equations, comp.lowered
    states = [sv.symbol for sv in eq.states]
    params = [s for pv in eq.params for s in pv.symbols] + [d.symbol for d in eq.derived]
    for fn in (low.rhs, low.jac, low.outs):
        c = _covered(fn, states, params)
        items = len(fn.lines) + len(fn.results)
        assert nr.may_cover(fn, c)
        assert c < nr.MIN_COVER * items and not nr.may_cover(fn, nr.MIN_COVER * items)
