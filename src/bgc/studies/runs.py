"""The runs of a work-precision study (bgc.studies.accuracy): the scene compiled once (Setup),
one solve of it, a solve in a forked child with a deadline, the two-way reference, the errors
against it, and the measured run (wall time, steps, evaluations).

Every measured solve runs in a forked child (:func:`run_isolated`): the rhs and Jacobian raise
:class:`BudgetExceeded` once the budget is spent, and the child is killed if it still has not
answered :data:`GRACE` seconds after it.
"""
from __future__ import annotations

import contextlib
import math
import multiprocessing as mp
import os
import time
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from bgc.backends.c import build as cbuild
from bgc.base.errors import ModelError, SimulationFailed
from bgc.core.signals import input_breakpoints
from bgc.format.scene import initial_state, parse_scene
from bgc.run.runner import compile_scene, scene_module

METHODS = ("RK45", "DOP853", "Radau", "BDF", "LSODA", "Rodas4")
# the C backend's integrators (the whole step loop in the scene's compiled library)
C_METHODS = ("C-Rodas4", "C-Radau")
# every C method a study may name: DOP853 in C too (the non-stiff reference's check)
C_ALL = C_METHODS + ("C-DOP853",)
ALL_METHODS = ("RK45", "RK23", "DOP853", "Radau", "BDF", "LSODA", "Rodas4") + C_ALL
IMPLICIT = ("Radau", "BDF", "LSODA", "Rodas4") + C_METHODS
# the implicit methods that also run on finite-difference Jacobians (Rodas4 needs the exact one)
FD_JACOBIAN = ("Radau", "BDF", "LSODA")
DEFAULT_TOLS = tuple(10.0 ** -k for k in range(3, 11))
JAC_MODES = ("analytic", "sparse-fd", "dense-fd")
STIFF_THRESHOLD = 1e3  # max|eig(J(t0, x0))| * span above this: the scene is treated as stiff
GRACE = 20.0  # seconds a child gets past its budget before it is killed (at most)


def grace(budget: float) -> float:
    """The seconds past its budget a run's child gets before it is killed: a quarter of the
    budget and 2 s, at most GRACE (a solver that does not call back in time, as LSODA's
    Fortran loop, would otherwise hold a short run for GRACE seconds more)."""
    return min(GRACE, 2.0 + budget / 4)


class BudgetExceeded(Exception):
    """Raised from inside the rhs/Jacobian once a run's deadline has passed."""


# --------------------------------------------------------------------------------------------
# setup and single runs


@dataclass
class Setup:
    """Everything a run needs: the compiled scene module and how to call simulate."""

    name: str
    scene: object
    module: object
    p: dict | None
    t_span: tuple
    t_eval: np.ndarray
    breakpoints: tuple
    max_step: float
    outputs: tuple
    atol_scale: float
    compile_time: float = 0.0
    compiled: object = None  # the Compiled scene module (for diagnoses)
    cmodule: object = None  # the C backend's module, for the C methods (made on first use)
    source: str = ""  # the module's source text: Dask workers compile their own copy
    x0: object = None  # the scene's initial state (its initial:), None for the module's own


def prepare(scene_path, t_end=None, atol_scale=None, breakpoints=(), progress=None) -> Setup:
    """Parse and compile the scene. t_end shortens the span; atol_scale defaults to atol/rtol;
    breakpoints are added to the scene's (instants where an input jumps)."""
    try:  # scene parameters not marked free are compiled into the module
        from bgc.format.scene import free_values as values
    except ImportError:  # pragma: no cover - older layout
        from bgc.format.scene import param_values as values

    scene = scene_path if hasattr(scene_path, "t_span") else parse_scene(scene_path)
    t0c = time.perf_counter()
    compiled, mod = compile_scene(scene, progress)
    ct = time.perf_counter() - t0c
    t0, t1 = scene.t_span
    if t_end is not None:
        if not t0 < t_end <= t1:
            raise ModelError(scene.coord, f"--t-end {t_end:g} is outside the scene's span "
                                          f"({t0:g}, {t1:g}]")
        t1 = float(t_end)
    dt = scene.dt or (t1 - t0) / 1000
    n = int(round((t1 - t0) / dt))
    t_eval = np.linspace(t0, t1, n + 1)
    outs = scene.outputs or tuple(mod.OUTPUT_NAMES)
    if atol_scale is None:
        atol_scale = scene.atol / scene.rtol
    if not atol_scale > 0:
        raise ModelError(scene.coord, "the atol scale must be positive")
    # the instants where an input expression jumps (where(t < 1, ...)) are breakpoints too:
    # at rtol 1e-12 no integrator steps through a jump it is not told of
    jumps = input_breakpoints(compiled.equations)
    p = values(scene) or None
    x0 = initial_state(scene, mod, p)  # the scene's start, as `bgc simulate` takes it
    return Setup(Path(scene.file).stem, scene, mod, p, (t0, t1),
                 t_eval, tuple(sorted({float(b) for b in (*scene.breakpoints, *breakpoints,
                                                          *jumps) if t0 < b < t1})),
                 scene.max_step,
                 outs, float(atol_scale), ct, compiled=compiled, source=compiled.source,
                 x0=x0)


@contextlib.contextmanager
def _instrumented(mod, deadline, dense_fd):
    """Deadline checks in the module's rhs and jacobian: they raise BudgetExceeded once the
    deadline has passed, even in the middle of a solver step. dense_fd: a full sparsity
    pattern, so that finite differences take one rhs call per state per Jacobian.

    (Inputs are one-sided at breakpoints inside the generated simulate itself.)"""
    rhs0, jac0, pattern0 = mod.rhs, mod.jacobian, mod.JAC_SPARSITY

    def rhs(*a, **k):
        if time.perf_counter() > deadline:
            raise BudgetExceeded("time budget exceeded")
        return rhs0(*a, **k)

    def jacobian(*a, **k):
        if time.perf_counter() > deadline:
            raise BudgetExceeded("time budget exceeded")
        return jac0(*a, **k)

    mod.rhs, mod.jacobian = rhs, jacobian
    if dense_fd:
        mod.JAC_SPARSITY = np.ones_like(pattern0)
    try:
        yield
    finally:
        mod.rhs, mod.jacobian, mod.JAC_SPARSITY = rhs0, jac0, pattern0


def solve(setup: Setup, method, rtol, atol, jac_mode="analytic", deadline=math.inf):
    """One simulate call; returns (SimResult, stats: nfev, njev, nlu, nsteps).

    njev counts every Jacobian the solver formed, finite-difference ones included (their rhs
    calls are in nfev)."""
    if method in C_ALL:  # one call into C: the budget is its wall-time limit
        mod = c_module(setup)
        wall = None if math.isinf(deadline) else max(deadline - time.perf_counter(), 1e-3)
        try:
            res = mod.simulate(setup.t_span, t_eval=setup.t_eval, method=method[2:], rtol=rtol,
                               atol=atol, p=setup.p, x0=setup.x0, breakpoints=setup.breakpoints,
                               max_step=setup.max_step, max_wall=wall, max_steps=10 ** 7)
        except mod.SimulationError as exc:
            if "wall time" in str(exc):
                raise BudgetExceeded(str(exc)) from None
            raise
        stats = {k: int(res.stats[k]) for k in ("nfev", "njev", "nlu", "nsteps")}
        return res, stats
    mod = setup.module
    with _instrumented(mod, deadline, jac_mode == "dense-fd"):
        res = mod.simulate(setup.t_span, t_eval=setup.t_eval, method=method, rtol=rtol,
                           atol=atol, p=setup.p, x0=setup.x0, breakpoints=setup.breakpoints,
                           jac=jac_mode == "analytic", max_step=setup.max_step,
                           max_steps=10 ** 7)  # the budget bounds a study's runs
    stats = {k: int(res.stats[k]) for k in ("nfev", "njev", "nlu", "nsteps")}
    return res, stats


def c_available() -> bool:
    """A C compiler and the C runtime: the C methods can run."""
    return cbuild.available() and bool(cbuild.runtime_sources())


def c_module(setup: Setup):
    """The scene's C-backend module (built once, through the compile cache)."""
    if setup.cmodule is None:
        backend, mod = scene_module(setup.scene, None, "c")
        if backend != "c":
            raise ModelError(None, "the C methods need a C compiler (set CC)")
        setup.cmodule = mod
    return setup.cmodule


def run_isolated(fn, timeout):
    """fn() in a forked child, killed after `timeout` s. Returns ("ok", value) or
    ("error", message) or ("killed", message). Without fork, runs fn() here."""
    if "fork" not in mp.get_all_start_methods():  # pragma: no cover - not Linux
        try:
            return "ok", fn()
        except Exception as exc:  # noqa: BLE001 - reported, not raised
            return "error", exc
    ctx = mp.get_context("fork")
    rd, wr = ctx.Pipe(duplex=False)

    def target():
        try:
            out = ("ok", fn())
        except BaseException as exc:  # noqa: BLE001
            out = ("error", exc if _picklable(exc) else RuntimeError(f"{type(exc).__name__}: {exc}"))
        try:
            wr.send(out)
        finally:
            wr.close()
            os._exit(0)

    proc = ctx.Process(target=target, daemon=True)
    proc.start()
    wr.close()
    try:
        if rd.poll(timeout):
            try:
                return rd.recv()
            except EOFError:
                return "error", RuntimeError(f"the worker died (exit code {proc.exitcode})")
        return "killed", BudgetExceeded(f"no answer after {timeout:.0f} s: killed")
    finally:
        if proc.is_alive():
            proc.kill()
        proc.join()
        rd.close()


def _picklable(obj):
    import pickle

    try:
        pickle.dumps(obj)
        return True
    except Exception:  # noqa: BLE001
        return False


# --------------------------------------------------------------------------------------------
# reference and errors


@dataclass
class Reference:
    method: str
    rtol: float
    atol: float
    t: np.ndarray
    x: np.ndarray
    y: dict
    wall: float
    stats: dict


#: How many of a pilot run's shortest steps (and evenly spread ones) is_stiff looks at.
STIFF_SAMPLES = 8


def _spectral_radius(mod, t, x, p) -> float:
    """max|eig(J(t, x))|; inf where the Jacobian is not finite (simulate would stop on it)."""
    x = np.asarray(x, dtype=float).reshape(-1)
    n = x.size
    with np.errstate(all="ignore"):
        J = np.asarray(mod.jacobian(t, x, p)).reshape(n, n)
    if not np.all(np.isfinite(J)):
        return math.inf
    return float(np.max(np.abs(np.linalg.eigvals(J)))) if n else 0.0


def _pilot_states(setup: Setup):
    """(time, state) pairs along a loose Radau run (rtol 1e-4), or none when that run fails:
    the states before its STIFF_SAMPLES shortest steps (where something fast happens: a
    contact that closes, a valve that shuts) and at STIFF_SAMPLES evenly spread steps, so a
    model that is stiff only later is judged where it is stiff, not at t0 alone."""
    # the C backend's module when the study has built it (the whole run in C: seconds less)
    mod = setup.cmodule if setup.cmodule is not None else setup.module
    try:
        with np.errstate(all="ignore"):
            res = mod.simulate(setup.t_span, method="Radau", rtol=1e-4,
                                        atol=1e-4 * setup.atol_scale, p=setup.p, x0=setup.x0,
                                        breakpoints=setup.breakpoints,
                                        max_step=setup.max_step, max_wall=30.0)
    except Exception:  # noqa: BLE001 - the study's own runs report failures
        return ()
    t = np.asarray(res.t, dtype=float)
    if t.size < 2:
        return ()
    X = np.asarray(res.x).reshape(setup.module.N_STATES, -1)
    h = np.diff(t)
    pick = set(np.argsort(h, kind="stable")[:STIFF_SAMPLES].tolist())
    pick |= set(np.linspace(0, t.size - 2, STIFF_SAMPLES).astype(int).tolist())
    return [(float(t[k]), X[:, k]) for k in sorted(pick)]


def is_stiff(setup: Setup) -> tuple[bool, float]:
    """(stiff, stiffness index): the index is the largest max|eig J| times the span, of the
    Jacobian at t0 and at states along a loose pilot run (_pilot_states)."""
    mod = setup.module
    x0 = (mod.initial_state(setup.p) if setup.x0 is None else np.asarray(setup.x0)).reshape(-1)
    rho = _spectral_radius(mod, setup.t_span[0], x0, setup.p)
    if math.isfinite(rho):
        for t, x in _pilot_states(setup):
            rho = max(rho, _spectral_radius(mod, t, x, setup.p))
    index = rho * (setup.t_span[1] - setup.t_span[0])
    return index > STIFF_THRESHOLD, index


def warm_up(setup: Setup):
    """Import what simulate imports lazily (about a second), so that every forked child
    inherits it instead of paying for it inside its measured wall time."""
    import scipy.integrate  # noqa: F401
    import scipy.linalg  # noqa: F401
    import scipy.sparse  # noqa: F401

    t0, t1 = setup.t_span
    for m in ("RK45", "Radau", "BDF", "LSODA", "Rodas4"):
        try:
            te = np.array([t0, t0 + 1e-6 * (t1 - t0)])
            solve(replace(setup, t_span=tuple(te), t_eval=te, breakpoints=()),
                  m, 1e-3, 1e-3 * setup.atol_scale, "analytic", time.perf_counter() + 5.0)
        except Exception:  # noqa: BLE001 - only warming up
            pass


def reference(setup: Setup, method, rtol, atol, budget) -> Reference:
    def work():
        t0 = time.perf_counter()
        res, st = solve(setup, method, rtol, atol, "analytic", t0 + budget)
        wall = time.perf_counter() - t0
        return Reference(method, rtol, atol, np.asarray(res.t), np.asarray(res.x),
                         {k: np.asarray(res.y[k]) for k in setup.outputs}, wall, st)

    status, val = run_isolated(work, budget + GRACE)
    if status != "ok":
        hint = ("raise --ref-budget or loosen --ref-rtol" if isinstance(val, BudgetExceeded)
                else "an input that jumps needs a breakpoint (scene `breakpoints` or "
                     "--breakpoints); or loosen --ref-rtol")
        raise SimulationFailed(setup.scene.coord, f"the reference solution ({method}, rtol "
                                                  f"{rtol:g}) did not finish: {val} ({hint})")
    return val


def errors(setup: Setup, ref: Reference, t, x, y) -> dict:
    """Per-output max abs errors, overall normalised output error, final-state error."""
    if len(t) != len(ref.t) or not np.allclose(t, ref.t, rtol=0, atol=1e-12):
        raise RuntimeError("the solution's time grid differs from the reference's")
    per = {}
    overall = 0.0
    worst = ""
    for o in setup.outputs:
        a, b = np.asarray(y[o], dtype=float), ref.y[o]
        e = float(np.max(np.abs(a - b))) if a.size else 0.0
        if not np.isfinite(e):
            e = math.inf
        per[o] = e
        rel = e / (float(np.max(np.abs(b))) + setup.atol_scale)
        if rel > overall or not worst:
            overall, worst = rel, o
    n = ref.x.shape[0]
    xs = np.asarray(x).reshape(n, -1)
    xr = ref.x.reshape(n, -1)
    scale = np.max(np.abs(xr), axis=1) + setup.atol_scale
    fin = np.abs(xs[:, -1] - xr[:, -1]) / scale
    k = int(np.argmax(fin))
    return {"err": overall, "err_output": worst, "err_abs": per,
            "err_abs_max": max(per.values(), default=0.0),
            "final_err": float(fin[k]), "final_err_state": setup.module.STATE_NAMES[k]}


# --------------------------------------------------------------------------------------------
# measured runs


@dataclass
class Run:
    method: str
    rtol: float
    atol: float
    jac: str  # analytic | sparse-fd | dense-fd | none (explicit methods)
    status: str  # ok | failed | budget | skipped
    message: str = ""
    wall: float = math.nan
    walls: tuple = ()
    nfev: int = 0
    njev: int = 0
    nlu: int = 0
    nsteps: int = 0  # accepted steps
    err: float = math.nan
    err_output: str = ""
    err_abs: dict = field(default_factory=dict)
    err_abs_max: float = math.nan
    final_err: float = math.nan
    final_err_state: str = ""
    kind: str = "study"  # study | jacobian | reference
    solution: tuple | None = None  # (t, x, y) while the errors wait for the reference (Dask)


def measure(setup: Setup, ref: Reference, method, rtol, atol=None, jac_mode="analytic",
            budget=60.0, repeats=3, long_run=math.inf) -> Run:
    """Median wall time of up to `repeats` solves within `budget` seconds, in a child; a solve
    that took longer than `long_run` seconds is not repeated (its time is already well above
    the timer's noise, and the repeats would cost the study most of its time).

    ref=None: the run does not wait for the reference; it keeps its solution (Run.solution)
    and :func:`with_errors` adds the errors once the reference is there."""
    atol = rtol * setup.atol_scale if atol is None else atol
    jac_label = jac_mode if method in IMPLICIT else "none"

    def work():
        walls = []
        start = time.perf_counter()
        out = None
        for i in range(max(1, repeats)):
            t0 = time.perf_counter()
            try:
                res, st = solve(setup, method, rtol, atol, jac_mode, start + budget)
            except BudgetExceeded:
                if walls:
                    break
                raise
            walls.append(time.perf_counter() - t0)
            if out is None:
                out = (res, st)
            if time.perf_counter() - start + walls[-1] > budget or walls[-1] > long_run:
                break
        res, st = out
        if ref is None:
            return walls, st, {"solution": (np.asarray(res.t), np.asarray(res.x), {
                k: np.asarray(res.y[k]) for k in setup.outputs})}
        return walls, st, errors(setup, ref, res.t, res.x, res.y)

    def quiet_work():  # an explicit method blowing up on a stiff scene warns on every call
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            return work()

    status, val = run_isolated(quiet_work, budget + grace(budget))
    run = Run(method, rtol, atol, jac_label, "ok")
    if status == "ok":
        walls, st, errs = val
        return replace(run, wall=float(np.median(walls)), walls=tuple(walls), nfev=st["nfev"],
                       njev=st["njev"], nlu=st["nlu"], nsteps=st["nsteps"], **errs)
    if isinstance(val, BudgetExceeded):
        return replace(run, status="budget", message=f"exceeded the {budget:.3g} s budget")
    msg = str(val).strip().splitlines()[0] if str(val).strip() else type(val).__name__
    if not type(val).__name__ == "SimulationError":
        msg = f"{type(val).__name__}: {msg}"
    return replace(run, status="failed", message=msg[:600])


def with_errors(setup: Setup, ref: Reference, run: Run) -> Run:
    """A run measured without the reference (measure(ref=None)), with its errors: the same
    numbers errors() gives inside the run's child."""
    if run.solution is None:
        return run
    try:
        errs = errors(setup, ref, *run.solution)
    except Exception as exc:  # noqa: BLE001 - as a failure inside the child is reported
        return replace(run, solution=None, status="failed",
                       message=f"{type(exc).__name__}: {exc}"[:600])
    return replace(run, solution=None, **errs)


@dataclass
class Study:
    setup: Setup
    refs: tuple  # the two reference solutions
    agreement: dict  # errors of refs[1] against refs[0]
    stiff: bool
    stiffness_index: float
    runs: list
    jac_runs: list
    settings: dict

