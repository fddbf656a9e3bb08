"""Shared fixtures for the example-model tests.

``gen(name)`` imports the module bgc generated for ``models/<name>.yaml`` straight from its
file, ``generated/<name>.py``, so the tests exercise exactly what bgc wrote (the generated
module must be importable standalone: nothing of bgc is on the path for it).
``BGC_GENERATED_DIR`` may point at another directory of generated modules.

``bgc_cli(*args)`` runs the bgc command line and returns the CompletedProcess.

``compiled_model(stem)`` is ``compile_file("models/<stem>.yaml")``, compiled once per worker:
the golden, symengine and C-backend tests of a model share one compile (their tests of one
model go to one worker together: ``work_unit``).
"""
from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
import tempfile
from functools import cache, lru_cache
from pathlib import Path

import pytest

# One BLAS thread per process, set before numpy is first imported: the suite runs in two
# workers (pytest -n 2) on two cores and solves many small dense systems, where OpenBLAS's
# threads only contend with the other worker (under load a 95x95 LU took ~47 ms instead of
# ~0.1 ms). Subprocesses started by the tests inherit it.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
# The compile cache of the whole test session: a fresh private directory (never the user's),
# inherited by the subprocesses the tests start.
os.environ.setdefault("BGC_CACHE_DIR", tempfile.mkdtemp(prefix="bgc-test-cache-"))

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT / "models"
GENERATED = Path(os.environ.get("BGC_GENERATED_DIR", ROOT / "generated"))


_modules: dict[str, object] = {}


def _import_generated(name: str):
    if name in _modules:
        return _modules[name]
    path = GENERATED / f"{name}.py"
    if not path.is_file():
        pytest.fail(f"{path} does not exist: compile models/{name}.yaml with bgc first")
    modname = f"bgc_generated_{name}"
    spec = importlib.util.spec_from_file_location(modname, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[modname] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        sys.modules.pop(modname, None)
        raise
    _modules[name] = module
    return module


@pytest.fixture(scope="session")
def gen():
    """``gen(name)`` -> the generated module for models/<name>.yaml."""
    return _import_generated


@lru_cache(maxsize=6)  # a model's tests run one after another (one unit): a few suffice
def _compiled_model(stem: str):
    from bgc.run.driver import compile_file

    return compile_file(MODELS / f"{stem}.yaml")


@pytest.fixture(scope="session")
def compiled_model():
    """``compiled_model(stem)`` -> bgc.run.driver.compile_file of models/<stem>.yaml, once per
    worker (callers must not change what it returns)."""
    return _compiled_model


_SESSION_CACHE = Path(os.environ["BGC_CACHE_DIR"])


@cache
def _session_runtime() -> Path | None:
    """The session cache's ``c-runtime`` folder once the C runtime's objects (and the
    compiler's facts: identity, OpenMP) are in it, built once per worker; None without a
    compiler or runtime."""
    from bgc.backends.c import build
    from bgc.base.store import Cache

    saved = os.environ.get("BGC_CACHE_DIR")
    os.environ["BGC_CACHE_DIR"] = str(_SESSION_CACHE)  # (a test may have pointed it elsewhere)
    try:
        if not (build.available() and build.runtime_sources()):
            return None
        build.flags()
        build._runtime_objects(Cache(_SESSION_CACHE), 1, None)
    finally:
        if saved is None:
            os.environ.pop("BGC_CACHE_DIR", None)
        else:
            os.environ["BGC_CACHE_DIR"] = saved
    return _SESSION_CACHE / "c-runtime"


def seed_c_runtime(cache_dir) -> Path:
    """``cache_dir`` (made if missing, mode 700) holding a copy of the session cache's
    ``c-runtime`` entries: the C runtime's objects and the compiler's facts, so that a test's
    fresh cache does not rebuild the runtime (1.4-2 s of CPU each time). For tests whose
    property is not the runtime's build; the model's own entries still start empty."""
    import shutil

    cache_dir = Path(cache_dir)
    cache_dir.mkdir(parents=True, mode=0o700, exist_ok=True)
    src = _session_runtime()
    if src is not None and src.is_dir():
        shutil.copytree(src, cache_dir / "c-runtime", dirs_exist_ok=True,
                        ignore=shutil.ignore_patterns(".*"))
    return cache_dir


@pytest.fixture(scope="session")
def c_runtime_seed():
    """``c_runtime_seed(cache_dir)`` -> cache_dir seeded with the C runtime's built objects
    (:func:`seed_c_runtime`)."""
    return seed_c_runtime


def _bgc_command() -> list[str]:
    exe = Path(sys.executable).with_name("bgc")
    if exe.exists():
        return [str(exe)]
    return [sys.executable, "-m", "bgc"]


@pytest.fixture(scope="session")
def bgc_cli():
    """``bgc_cli(*args)`` runs ``bgc args...`` from the repository root."""
    def run(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
        env = dict(os.environ)
        src = str(ROOT / "src")
        env["PYTHONPATH"] = src + os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else src
        return subprocess.run(_bgc_command() + list(args), cwd=ROOT, env=env, text=True,
                              capture_output=True, timeout=timeout, stdin=subprocess.DEVNULL)
    return run



# ---------------------------------------------------------------------------------------------
# How the two xdist workers share the work (pytest -n 2). xdist's default hands out single
# tests, so a module-scoped fixture (a compiled 3R2S scene, a set of FMUs, a Dask cluster) is
# built by each worker that runs one of its tests. Here a module that has module-scoped
# fixtures goes to one worker as one unit (so each is built once), the golden, symengine and
# C-backend tests of one example model go together (they share its compile, ``compiled_model``,
# and its C build), and the units holding a test marked slow go first, so that the two workers
# finish together. (xdist's own `--dist loadgroup` marks do not take under pytest 9: xdist
# renames node ids through an attribute pytest 9 no longer reads.)

_MODULE_SCOPED = re.compile(r"""scope\s*=\s*["']module["']""")
# the tests of one example model that share its compile (``compiled_model``) and its C build
_PER_MODEL = re.compile(
    r"^tests/(?:test_c_backend\.py::test_(?:rhs_jacobian_outputs_match_numpy|whole_runs_match_"
    r"numpy)\[(?:Rodas4-|Radau-)?|test_golden\.py::test_compiling_reproduces_the_golden_file\["
    r"|test_fastsym\.py::test_symengine_equals_sympy\[)([^\]]+?)(?:\.yaml)?\]$")


@cache
def _has_module_fixtures(path: str) -> bool:
    try:
        return bool(_MODULE_SCOPED.search((ROOT / path).read_text(encoding="utf-8")))
    except OSError:
        return False


# tests of one file that build the same compile-cache entries: unit name -> node ids. Two
# workers missing one entry at once build it once (bgc.base.store's per-entry lock), but the
# second waits idle for the first's build (a C build of the 3R2S takes minutes): one worker
# runs them one after another, while the other worker takes other tests
_SHARED_BUILDS = {
    "closed_loop_refs:3r2s": re.compile(  # the circle scenes' C builds, compliant and rigid
        r"^tests/test_closed_loop_refs\.py::test_(?:compliant_3r2s_converges_to_the_rigid_"
        r"(?:ik|3r2s)|rigid_3r2s_circle_follows_its_own_ik)$"),
    "model:msd": re.compile(  # test_c_backend's tests on msd's pair
        r"^tests/test_c_backend\.py::test_(?:closed_form_msd|nonfinite_is_located|other_methods_"
        r"and_input_overrides_use_the_python_loop|c_rodas4_takes_the_numpy_rodas4_steps|"
        r"generated_c_is_golden\[msd\])$"),
    "model:dc_motor": re.compile(  # and on dc_motor's
        r"^tests/test_c_backend\.py::test_(?:parameter_batches_broadcast_like_numpy|batch_equals_"
        r"single_runs\[\w+\]|generated_c_is_golden\[dc_motor\])$"),
    "closed_loop_refs:fourbar": re.compile(  # the four-bars' C builds (its _compiled)
        r"^tests/test_closed_loop_refs\.py::test_(?:rigid_fourbar_against_the_reference|"
        r"compliant_fourbar_converges_to_the_(?:rigid_model|reference_as_1_over_k))$"),
}


def work_unit(nodeid: str) -> str:
    """The unit of work a test goes to a worker in: its module's, its model's, its shared
    builds', or its own."""
    m = _PER_MODEL.match(nodeid)
    if m:
        return f"model:{m.group(1)}"
    for unit, pattern in _SHARED_BUILDS.items():
        if pattern.match(nodeid):
            return unit
    path = nodeid.split("::", 1)[0]
    return path if _has_module_fixtures(path) else nodeid


@pytest.hookimpl(optionalhook=True)  # xdist's hook: nothing without xdist
def pytest_xdist_make_scheduler(config, log):
    if config.getvalue("dist") != "load":  # another --dist asked for: xdist's own
        return None
    from xdist.scheduler import LoadScopeScheduling

    # units in the order of their first test (the workers sort slow tests first), not by size
    config.option.loadscopereorder = False

    class Units(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return work_unit(nodeid)

    return Units(config, log)


def pytest_collection_modifyitems(config, items):
    if hasattr(config, "workerinput"):  # an xdist worker: its units keep a module together
        items.sort(key=lambda item: item.get_closest_marker("slow") is None)  # stable


# ---------------------------------------------------------------------------------------------
# `bgc ARGS` in the test's own process: what `python -m bgc` runs (bgc.cli.launch.main: the
# run-record replay, then click), without starting an interpreter and importing bgc again
# (0.5-1 s a call). For tests whose property is not about the process (its exit through
# os._exit, its imports, a compiler identity probed once per process): those keep subprocesses.


def bgc_in_process(*args, env: dict | None = None, cwd=None) -> subprocess.CompletedProcess:
    """``bgc ARGS`` through :func:`bgc.cli.launch.main` in this process, with ``env``'s
    variables set (and restored after), stdout and stderr captured: a CompletedProcess whose
    returncode is the SystemExit's status (1 and the traceback on stderr for an exception
    that escapes, as the interpreter would)."""
    import contextlib
    import io
    import traceback

    # lazy: a test helper; bgc loads when a test runs it
    from bgc.cli.launch import main

    argv = [str(a) for a in args]
    out, err = io.StringIO(), io.StringIO()
    saved = {k: os.environ.get(k) for k in (env or {})}
    here = os.getcwd()
    code = 0
    try:
        os.environ.update({k: str(v) for k, v in (env or {}).items()})
        if cwd is not None:
            os.chdir(cwd)
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                main(argv)
            except SystemExit as exc:
                c = exc.code
                code = 0 if c is None else c if isinstance(c, int) else 1
                if not isinstance(c, (int, type(None))):
                    print(c, file=sys.stderr)
            except Exception:  # noqa: BLE001 - what the interpreter would print
                traceback.print_exc()
                code = 1
    finally:
        os.chdir(here)
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    return subprocess.CompletedProcess(["bgc", *argv], code, out.getvalue(), err.getvalue())


# ---------------------------------------------------------------------------------------------
# scipy's integrator for a reference run of an example model (scipy's, so it shares no code
# with bgc's runtimes), chosen by the model's stiffness over the tests' spans, all at the
# tests' own tolerances. DOP853 (explicit, order 8) for the models that are not stiff: it meets
# rtol 1e-11 in far fewer steps than Radau, each without a Newton iteration or an LU (on the
# numpy modules, steps DOP853 against Radau: msd 45 against 1,872, rlc 223 against 3,531,
# quarter_car 140 against 3,341, point_mass_3d 70 against 2,894, the rectifier 356 against
# 1,834, the rigid 3R2S 52 against 974; the references differ by at most 7e-4 of the bound
# test_c_backend holds the C runs to). LSODA (ODEPACK's Adams and BDF, switched by stiffness)
# for the stiff ones where it beats Radau: the compliant 3R2S 7,991 steps and 15,253 calls
# against Radau's 8,935 and 62,782, the compliant four-bar 4.0 s against 14.3 s (references
# 2e-3 and 7e-5 of the bound apart). Radau for the rest: van_der_pol and the ideal rectifier
# (LSODA no faster), two_mass_chain (its fastest mode, 1.4e4 1/s, holds DOP853 at its
# stability limit), two_tanks (its orifices' square roots have no finite Jacobian at an empty
# tank, which DOP853's stiffness check at the start evaluates), and any new model.
NONSTIFF_MODELS = frozenset({
    "3r2s_rigid", "algebraic_loop", "dc_motor", "double_pendulum_rigid", "fourbar_rigid",
    "motor_thermal", "msd", "pendulum", "point_mass_3d", "quarter_car", "rectifier",
    "rectifier_pair", "rectifier_switch", "rlc", "stick_slip", "three_rod_rigid", "top"})
LSODA_MODELS = frozenset({"3r2s", "fourbar_compliant"})


def reference_method(model: str) -> str:
    """scipy's method for a reference run of models/<model>.yaml (see above)."""
    return "DOP853" if model in NONSTIFF_MODELS else "LSODA" if model in LSODA_MODELS \
        else "Radau"
