"""The C backend against the numpy module (the reference): rhs, Jacobian, outputs and initial
state at random points; whole runs of every example model; batches against single runs;
non-finite diagnostics; the C text door (string literals, comments); golden C sources; the
numpy fallback without a compiler.

The numpy module is an independent implementation of the same lowered equations (other
printer, other arithmetic order), and its integrations here use scipy's integrators at tight
tolerances (DOP853 where the model is not stiff, else LSODA or Radau), which share no code
with the C runtime.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import bgc_in_process, reference_method, seed_c_runtime

from bgc.backends import load as backends
from bgc.backends.c import build as cbuild
from bgc.backends.c.printer import c_comment, c_string_literal
from bgc.backends.load import load_module
from bgc.run import cache as cache_mod
from bgc.run.driver import compile_file

ROOT = Path(__file__).resolve().parents[1]
MODELS = sorted(p.stem for p in (ROOT / "models").glob("*.yaml"))
SLOW = {"3r2s", "3r2s_rigid"}  # the C build of its Jacobian takes tens of seconds on a loaded machine
HAVE_CC = cbuild.available()
HAVE_RUNTIME = bool(cbuild.runtime_sources())

needs_cc = pytest.mark.skipif(not HAVE_CC, reason="no C compiler (CI installs one)")
needs_runtime = pytest.mark.skipif(not HAVE_RUNTIME,
                                   reason="the C runtime (templates/c/runtime/*.c) is missing")

_built: dict = {}


def _pair(name, compiled_model):
    """(numpy module, C module) of models/<name>.yaml, built once per worker from the model's
    one compile there (conftest's ``compiled_model``, shared with its golden and symengine
    tests); the C library through the test session's compile cache (the C runtime's objects
    are built once there, and a model another test file builds for C is built once)."""
    if name not in _built:
        path = ROOT / "models" / f"{name}.yaml"
        c = compiled_model(name)
        np_mod = load_module(c.source, f"{name}_np_test")
        _, c_mod = backends.load(f"{name}_c_test", "c", cache_mod.key("c", path), lambda: c,
                                 cache_mod.Cache())
        _built[name] = (np_mod, c_mod)
    return _built[name]


def _param(name):
    # a model's tests share its pair: they go to one xdist worker together (conftest.work_unit)
    return pytest.param(name, marks=pytest.mark.slow) if name in SLOW else name


def _close(a, b, rel=1e-12):
    """|a - b| within rel of the larger magnitude (elementwise, with the array's scale as a
    floor for entries that cancel to near zero)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    scale = np.maximum(np.maximum(np.abs(a), np.abs(b)), 1e-300)
    floor = rel * max(float(np.max(np.abs(b))) if b.size else 0.0, 1e-300) * 1e-3
    both_nan = np.isnan(a) & np.isnan(b)  # an output undefined at a random state in both
    return bool(np.all((np.abs(a - b) <= rel * scale + floor) | both_nan))


def _points(m, rng, k=4):
    """Random states near the initial state (positive where the model needs it: tanks)."""
    x0 = np.asarray(m.X0, float)
    xs = x0[:, None] * (1 + 0.3 * rng.standard_normal((len(x0), k))) + \
        0.2 * rng.standard_normal((len(x0), k)) * (np.abs(x0[:, None]) + 0.1)
    if "rectifier" in m.__name__:  # the 1 mF capacitor across +-100 V: the diode's exp()
        xs = x0[:, None] + 0.1 * rng.uniform(-1, 1, (len(x0), k))  # loop from far off
    if "3r2s_rigid" in m.__name__:  # near the assembled pose: far from it the reactions'
        xs = x0[:, None] * (1 + 1e-3 * rng.standard_normal((len(x0), k)))  # system is near
    return np.abs(xs) if "tanks" in m.__name__ else xs  # singular (entries ~1e5)


@needs_cc
@needs_runtime
@pytest.mark.parametrize("name", [_param(n) for n in MODELS])
def test_rhs_jacobian_outputs_match_numpy(name, compiled_model):
    npm, cm = _pair(name, compiled_model)
    # the rigid 3R2S: its rhs and Jacobian go through a 21x21 numeric solve, whose rounding
    # differs between the C runtime's LU and LAPACK's
    rel = 1e-9 if name == "3r2s_rigid" else 1e-12
    rng = np.random.default_rng(11)
    X = _points(npm, rng)
    for k in range(X.shape[1]):
        t = float(rng.uniform(0, 2))
        x = X[:, k]
        assert _close(cm.rhs(t, x), npm.rhs(t, x), rel), (name, k)
        assert _close(cm.jacobian(t, x), npm.jacobian(t, x), rel), (name, k)
        yc, yn = cm.outputs(t, x), npm.outputs(t, x)
        assert set(yc) == set(yn)
        for o in yn:
            assert yc[o].shape == yn[o].shape and _close(yc[o], yn[o], rel), (name, o)
    # a batch of states at once, and the initial state
    assert _close(cm.rhs(0.5, X), npm.rhs(0.5, X), rel)
    assert _close(cm.jacobian(0.5, X), npm.jacobian(0.5, X), rel)
    assert _close(cm.initial_state(), npm.initial_state())


@needs_cc
@needs_runtime
def test_parameter_batches_broadcast_like_numpy(compiled_model):
    npm, cm = _pair("dc_motor", compiled_model)
    p = {"R_a": np.array([1.0, 2.0, 3.0]), "K": np.array([[0.04], [0.06]])}  # batch (2, 3)
    x = npm.X0 + 0.5
    assert cm.rhs(0.1, x, p).shape == npm.rhs(0.1, x, p).shape == (2, 2, 3)
    assert _close(cm.rhs(0.1, x, p), npm.rhs(0.1, x, p))
    assert _close(cm.jacobian(0.1, x, p), npm.jacobian(0.1, x, p))


def _span(name):
    # the references (scipy's Radau on the numpy module at rtol 1e-11, before conftest's
    # reference_method) are the cost here:
    # the rigid 3R2S's (a 21-unknown reaction solve per call) took 4,233 steps and 30,149
    # calls over a quarter second (73 CPU s for the whole test), about 200 s over 1 s, 1,886
    # steps (30 CPU s) over 0.1 s, 974 (16 CPU s) over 0.05 s: its first 0.05 s are checked,
    # where the C loops take 280-300 steps each (largest error 0.004 of the bound there, 0.006
    # over 0.1 s); the compliant 3R2S's stiff couplings take 8,935 steps (62,782 calls, 20
    # CPU s) over 0.02 s, in which its joint angles move by up to 1e-2 rad (46 CPU s for the
    # whole test over 0.05 s); the rectifier's 76 s over 50 periods (15,000 steps), 23 s over
    # 10 periods (19 CPU s for the whole test), 5 periods kept, each with both diode
    # switchings, and so for the other 50 Hz rectifiers (ideal diodes, a switch: their mode
    # events; over 50 periods the pair's test took 8.4 s, the switch's 6.4 s in a CI run);
    # the top's 48 s over 1 s of its 300 rad/s spin, 14 s over 0.3 s, 0.15 s kept (7 turns)
    return {"van_der_pol": (0.0, 0.5), "3r2s": (0.0, 0.02), "3r2s_rigid": (0.0, 0.05),
            "rectifier": (0.0, 0.1), "rectifier_pair": (0.0, 0.1),
            "rectifier_switch": (0.0, 0.1), "rectifier_ideal": (0.0, 0.1),
            "top": (0.0, 0.15)}.get(name, (0.0, 1.0))


_REFERENCES: dict = {}



def _reference(name, npm, span, x0, ms):
    """scipy's integrator for the model (conftest.reference_method: DOP853, LSODA or Radau)
    on the numpy module at rtol 1e-11, once per model in a worker (both C methods are checked against it; the
    scheduler keeps a model's C tests on one worker)."""
    if name not in _REFERENCES:
        method = reference_method(name)
        _REFERENCES[name] = npm.simulate(span, dt=(span[1] - span[0]) / 50, method=method,
                                         rtol=1e-11, atol=1e-13, x0=x0, max_step=ms)
    return _REFERENCES[name]


@needs_cc
@needs_runtime
@pytest.mark.parametrize("name", [_param(n) for n in MODELS])
@pytest.mark.parametrize("method", ["Rodas4", "Radau"])
def test_whole_runs_match_numpy(name, method, compiled_model):
    """C Rodas4 and Radau at rtol 1e-8 (atol 1e-11) against scipy's DOP853, LSODA or Radau
    (numpy module, _reference) at rtol 1e-11: every state, at every output time, within 1e-5
    of its scale plus 1e-7 (states that stay near zero, such as stiff joint deflections, are held to
    the absolute floor)."""
    npm, cm = _pair(name, compiled_model)
    span = _span(name)
    # off zero head: a square-root orifice has an infinite slope there
    x0 = npm.X0 + 0.1 if name == "two_tanks" else None
    # a periodic input bounds the step as a scene's run does (bgc.run.steps: 50 per period)
    ms = min(getattr(npm, "INPUT_PERIODS", {}).values(), default=np.inf) / 50
    ref = _reference(name, npm, span, x0, ms)
    res = cm.simulate(span, dt=(span[1] - span[0]) / 50, method=method, rtol=1e-8, atol=1e-11,
                      x0=x0, max_step=ms)
    assert res.t.shape == ref.t.shape and np.allclose(res.t, ref.t, rtol=0, atol=1e-12)
    scale = np.max(np.abs(ref.x), axis=-1, keepdims=True)
    err = np.max(np.abs(res.x - ref.x) / (1e-5 * scale + 1e-7))
    assert err < 1, (name, method, err)
    assert res.stats["nsteps"] > 0 and res.stats["nfev"] > res.stats["nsteps"]
    assert set(ref.stats) <= set(res.stats)
    for o in ref.y:
        assert res.y[o].shape == ref.y[o].shape


@needs_cc
@needs_runtime
@pytest.mark.parametrize("method", ["Rodas4", "Radau"])
def test_batch_equals_single_runs(method, compiled_model):
    npm, cm = _pair("dc_motor", compiled_model)
    Ra = np.array([1.0, 2.0, 4.0, 8.0])
    batch = cm.simulate((0, 0.5), dt=0.01, method=method, rtol=1e-7, p={"R_a": Ra})
    assert batch.x.shape == (2, 4, 51)
    for k, r in enumerate(Ra):
        one = cm.simulate((0, 0.5), dt=0.01, method=method, rtol=1e-7, p={"R_a": float(r)})
        # each instance takes its own steps: the same arithmetic as the single run
        assert np.allclose(batch.x[:, k], one.x, rtol=1e-12, atol=1e-15)
        for o in one.y:
            assert np.allclose(batch.y[o][..., k, :], one.y[o], rtol=1e-12, atol=1e-15)


@needs_cc
@needs_runtime
def test_closed_form_msd(compiled_model):
    """The mass-spring-damper's step response against its closed form (no bgc code)."""
    _, cm = _pair("msd", compiled_model)
    m, k, c, F0 = 2.0, 200.0, 4.0, 10.0
    wn, zeta = np.sqrt(k / m), c / (2 * np.sqrt(k * m))
    wd = wn * np.sqrt(1 - zeta ** 2)
    for method in ("Rodas4", "Radau"):
        r = cm.simulate((0, 2), dt=0.01, method=method, rtol=1e-10, atol=1e-13)
        t = r.t
        q = F0 / k * (1 - np.exp(-zeta * wn * t) * (np.cos(wd * t)
                                                   + zeta / np.sqrt(1 - zeta ** 2) * np.sin(wd * t)))
        assert np.max(np.abs(r.y["position"] - q)) < 1e-8 * F0 / k * 100


@needs_cc
@needs_runtime
def test_nonfinite_is_located(compiled_model):
    """A zero mass makes the velocity p/m non-finite: the error names the state and time."""
    _, cm = _pair("msd", compiled_model)
    with pytest.raises(cm.SimulationError) as exc:
        cm.simulate((0, 1), dt=0.1, method="Rodas4", p={"m": 0.0})
    msg = str(exc.value)
    assert "non-finite" in msg and "t = 0" in msg
    assert any(repr(s) in msg for s in cm.STATE_NAMES), msg
    assert exc.value.t == 0.0 and "nfev" in exc.value.stats


@needs_cc
@needs_runtime
def test_other_methods_and_input_overrides_use_the_python_loop(compiled_model):
    npm, cm = _pair("msd", compiled_model)
    a = cm.simulate((0, 1), dt=0.1, method="RK45", rtol=1e-9, atol=1e-12)
    b = npm.simulate((0, 1), dt=0.1, method="RK45", rtol=1e-9, atol=1e-12)
    assert np.allclose(a.x, b.x, rtol=1e-9, atol=1e-12)
    u = {"F": lambda t: 5.0 + 0 * np.asarray(t)}
    # u= runs in the numpy module of the same model, which bgc's loader (bgc.run.driver.build)
    # hands the wrapper; loaded here by hand, the test hands it over itself
    cm._NUMPY_MODULE = lambda: npm
    x = npm.X0 + 1
    assert _close(cm.rhs(0.0, x, u=u), npm.rhs(0.0, x, u=u))
    # only the force changes: dp/dt by F - F0 = 5 - 10 N (msd's F0), dq/dt not at all
    assert _close(cm.rhs(0.0, x, u=u) - cm.rhs(0.0, x), np.array([-5.0, 0.0]))


# ---------------------------------------------------------------------------------------------
# The C text door, checked by the C compiler itself

_WEIRD = ['plain', 'quote " and backslash \\ and ??/ trigraph', "new\nline\r\ttab",
          "star */ comment /* open", "unicode \u00e9\u2028\U0001F600", "\x00nul\x7f", "%s%n"]


@needs_cc
def test_c_string_literal_round_trips_through_the_compiler(tmp_path):
    src = ["#include <stdio.h>", "int main(void) {"]
    for s in _WEIRD:
        src.append(f"  fwrite({c_string_literal(s)}, 1, sizeof({c_string_literal(s)}) - 1, "
                   "stdout); putchar(255);")
        src.append(f"  /* {c_comment(s)} */")
    src += ["  return 0;", "}"]
    (tmp_path / "t.c").write_text("\n".join(src) + "\n", encoding="ascii")
    subprocess.run(cbuild.compiler() + ["-std=c99", "-Werror", "-o", str(tmp_path / "t"),
                                        str(tmp_path / "t.c")], check=True, capture_output=True)
    out = subprocess.run([str(tmp_path / "t")], capture_output=True, check=True).stdout
    parts = out.split(b"\xff")[:-1]  # 0xff never occurs in UTF-8
    assert parts == [s.encode("utf-8") for s in _WEIRD]


def test_c_comment_cannot_end_the_comment():
    for s in _WEIRD + ["*/*/", "**//", "a*\u200b/"]:
        c = c_comment(s)
        assert "*/" not in c and "/*" not in c and "??" not in c and c.isascii()
        assert "\n" not in c and "\r" not in c


# ---------------------------------------------------------------------------------------------
# Golden C sources (scripts/regenerate.py writes them)

@pytest.mark.parametrize("name", ["msd", "dc_motor"])
def test_generated_c_is_golden(name, compiled_model):
    c = compiled_model(name)
    files, wrapper = backends.c_files(c)
    gold = ROOT / "generated" / "c" / name
    assert sorted(p.name for p in gold.glob("*.c")) == sorted(files)
    for fname, text in files.items():
        assert text == (gold / fname).read_text(encoding="utf-8"), (
            f"generated/c/{name}/{fname} differs: review, then run scripts/regenerate.py")
    # deterministic: a second rendering is the same text
    again, _ = backends.c_files(compile_file(ROOT / "models" / f"{name}.yaml"))
    assert again == files


# ---------------------------------------------------------------------------------------------
# The command line

def _bgc(*args, env=None, cwd=None):
    return subprocess.run([sys.executable, "-m", "bgc", *args], capture_output=True, text=True,
                          env={**os.environ, **(env or {})}, cwd=cwd, timeout=600)


def test_without_a_compiler_simulate_falls_back_to_numpy(tmp_path):
    out = tmp_path / "r.npz"
    p = _bgc("simulate", str(ROOT / "models/scenes/msd_step.yaml"), "--backend", "c", "--out",
             str(out), env={"CC": "/nonexistent/cc", "BGC_CACHE_DIR": str(tmp_path / "cache")})
    assert p.returncode == 0, p.stderr
    assert "no C compiler" in p.stderr and "numpy" in p.stderr
    assert "(numpy backend; fell back from c, see above)" in p.stdout
    assert out.is_file()


@needs_cc
@needs_runtime
def test_simulate_defaults_to_c_where_a_compiler_works(tmp_path, monkeypatch):
    """No --backend and no solver backend in the scene: C for a method the C step loop runs,
    numpy for one it does not; the summary line says which and why."""
    # runtime objects built
    monkeypatch.setenv("BGC_CACHE_DIR", str(seed_c_runtime(tmp_path / "cache")))
    scene = str(ROOT / "models/scenes/msd_step.yaml")
    p = bgc_in_process("simulate", scene, "--out", str(tmp_path / "c.npz"))
    assert p.returncode == 0, p.stderr
    assert "(c backend; default: a C compiler works)" in p.stdout
    q = bgc_in_process("simulate", scene, "--method", "BDF")
    assert q.returncode == 0, q.stderr
    assert "(numpy backend; default: BDF has no C step loop)" in q.stdout
    r = bgc_in_process("simulate", scene, "--backend", "numpy", "--out", str(tmp_path / "n.npz"))
    assert r.returncode == 0 and "(numpy backend)" in r.stdout, r.stderr
    a, b = np.load(tmp_path / "c.npz"), np.load(tmp_path / "n.npz")
    assert np.max(np.abs(a["position"] - b["position"])) < 1e-5 * np.max(np.abs(b["position"]))


@needs_cc
def test_a_big_models_units_build_at_O0(tmp_path):
    """Units that together pass BIG_MODEL_BYTES get -O0 in place of -O2; smaller ones -O2."""
    (tmp_path / "a.c").write_text("int a;\n")
    assert "-O2" in cbuild.model_flags(tmp_path, ["a.c"])
    (tmp_path / "b.c").write_text("/*" + "x" * cbuild.BIG_MODEL_BYTES + "*/\nint b;\n")
    fl = cbuild.model_flags(tmp_path, ["a.c", "b.c"])
    assert "-O0" in fl and "-O2" not in fl and "-fPIC" in fl


@pytest.mark.parametrize("cc", ["/nonexistent/cc", "/bin/false"])
def test_without_a_working_compiler_simulate_defaults_to_numpy_with_a_note(tmp_path, cc):
    """CC naming nothing, or a program that is no compiler (`false --version` fails): the
    default is numpy, said on the summary line, and the run completes."""
    out = tmp_path / "r.npz"
    p = _bgc("simulate", str(ROOT / "models/scenes/msd_step.yaml"), "--out", str(out),
             env={"CC": cc, "BGC_CACHE_DIR": str(tmp_path / "cache")})
    assert p.returncode == 0, p.stderr
    assert f"(numpy backend; default: no C compiler ({cc!r} cannot run))" in p.stdout
    assert out.is_file() and "Traceback" not in p.stderr


def test_compile_target_c_without_a_compiler_is_one_clear_error(tmp_path):
    p = _bgc("compile", str(ROOT / "models/msd.yaml"), "--target", "c", "-o",
             str(tmp_path / "out"), env={"CC": "/nonexistent/cc"})
    assert p.returncode == 2
    assert "no C compiler" in p.stderr and "Traceback" not in p.stderr


@needs_cc
@needs_runtime
def test_compile_target_c_writes_an_importable_folder(tmp_path):
    out = tmp_path / "out"
    p = _bgc("compile", str(ROOT / "models/msd.yaml"), "--target", "c", "-o", str(out), "-q")
    assert p.returncode == 0, p.stderr
    assert (out / "model.c").is_file() and (out / cbuild.LIB_NAME).is_file()
    assert (out / "runtime" / "bgc_runtime.h").is_file()
    code = ("import importlib.util, sys, numpy as np\n"
            "sys.modules['bgc'] = None\n"
            f"spec = importlib.util.spec_from_file_location('w', {str(out / 'msd.py')!r})\n"
            "m = importlib.util.module_from_spec(spec); spec.loader.exec_module(m)\n"
            "r = m.simulate((0, 1), dt=0.5, method='Rodas4')\n"
            "print(m._LIB is not None, r.x.shape)\n")
    q = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path)
    assert q.returncode == 0, q.stderr
    assert q.stdout.split() == ["True", "(2,", "3)"]


@needs_cc
@needs_runtime
def test_simulate_backend_c_agrees_with_numpy(tmp_path, monkeypatch):
    # runtime objects built
    monkeypatch.setenv("BGC_CACHE_DIR", str(seed_c_runtime(tmp_path / "cache")))
    scene = str(ROOT / "models/scenes/msd_step.yaml")
    a = bgc_in_process("simulate", scene, "--backend", "c", "--out", str(tmp_path / "c.npz"),
                       "--rtol", "1e-9", "--atol", "1e-12")
    b = bgc_in_process("simulate", scene, "--backend", "numpy", "--out",
                       str(tmp_path / "n.npz"), "--rtol", "1e-9", "--atol", "1e-12")
    assert a.returncode == 0 and b.returncode == 0, a.stderr + b.stderr
    assert "(c backend)" in a.stdout and "atol=1e-12" in a.stdout and "compile" in a.stdout
    ra, rb = np.load(tmp_path / "c.npz"), np.load(tmp_path / "n.npz")
    assert np.allclose(ra["t"], rb["t"])
    assert np.max(np.abs(ra["position"] - rb["position"])) < 1e-7 * np.max(np.abs(rb["position"]))


@needs_cc
@needs_runtime
def test_c_rodas4_takes_the_numpy_rodas4_steps(compiled_model):
    """The C Rodas4 and the numpy module's Rodas4 are two implementations of one method (same
    tableau, error norm and step control): on the step response they take the same steps and
    agree far below the tolerance."""
    npm, cm = _pair("msd", compiled_model)
    a = cm.simulate((0, 2), dt=0.01, method="Rodas4", rtol=1e-6, atol=1e-9)
    b = npm.simulate((0, 2), dt=0.01, method="Rodas4", rtol=1e-6, atol=1e-9)
    assert abs(a.stats["nsteps"] - b.stats["nsteps"]) <= max(2, b.stats["nsteps"] // 50)
    assert np.max(np.abs(a.x - b.x)) < 1e-9 * np.max(np.abs(b.x))


def test_c_names_avoid_keywords_and_the_library():
    from bgc.backends.c.printer import c_name

    for nm in ("double", "sin", "y0", "j1", "NAN", "bgc_x", "restrict", "FP_NAN"):
        assert c_name(nm) != nm and c_name(nm).isidentifier()
    for nm in ("m", "k_t", "p_mass", "link1__Ixx", "t"):
        assert c_name(nm) == nm
