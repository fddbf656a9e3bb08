"""The C backend's numeric solves against the numpy module: derivative causality's numeric
linear solves (the mass-matrix form, a dense LU per instance in C, np.linalg.solve in numpy)
and nonlinear algebraic loops (a Newton function per loop in C, _newton_k in numpy).

The models are the rigid pendulum chains compiled with symbolic_max=0 (every linear system of
derivative causality solved numerically, not symbolically), and models/algebraic_loop.yaml
with its series resistor made cubic (a nonlinear loop: Newton). References: the numpy module
(other printer, numpy's LAPACK solve and batched Newton; its runs in scipy's DOP853), scipy's
brentq on the circuit's one-unknown equation, and the closed forms of a singular system and
of a non-convergent loop.
"""
from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest

from bgc.backends import load as backends
from bgc.backends.c import build as cbuild
from bgc.backends.load import load_module
from bgc.base.errors import ModelError
from bgc.format.parse import parse_text
from bgc.run import cache as cache_mod
from bgc.run.driver import compile_model

ROOT = Path(__file__).resolve().parents[1]
pytestmark = [
    pytest.mark.skipif(not cbuild.available(), reason="no C compiler (CI installs one)"),
    pytest.mark.skipif(not cbuild.runtime_sources(), reason="the C runtime is missing"),
]

# the resistive loop of models/algebraic_loop.yaml with R1 cubic: Newton in the generated code
CUBIC = 'series_R: {type: R, effort: "R1 * f + 1.0e5 * f**3"}'
NOT_CONVERGING = 'series_R: {type: R, effort: "R1 * 1.0 / f"}'  # no root near the warm start
# (the 1.0 carries A^2: a number in a product takes the unit its place needs)
from test_derivative_causality import GEAR  # noqa: E402  (the rigid gear pair, J1 + n^2 J2)

_built: dict = {}


def _text(name):
    if name == "gear":
        return GEAR, "gear.yaml"
    if name.startswith("loop"):
        text = (ROOT / "models" / "algebraic_loop.yaml").read_text()
        law = CUBIC if name == "loop_cubic" else NOT_CONVERGING
        text = text.replace('series_R: {type: R, resistance: "R1"}', law)
        assert law in text
        return text, "algebraic_loop.yaml"
    return (ROOT / "models" / f"{name}.yaml").read_text(), f"{name}.yaml"


def _key(name, text, fname):
    """The C library's key in the test session's compile cache: the model text (written
    where the key can read it) with symbolic_max=0, bgc's code, the compiler and its flags.
    Through the cache the C runtime's objects are built once per session, and a model's
    library once for both workers."""
    d = Path(tempfile.mkdtemp(prefix="bgc-c-solve-"))
    (d / fname).write_text(text, encoding="utf-8")
    try:
        return cache_mod.key("c", d / fname, extra=f"c_solve:{name}:symbolic_max=0")
    finally:
        shutil.rmtree(d, ignore_errors=True)


_compiles: dict = {}


def _compiled(name):
    """The model compiled with symbolic_max=0, once per worker (the pair below and the parts
    test print their C from it; callers must not change it)."""
    if name not in _compiles:
        text, fname = _text(name)
        _compiles[name] = compile_model(parse_text(text, fname), symbolic_max=0)
    return _compiles[name]


def _pair(name):
    """(compiled, numpy module, C module), every linear system solved numerically."""
    if name not in _built:
        text, fname = _text(name)
        c = _compiled(name)
        npm = load_module(c.source, f"solve_{name}_np")
        _, cm = backends.load(f"solve_{name}_c", "c", _key(name, text, fname), lambda: c,
                              cache_mod.Cache())
        _built[name] = (c, npm, cm)
    return _built[name]


def _close(a, b, rel=1e-12):
    a, b = np.asarray(a, float), np.asarray(b, float)
    scale = np.maximum(np.abs(a), np.abs(b))
    floor = rel * 1e-3 * max(float(np.max(np.abs(b))), 1e-300)
    return bool(np.all(np.abs(a - b) <= rel * scale + floor))


SOLVES = ["double_pendulum_rigid", "three_rod_rigid", "gear"]
ALL = SOLVES + ["loop_cubic"]


def test_the_models_hit_the_numeric_solves():
    """The cases under test really solve numerically (else the tests below prove nothing)."""
    for name in SOLVES:
        c, _, _ = _pair(name)
        assert "_bgc_linsolve(" in c.source and not c.equations.newton, name
    c, _, _ = _pair("loop_cubic")
    assert len(c.equations.newton) == 1 and "def _newton_0" in c.source


@pytest.mark.parametrize("name", ALL)
def test_rhs_jacobian_outputs_match_numpy(name):
    _, npm, cm = _pair(name)
    rng = np.random.default_rng(5)
    x0 = np.asarray(npm.X0, float)
    for k in range(5):
        x = x0 * (1 + 0.3 * rng.standard_normal(x0.shape)) + 0.2 * rng.standard_normal(x0.shape)
        t = float(rng.uniform(0, 2))
        assert _close(cm.rhs(t, x), npm.rhs(t, x)), (name, k)
        assert _close(cm.jacobian(t, x), npm.jacobian(t, x)), (name, k)
        yc, yn = cm.outputs(t, x), npm.outputs(t, x)
        for o in yn:
            assert _close(yc[o], yn[o]), (name, o)
    # a batch of states at once (one call, one instance after the other in C)
    X = x0[:, None] * (1 + 0.2 * rng.standard_normal((len(x0), 7)))
    assert _close(cm.rhs(0.5, X), npm.rhs(0.5, X))
    assert _close(cm.jacobian(0.5, X), npm.jacobian(0.5, X))


def test_newton_loop_against_brentq():
    """The node voltage of the cubic loop from C against scipy's brentq on the circuit's
    one-unknown equation (an answer from outside bgc)."""
    from scipy.optimize import brentq

    _, _, cm = _pair("loop_cubic")
    V, R1, R2, R3, C1 = 10.0, 1000.0, 2000.0, 500.0, 1e-3
    for q in (0.0, 0.004, -0.01):
        vc = q / C1

        def res(f):
            en = V - (R1 * f + 1e5 * f ** 3)
            return f - (en / R2 + (en - vc) / R3)
        f = brentq(res, -1, 1, xtol=1e-16)
        en = V - (R1 * f + 1e5 * f ** 3)
        y = cm.outputs(0.0, np.array([q]))
        assert abs(float(y["v_node"]) - en) <= 1e-10 * abs(en)
        assert abs(float(cm.rhs(0.0, np.array([q]))[0]) - (en - vc) / R3) <= 1e-12


def _span(name):
    return {"double_pendulum_rigid": 3.0, "three_rod_rigid": 2.0}.get(name, 4.0)


@pytest.fixture(scope="module")
def numpy_runs():
    """name -> the states of the numpy module's reference run below, made once for both C
    methods. (A module-scoped fixture: conftest.work_unit sends this file's tests to one
    xdist worker together, so each model is also compiled once.)"""
    return {}


@pytest.mark.parametrize("method", ["Radau", "Rodas4"])
@pytest.mark.parametrize("name", ALL)
def test_whole_runs_match_numpy(name, method, numpy_runs):
    """The step loop in C (Radau IIA 5 or Rodas4, the model's solves inside) against the
    numpy module in scipy's DOP853 (the numpy Rodas4 needs ~100x the steps of the C one on
    the gear's time-dependent drive, which makes it too slow for a test; none of the four
    models is stiff, and at rtol 1e-10 DOP853 takes 13-85 steps where scipy's Radau took
    207-1,738: double_pendulum_rigid 85 against 1,738), both at rtol 1e-10."""
    _, npm, cm = _pair(name)
    T = _span(name)
    t_eval = np.linspace(0, T, 21)
    kw = dict(t_eval=t_eval, rtol=1e-10, atol=1e-12)
    _, xc, yc = cm.simulate((0, T), method=method, **kw)
    if name not in numpy_runs:  # (the same run for either C method)
        numpy_runs[name] = npm.simulate((0, T), method="DOP853", **kw).x
    xn = numpy_runs[name]
    scale = np.max(np.abs(xn), axis=1, keepdims=True) + 1e-3
    assert np.all(np.abs(xc - xn) <= 1e-6 * scale), np.max(np.abs(xc - xn) / scale)
    assert all(np.all(np.isfinite(v)) for v in yc.values())


def test_batches_equal_single_runs():
    """A parameter batch integrates each instance with its own steps and its own Newton warm
    start (the instance's workspace, never shared between threads): every instance equals
    its single run exactly, with one thread or two."""
    for name, p in (("loop_cubic", {"V0": np.array([5.0, 10.0, -8.0])}),
                    ("double_pendulum_rigid", {"c1": np.array([0.0, 0.05, 0.3])})):
        _, _, cm = _pair(name)
        key, vals = next(iter(p.items()))
        kw = dict(t_eval=np.linspace(0, 1.5, 7), rtol=1e-8, atol=1e-10)
        for method in ("Radau", "Rodas4"):
            singles = [cm.simulate((0, 1.5), method=method, p={key: float(v)}, **kw)[1]
                       for v in vals]
            for threads in (1, 2):
                _, xb, _ = cm.simulate((0, 1.5), method=method, p=p, nthreads=threads, **kw)
                for k in range(len(vals)):
                    np.testing.assert_array_equal(xb[:, k], singles[k])


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_newton_failure_is_the_located_error():
    """A loop without a root near its start: the numpy module and the C module raise a
    SimulationError located at the loop (file:line:col, its elements) with a remedy; the numpy
    module says when, a C run says it too, with the method and the time."""
    c, npm, cm = _pair("loop_bad")
    x = np.array([0.0])
    with pytest.raises(npm.SimulationError) as en:
        npm.rhs(0.0, x)
    with pytest.raises(cm.SimulationError) as ec:
        cm.rhs(0.0, x)
    msg = str(ec.value)
    assert msg.startswith("algebraic_loop.yaml:") and "series_R" in msg
    assert "did not converge (damped Newton, 100 iterations)" in msg and "max_step" in msg
    assert str(en.value) == msg.replace("did not converge", "did not converge at t = 0")
    with pytest.raises(cm.SimulationError):
        cm.jacobian(0.0, x)
    for method in ("Radau", "Rodas4"):
        with pytest.raises(cm.SimulationError) as er:
            cm.simulate((0, 1), method=method)
        assert str(er.value).startswith(msg) and f"({method}, at t = 0)" in str(er.value)


def test_singular_linear_solve_is_an_error_not_garbage():
    """J1 + n^2 J2 = 0 (a negative inertia: the gear's mass matrix is exactly singular):
    numpy's solve refuses it; the C module raises a SimulationError naming the system and
    its elements, from rhs, jacobian and a run, never a number."""
    _, npm, cm = _pair("gear")
    p = {"n": 2.0, "J1": 1.0, "J2": -0.25}
    x = np.asarray(npm.X0, float)
    with pytest.raises(np.linalg.LinAlgError):
        npm.rhs(0.0, x, p)
    for call in (lambda: cm.rhs(0.0, x, p), lambda: cm.jacobian(0.0, x, p),
                 lambda: cm.simulate((0, 1), method="Radau", p=p)):
        with pytest.raises(cm.SimulationError) as e:
            call()
        msg = str(e.value)
        assert "linear system in 1 unknown(s) (dx_p_I1)" in msg and "is singular" in msg
        assert "TF 'gear'" in msg
    # one singular instance in a batch: that instance fails, located, and says which
    pb = {"n": 2.0, "J1": 1.0, "J2": np.array([0.2, -0.25])}
    with pytest.raises(cm.SimulationError, match=r"batch instance \(1,\)"):
        cm.simulate((0, 1), method="Rodas4", p=pb)


def test_fmu_export_carries_numeric_solves():
    """The FMU's parts hold derivative causality's numeric solve as the C backend's do, and
    return its failure code (tests/test_fmu_solves.py runs such units in FMPy)."""
    from bgc.backends.fmu.export import build_spec, render_sources

    c, _, _ = _pair("gear")
    files = render_sources(c, build_spec(c))
    parts = "".join(v for k, v in files.items() if k.startswith("model_part"))
    assert "bgc_dense_lu(" in parts
    assert ", NULL)) return 1;" in files["bgc_fmu_model.c"]


def test_cli_simulate_backend_c_runs_a_newton_loop_in_c(tmp_path, monkeypatch):
    """`bgc simulate --backend c` on a scene whose model has a nonlinear algebraic loop: the
    C backend runs it (no fallback to numpy) and agrees with the numpy backend.

    The command line in-process (conftest's bgc_in_process: two `bgc` processes spent seconds
    of CPU in imports alone), through a cache of its own that starts with the C runtime's objects
    (conftest's seed_c_runtime): the scene's entries start empty, so both are compiled here."""
    from conftest import bgc_in_process, seed_c_runtime

    text, _ = _text("loop_cubic")
    (tmp_path / "loop.yaml").write_text(text)
    (tmp_path / "scene.yaml").write_text(
        "bgc_scene: 1\nmodel: loop.yaml\nduration: 3.0\nparameters: {R2: 1500.0}\n"
        "outputs: [v_C, v_node]\nsolver: {method: Radau, rtol: 1.0e-9, atol: 1.0e-12, dt: 0.1}\n")
    monkeypatch.setenv("BGC_CACHE_DIR", str(seed_c_runtime(tmp_path / "cache")))
    runs = {}
    for backend in ("c", "numpy"):
        out = tmp_path / f"{backend}.npz"
        p = bgc_in_process("simulate", tmp_path / "scene.yaml", "--backend", backend,
                           "--out", out)
        assert p.returncode == 0, p.stderr
        assert f"({backend} backend)" in p.stdout and "using the numpy backend" not in p.stderr
        runs[backend] = np.load(out)
    for o in ("v_C", "v_node"):
        a, b = runs["c"][o], runs["numpy"][o]
        assert np.max(np.abs(a - b)) <= 1e-6 * np.max(np.abs(b))


@pytest.mark.parametrize("name", ["double_pendulum_rigid", "loop_cubic"])
def test_solves_across_parts(name, monkeypatch):
    """Bodies cut into parts of 3 lines: a solve's result crosses from its part to later ones
    through the scratch array (one slot per entry); rhs, Jacobian and a run still match the
    numpy module."""
    from bgc.backends.c import printer as emit_c

    monkeypatch.setattr(emit_c, "PART_LINES", 3)
    text, fname = _text(name)
    c = _compiled(name)  # (the pair's compile: the parts are the C printer's)
    files, _ = backends.c_files(c)
    parts = [t for f, t in files.items() if f.startswith("model_part")]
    assert any("const double *const" in t and "= bgc_w + " in t for t in parts)  # imported
    assert any("double *const" in t for t in parts)  # a solve written to the scratch array
    npm = load_module(c.source, f"parts_{name}_np")
    # built through the session's cache (its C runtime's objects built once), under a key of
    # its own: a library of 3-line parts
    _, cm = backends.load(f"parts_{name}_c", "c", _key(f"{name}:PART_LINES=3", text, fname),
                          lambda: c, cache_mod.Cache())
    rng = np.random.default_rng(2)
    x0 = np.asarray(npm.X0, float)
    for _ in range(3):
        x = x0 + 0.3 * rng.standard_normal(x0.shape) * (np.abs(x0) + 0.1)
        assert _close(cm.rhs(0.7, x), npm.rhs(0.7, x))
        assert _close(cm.jacobian(0.7, x), npm.jacobian(0.7, x))
    kw = dict(t_eval=np.linspace(0, 1, 5), rtol=1e-10, atol=1e-12)
    xc = cm.simulate((0, 1), method="Radau", **kw).x
    xn = npm.simulate((0, 1), method="DOP853", **kw).x  # (scipy's: the models are not stiff)
    assert np.max(np.abs(xc - xn)) <= 1e-6 * (np.max(np.abs(xn)) + 1e-3)


def test_fmu_export_carries_table_inputs(tmp_path):
    """An FMU input that follows its default follows the table's data (compiled into the
    unit as the C backend's model_tables.c), not a placeholder (tests/test_fmu_solves.py runs
    such a unit in FMPy)."""
    from bgc.backends.fmu.export import build_spec, render_sources
    from bgc.run.driver import compile_file

    text = (ROOT / "models" / "quarter_car.yaml").read_text()
    old = 'zr: {default: "0", shape: [], unit: m}'
    assert old in text
    (tmp_path / "qc.yaml").write_text(
        text.replace(old, "zr: {table: road.csv, columns: [time, height], unit: m}"))
    (tmp_path / "road.csv").write_text("time,height\n0,0\n0.5,0.02\n1,0\n")
    c = compile_file(tmp_path / "qc.yaml")
    files = render_sources(c, build_spec(c))
    assert "0.02" in files["model_tables.c"] and "bgcm_table_0" in files["model_tables.c"]
    assert "bgcf_table_0(t)" in files["bgc_fmu_model.c"]
