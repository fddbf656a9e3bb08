"""Work-precision study of a scene: error against cost for scipy's integrators and bgc's own
Rosenbrock method Rodas4.

    bgc accuracy SCENE.yaml [--out DIR] [--methods RK45,DOP853,Radau,BDF,LSODA,Rodas4]
                 [--tols 1e-3:1e-10] [--budget 60] [--repeats 3] [--workers N | --scheduler ADDR]

What is measured (everything through the generated module's own ``simulate``):

* a reference solution, computed two independent ways at ``ref_rtol`` (1e-12) with the
  analytic Jacobian: Radau and BDF when the scene is stiff, Radau and DOP853 when it is not
  (stiff: the largest |eigenvalue| of the Jacobian at t0 times the span exceeds 1e3). Their
  disagreement bounds the smallest error the study can resolve;
* for each method and tolerance (rtol; atol = rtol * atol_scale, the scene's atol/rtol ratio
  unless given): the largest error over time of every scene output, in its units; an overall,
  dimensionless error = max over outputs of max|y - y_ref| / (max|y_ref| + atol_scale); the
  final-state error max_i |x_i(T) - x_ref,i(T)| / (max_t |x_ref,i| + atol_scale); wall time
  (median of the repeats; fewer repeats when they would not fit in the budget); accepted
  steps; rhs and Jacobian evaluations (finite-difference columns count as rhs evaluations);
  LU decompositions; failures (an explicit method on a stiff scene stops with simulate's
  StiffnessError instead of spending the budget);
* for Radau and BDF, the analytic Jacobian against finite differences over JAC_SPARSITY
  (``simulate(jac=False)``) and dense finite differences, measured side by side.

Every solve runs in a forked child process with a deadline: the rhs and Jacobian raise once
the budget is spent, and the child is killed if it still has not answered shortly after.
A method that fails, or exceeds the budget, is reported as such; once a method exceeds the
budget at one tolerance, tighter tolerances are skipped (they cost at least as much).

With --workers N (a local Dask cluster) or --scheduler ADDRESS, the references and runs are
Dask tasks (see _study_on): the same runs, each still in its own child with its budget, and
the same results.
"""
from __future__ import annotations

import contextlib
import csv
import io
import math
import multiprocessing as mp
import os
import time
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from bgc.base.errors import ModelError, SimulationFailed
from bgc.base.limits import LIMITS

METHODS = ("RK45", "DOP853", "Radau", "BDF", "LSODA", "Rodas4")
# the C backend's integrators (the whole step loop in the scene's compiled library)
C_METHODS = ("C-Rodas4", "C-Radau")
ALL_METHODS = ("RK45", "RK23", "DOP853", "Radau", "BDF", "LSODA", "Rodas4") + C_METHODS
IMPLICIT = ("Radau", "BDF", "LSODA", "Rodas4") + C_METHODS
# the implicit methods that also run on finite-difference Jacobians (Rodas4 needs the exact one)
FD_JACOBIAN = ("Radau", "BDF", "LSODA")
DEFAULT_TOLS = tuple(10.0 ** -k for k in range(3, 11))
JAC_MODES = ("analytic", "sparse-fd", "dense-fd")
STIFF_THRESHOLD = 1e3  # max|eig(J(t0, x0))| * span above this: the scene is treated as stiff
_GRACE = 20.0  # seconds a child gets past its budget before it is killed


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


def prepare(scene_path, t_end=None, atol_scale=None, breakpoints=(), progress=None) -> Setup:
    """Parse and compile the scene. t_end shortens the span; atol_scale defaults to atol/rtol;
    breakpoints are added to the scene's (instants where an input jumps)."""
    from bgc.format.scene import parse_scene
    from bgc.run.runner import compile_scene

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
    return Setup(Path(scene.file).stem, scene, mod, values(scene) or None, (t0, t1),
                 t_eval, tuple(sorted({float(b) for b in (*scene.breakpoints, *breakpoints)
                                       if t0 < b < t1})), scene.max_step,
                 outs, float(atol_scale), ct, compiled=compiled, source=compiled.source)


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
    if method in C_METHODS:  # one call into C: the budget is its wall-time limit
        mod = c_module(setup)
        wall = None if math.isinf(deadline) else max(deadline - time.perf_counter(), 1e-3)
        try:
            res = mod.simulate(setup.t_span, t_eval=setup.t_eval, method=method[2:], rtol=rtol,
                               atol=atol, p=setup.p, breakpoints=setup.breakpoints,
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
                           atol=atol, p=setup.p, breakpoints=setup.breakpoints,
                           jac=jac_mode == "analytic", max_step=setup.max_step)
    stats = {k: int(res.stats[k]) for k in ("nfev", "njev", "nlu", "nsteps")}
    return res, stats


def c_available() -> bool:
    """A C compiler and the C runtime: the C methods can run."""
    from bgc.backends.c import build as cbuild

    return cbuild.available() and bool(cbuild.runtime_sources())


def c_module(setup: Setup):
    """The scene's C-backend module (built once, through the compile cache)."""
    if setup.cmodule is None:
        from bgc.run.runner import scene_module

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


def is_stiff(setup: Setup) -> tuple[bool, float]:
    mod = setup.module
    x0 = mod.initial_state(setup.p).reshape(-1)
    n = x0.size
    with np.errstate(all="ignore"):
        J = np.asarray(mod.jacobian(setup.t_span[0], x0, setup.p)).reshape(n, n)
    if not np.all(np.isfinite(J)):  # simulate stops on it; treat the scene as stiff
        return True, math.inf
    rho = float(np.max(np.abs(np.linalg.eigvals(J)))) if n else 0.0
    index = rho * (setup.t_span[1] - setup.t_span[0])
    return index > STIFF_THRESHOLD, index


def _warm_up(setup: Setup):
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

    status, val = run_isolated(work, budget + _GRACE)
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
            budget=60.0, repeats=3) -> Run:
    """Median wall time of up to `repeats` solves within `budget` seconds, in a child.

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
            if time.perf_counter() - start + walls[-1] > budget:
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

    status, val = run_isolated(quiet_work, budget + _GRACE)
    run = Run(method, rtol, atol, jac_label, "ok")
    if status == "ok":
        walls, st, errs = val
        return replace(run, wall=float(np.median(walls)), walls=tuple(walls), nfev=st["nfev"],
                       njev=st["njev"], nlu=st["nlu"], nsteps=st["nsteps"], **errs)
    if isinstance(val, BudgetExceeded):
        return replace(run, status="budget", message=f"exceeded the {budget:g} s budget")
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


def parse_tols(text: str) -> tuple:
    """'1e-3:1e-10' (every decade between) or '1e-3,1e-6,...'."""
    try:
        if ":" in text:
            a, b = (float(s) for s in text.split(":"))
            if not (0 < a < 1 and 0 < b < 1):
                raise ValueError
            ka, kb = round(-math.log10(a)), round(-math.log10(b))
            step = 1 if kb >= ka else -1
            tols = tuple(10.0 ** -k for k in range(ka, kb + step, step))
        else:
            tols = tuple(float(s) for s in text.split(",") if s.strip())
    except ValueError:
        raise ModelError(None, f"--tols {text!r}: give 1e-3:1e-10 or a comma list") from None
    if not tols or not all(0 < t < 1 for t in tols):
        raise ModelError(None, f"--tols {text!r}: tolerances lie strictly between 0 and 1")
    low = LIMITS.min_rtol
    if any(t < low * (1 - 1e-9) for t in tols):
        raise ModelError(None, f"--tols {text!r}: {min(tols):g} is below {low:g}, the smallest "
                               "relative tolerance double precision resolves (a scene's rtol "
                               "has the same bound)")
    return tols


def md_cell(text: str) -> str:
    """Text for one markdown table cell: its pipes escaped (messages quote |eigenvalue|) and
    line breaks folded, so that the row keeps its columns."""
    return " ".join(str(text).split()).replace("|", "\\|")


def parse_methods(text, allowed=ALL_METHODS) -> tuple:
    ms = tuple(s.strip() for s in text.split(",") if s.strip())
    for m in ms:
        if m not in allowed:
            raise ModelError(None, f"unknown method {m!r} (one of {', '.join(allowed)})")
    if not ms:
        raise ModelError(None, "no methods given")
    return ms


def _study_head(setup: Setup, ref_methods, ref_rtol):
    """(stiff, stiffness index, reference methods, reference atol, the study's first progress
    line), the same whether the runs go one after another or on Dask."""
    stiff, index = is_stiff(setup)
    if ref_methods is None:
        ref_methods = ("Radau", "BDF") if stiff else ("Radau", "DOP853")
    head = (f"{setup.name}: {setup.module.N_STATES} states, t = {setup.t_span[0]:g}..."
            f"{setup.t_span[1]:g} s, {len(setup.t_eval)} output points; stiffness index "
            f"{index:.3g} ({'stiff' if stiff else 'not stiff'}); atol = rtol x "
            f"{setup.atol_scale:g}")
    return stiff, index, ref_methods, ref_rtol * setup.atol_scale, head


def study(setup: Setup, methods=METHODS, tols=DEFAULT_TOLS, budget=60.0, repeats=3,
          ref_rtol=1e-12, ref_methods=None, ref_budget=900.0, jac_methods=("Radau", "BDF"),
          jac_tols=(1e-4, 1e-6, 1e-8), progress=None, client=None) -> Study:
    """The study; with a dask.distributed client, its runs are Dask tasks (see _Grid)."""
    say = progress or (lambda msg: None)
    if client is not None:
        return _study_on(client, setup, methods, tols, budget, repeats, ref_rtol, ref_methods,
                         ref_budget, jac_methods, jac_tols, say)
    _warm_up(setup)
    if any(m in C_METHODS for m in methods):  # built here, before the runs' forked children
        say("building the C backend's module for the C methods")
        c_module(setup)
    stiff, index, ref_methods, ref_atol, head = _study_head(setup, ref_methods, ref_rtol)
    say(head)
    refs = []
    check_note = ""
    for i, m in enumerate(ref_methods):
        say(f"reference: {m}, rtol {ref_rtol:g}, atol {ref_atol:g} ...")
        try:
            r = reference(setup, m, ref_rtol, ref_atol, ref_budget)
        except ModelError as exc:
            if i == 0:
                raise
            # the check could not be computed: fall back to the first method, 10x looser
            check_note = (f"{m} at rtol {ref_rtol:g} did not finish ({exc.message}); the "
                          f"check is {ref_methods[0]} at rtol {10 * ref_rtol:g} instead "
                          "(a convergence check, not an independent method)")
            say(check_note)
            r = reference(setup, ref_methods[0], 10 * ref_rtol, 10 * ref_atol, ref_budget)
        say(f"reference: {r.method} done in {r.wall:.2f} s ({r.stats['nsteps']} steps, "
            f"{r.stats['nfev']} rhs, "
            f"{r.stats['njev']} Jacobians)")
        refs.append(r)
    ref_methods = tuple(r.method for r in refs)
    agree = errors(setup, refs[0], refs[1].t, refs[1].x, refs[1].y)
    say(f"reference agreement ({ref_methods[1]} vs {ref_methods[0]}): output error "
        f"{agree['err']:.2e} ({agree['err_output']}), final state {agree['final_err']:.2e}")
    ref = refs[0]
    runs = []
    for m in methods:
        over = None
        for tol in sorted(tols, reverse=True):
            if over is not None:
                runs.append(Run(m, tol, tol * setup.atol_scale, "analytic" if m in IMPLICIT
                                else "none", "skipped",
                                f"skipped: over the budget at rtol {over:g}"))
                continue
            r = measure(setup, ref, m, tol, budget=budget, repeats=repeats)
            runs.append(r)
            say(_line(r))
            if r.status == "budget":
                over = tol
    jac_runs = []
    for m in jac_methods:
        for tol in jac_tols:
            for mode in JAC_MODES:
                r = replace(measure(setup, ref, m, tol, jac_mode=mode, budget=budget,
                                    repeats=repeats), kind="jacobian")
                jac_runs.append(r)
                say(_line(r))
    settings = {"ref_rtol": ref_rtol, "ref_atol": ref_atol, "ref_methods": tuple(ref_methods),
                "budget": budget, "repeats": repeats, "atol_scale": setup.atol_scale,
                "tols": tuple(tols), "methods": tuple(methods), "jac_tols": tuple(jac_tols),
                "jac_methods": tuple(jac_methods), "check_note": check_note}
    return Study(setup, tuple(refs), agree, stiff, index, runs, jac_runs, settings)


def _line(r: Run) -> str:
    head = f"{r.method:<6} {r.jac:<9} rtol {r.rtol:.0e}:"
    if r.status != "ok":
        return f"{head} {r.status.upper()} {r.message}"
    return (f"{head} error {r.err:.2e}, final {r.final_err:.2e}, {r.wall:.3f} s "
            f"(median of {len(r.walls)}), {r.nsteps} steps, {r.nfev} rhs, {r.njev} Jac, "
            f"{r.nlu} LU")


# --------------------------------------------------------------------------------------------
# the same study as Dask tasks: every reference and every (method, tolerance) run is a task on
# a worker, which compiles its own module from the source text and still runs each solve in a
# forked child with its budget (run_isolated). A method's tolerances run one after another,
# loosest first, so that one over the budget still skips the tighter ones; methods, the
# Jacobian comparison and the two references run side by side. The runs do not wait for the
# reference: each keeps its solution, and its errors are computed here once the reference is
# in (the same function on the same arrays as inside a child, so the same numbers).

_WORKER_SETUPS: dict = {}


def _worker_setup(bare: Setup) -> Setup:
    """The setup with this process's own module (compiled once per process, warmed up)."""
    import hashlib

    from bgc.backends.load import load_module

    key = hashlib.sha256(bare.source.encode()).hexdigest()
    if key not in _WORKER_SETUPS:
        mod = load_module(bare.source, f"{bare.name}_acc_{key[:8]}")
        _WORKER_SETUPS[key] = replace(bare, module=mod)
        _warm_up(_WORKER_SETUPS[key])
    return _WORKER_SETUPS[key]


@contextlib.contextmanager
def _children_allowed():
    """Let this process fork (a Dask worker process is daemonic unless configured otherwise,
    and multiprocessing refuses children of daemonic processes; ours are killed by us)."""
    proc = mp.current_process()
    daemon = proc._config.get("daemon")
    proc._config["daemon"] = False
    try:
        yield
    finally:
        if daemon is not None:
            proc._config["daemon"] = daemon


def _task(kind, bare: Setup, args):
    """One reference (kind 'ref') or measured run (kind 'run') on a worker. A reference that
    fails comes back as ('error', coord, message): a ModelError does not pickle."""
    setup = _worker_setup(bare)
    with _children_allowed():
        if kind == "ref":
            try:
                return reference(setup, *args)
            except ModelError as exc:
                return ("error", exc.coord, exc.message)
        return measure(setup, *args)


def _study_on(client, setup, methods, tols, budget, repeats, ref_rtol, ref_methods,
              ref_budget, jac_methods, jac_tols, say) -> Study:
    from distributed import as_completed

    bare = replace(setup, module=None, compiled=None, cmodule=None)  # workers rebuild them
    # a fresh key (hash=False): a key shared with an earlier study's data could be released
    # by that study's futures going away while this one still needs it
    fbare = client.scatter(bare, broadcast=True, hash=False)
    stiff, index, ref_methods, ref_atol, head = _study_head(setup, ref_methods, ref_rtol)
    say(f"{head}; on {len(client.scheduler_info()['workers'])} Dask workers")

    def ref_of(val, fallback_ok):
        if isinstance(val, tuple) and val and val[0] == "error":
            if not fallback_ok:
                raise ModelError(val[1], val[2])
            return None, val[2]
        return val, ""

    say(f"references: {', '.join(ref_methods)} at rtol {ref_rtol:g}, atol {ref_atol:g}; the "
        "runs meanwhile (their errors once the reference is there) ...")
    rf = [client.submit(_task, "ref", fbare, (m, ref_rtol, ref_atol, ref_budget), pure=False)
          for m in ref_methods]
    tols_sorted = sorted(tols, reverse=True)
    order = [(m, tol, "analytic", "study") for m in methods for tol in tols_sorted]
    order += [(m, tol, mode, "jacobian") for m in jac_methods for tol in jac_tols
              for mode in JAC_MODES]
    results: dict = {}

    def submit(item):
        m, tol, mode, kind = item
        return client.submit(_task, "run", fbare, (None, m, tol, None, mode, budget, repeats),
                             pure=False)

    pending = {}
    for m in methods:  # each method's loosest tolerance first
        pending[submit((m, tols_sorted[0], "analytic", "study"))] = (m, tols_sorted[0],
                                                                      "analytic", "study")
    for item in order:
        if item[3] == "jacobian":
            pending[submit(item)] = item
    ac = as_completed(list(pending))
    for fut in ac:
        item = pending.pop(fut)
        m, tol, mode, kind = item
        r = fut.result()
        if kind == "jacobian":
            r = replace(r, kind="jacobian")
        results[item] = r
        say(_line(r).replace("error nan, final nan, ", "") if r.status == "ok" else _line(r))
        if kind == "study":
            rest = [t for t in tols_sorted if t < tol]
            if rest and r.status == "budget":
                for t in rest:
                    results[(m, t, mode, kind)] = Run(
                        m, t, t * setup.atol_scale, "analytic" if m in IMPLICIT else "none",
                        "skipped", f"skipped: over the budget at rtol {tol:g}")
            elif rest:
                nxt = (m, rest[0], mode, kind)
                f2 = submit(nxt)
                pending[f2] = nxt
                ac.add(f2)
    r0, _ = ref_of(rf[0].result(), False)
    results = {k: with_errors(setup, r0, r) for k, r in results.items()}
    runs = [results[i] for i in order if i[3] == "study"]
    jac_runs = [results[i] for i in order if i[3] == "jacobian"]
    check_note = ""
    r1, err = ref_of(rf[1].result(), True)
    if r1 is None:
        check_note = (f"{ref_methods[1]} at rtol {ref_rtol:g} did not finish ({err}); the "
                      f"check is {ref_methods[0]} at rtol {10 * ref_rtol:g} instead "
                      "(a convergence check, not an independent method)")
        say(check_note)
        r1, _ = ref_of(client.submit(_task, "ref", fbare, (ref_methods[0], 10 * ref_rtol,
                                                           10 * ref_atol, ref_budget),
                                     pure=False).result(), False)
    refs = (r0, r1)
    for r in refs:
        say(f"reference: {r.method} done in {r.wall:.2f} s ({r.stats['nsteps']} steps, "
            f"{r.stats['nfev']} rhs, {r.stats['njev']} Jacobians)")
    ref_methods = tuple(r.method for r in refs)
    agree = errors(setup, refs[0], refs[1].t, refs[1].x, refs[1].y)
    say(f"reference agreement ({ref_methods[1]} vs {ref_methods[0]}): output error "
        f"{agree['err']:.2e} ({agree['err_output']}), final state {agree['final_err']:.2e}")
    settings = {"ref_rtol": ref_rtol, "ref_atol": ref_atol, "ref_methods": tuple(ref_methods),
                "budget": budget, "repeats": repeats, "atol_scale": setup.atol_scale,
                "tols": tuple(tols), "methods": tuple(methods), "jac_tols": tuple(jac_tols),
                "jac_methods": tuple(jac_methods), "check_note": check_note}
    return Study(setup, refs, agree, stiff, index, runs, jac_runs, settings)


# --------------------------------------------------------------------------------------------
# outputs


def _fmt(v, spec=".2e"):
    if isinstance(v, str):
        return v
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return ""
    return format(v, spec)


def write_csv(st: Study, path, inputs=None):
    outs = st.setup.outputs
    cols = ["kind", "method", "jacobian", "rtol", "atol", "status", "message", "wall_s",
            "n_repeats", "walls_s", "nsteps", "nfev", "njev", "nlu", "err", "err_output",
            "err_abs_max", "final_err", "final_err_state"] + [f"err_abs_{o}" for o in outs]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    rows = []
    for ref in st.refs:
        rows.append(Run(ref.method, ref.rtol, ref.atol, "analytic", "ok", "reference",
                        ref.wall, (ref.wall,), ref.stats["nfev"], ref.stats["njev"],
                        ref.stats["nlu"], ref.stats["nsteps"], kind="reference"))
    rows[-1] = replace(rows[-1], message="reference (errors: against the first)",
                       **{k: st.agreement[k] for k in ("err", "err_output", "err_abs",
                                                       "err_abs_max", "final_err",
                                                       "final_err_state")})
    for r in rows + st.runs + st.jac_runs:
        w.writerow([r.kind, r.method, r.jac, f"{r.rtol:g}", f"{r.atol:g}", r.status, r.message,
                    _fmt(r.wall, ".6g"), len(r.walls), " ".join(f"{x:.4g}" for x in r.walls),
                    r.nsteps, r.nfev, r.njev, r.nlu, _fmt(r.err, ".6e"), r.err_output,
                    _fmt(r.err_abs_max, ".6e"), _fmt(r.final_err, ".6e"), r.final_err_state]
                   + [_fmt(r.err_abs.get(o, math.nan), ".6e") for o in outs])
    _write(path, buf.getvalue(), inputs)


def _write(path, data, inputs=None):
    """Every file of the study goes through bgc's one checked writer; ``inputs`` (a
    bgc.base.outfiles.Inputs: the scene, the model, its imports) are never replaced."""
    from bgc.base.outfiles import write_output

    write_output(path, data, inputs, "accuracy output")


def cheapest(runs, target):
    ok = [r for r in runs if r.status == "ok" and r.err <= target]
    return min(ok, key=lambda r: r.wall) if ok else None


def write_markdown(st: Study, path, images=(), inputs=None):
    s, se = st.settings, st.setup
    a = st.agreement
    L = []
    L.append(f"# Work-precision study: `{se.name}`\n")
    L.append(f"Scene `{se.scene.file}`, model `{Path(se.scene.model_path).name}`, "
             f"{se.module.N_STATES} states; t = {se.t_span[0]:g}..{se.t_span[1]:g} s"
             + (" (shortened from the scene's "
                f"{se.scene.t_span[1]:g} s)" if se.t_span[1] < se.scene.t_span[1] else "")
             + f", errors sampled at {len(se.t_eval)} points; breakpoints "
             f"{list(se.breakpoints) or 'none'}.\n")
    L.append(f"* Tolerances: rtol as listed, **atol = rtol x {s['atol_scale']:g}** "
             f"(the scene's atol/rtol ratio unless `--atol-scale` was given).")
    L.append(f"* Stiffness index max|eig J(t0)| x span = {st.stiffness_index:.3g}: "
             f"{'stiff' if st.stiff else 'not stiff'}.")
    L.append(f"* Reference: {s['ref_methods'][0]} at rtol {s['ref_rtol']:g}, atol "
             f"{s['ref_atol']:g}, analytic Jacobian ({st.refs[0].wall:.1f} s); checked with "
             f"{st.refs[1].method} at rtol {st.refs[1].rtol:g}, atol {st.refs[1].atol:g} "
             f"({st.refs[1].wall:.1f} s)." + (f" Note: {s['check_note']}." if s.get(
                 "check_note") else ""))
    L.append(f"* **Reference agreement: {a['err']:.2e}** (overall output error, largest in "
             f"`{a['err_output']}`), final state {a['final_err']:.2e}. Errors near or below "
             "this are not resolved.")
    L.append("* Error (dimensionless): max over the outputs of max_t |y - y_ref| / "
             "(max_t |y_ref| + atol scale); the max abs error per output, in its units, is "
             "in the CSV (`err_abs_*`). Final-state error: max_i |x_i(T) - x_ref,i(T)| / "
             "(max_t |x_ref,i| + atol scale).")
    L.append(f"* Wall time: median of up to {s['repeats']} runs within a {s['budget']:g} s "
             "budget per (method, tolerance), each in a forked child with a hard limit; "
             "'steps' counts accepted steps; rhs counts include finite-difference "
             "columns; 'Jac' counts Jacobian "
             "evaluations (analytic or finite-difference).\n")
    L.append("## Cheapest run reaching an error\n")
    L.append("| error <= | method | rtol | error | wall [s] | steps | rhs | Jac |")
    L.append("|---|---|---|---|---|---|---|---|")
    for target in (1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8):
        if target < a["err"]:
            continue
        r = cheapest(st.runs, target)
        if r is None:
            L.append(f"| {target:.0e} | none | | | | | | |")
        else:
            L.append(f"| {target:.0e} | {r.method} | {r.rtol:.0e} | {r.err:.2e} | "
                     f"{r.wall:.3g} | {r.nsteps} | {r.nfev} | {r.njev} |")
    L.append("")
    L.append("## All runs (analytic Jacobian for the implicit methods)\n")
    L.append("| method | rtol | atol | status | error | worst output | max abs error "
             "| final-state error | wall [s] (runs) | steps | rhs | Jac | LU |")
    L.append("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in st.runs:
        if r.status == "ok":
            L.append(f"| {r.method} | {r.rtol:.0e} | {r.atol:.0e} | ok | {r.err:.2e} | "
                     f"{r.err_output} | {r.err_abs[r.err_output]:.2e} | {r.final_err:.2e} | "
                     f"{r.wall:.3g} ({len(r.walls)}) | {r.nsteps} | {r.nfev} | {r.njev} | "
                     f"{r.nlu} |")
        else:
            L.append(f"| {r.method} | {r.rtol:.0e} | {r.atol:.0e} | **{r.status}** | "
                     f"{md_cell(r.message)} | | | | | | | | |")
    L.append("")
    if st.jac_runs:
        L.append("## Analytic Jacobian against finite differences\n")
        L.append("Sparse FD: `simulate(jac=False)`, scipy's grouped differences over "
                 "JAC_SPARSITY; dense FD: the same without the sparsity pattern (one rhs per "
                 "state per Jacobian). Ratios are FD / analytic, measured back to back.\n")
        L.append("| method | rtol | Jacobian | status | error | wall [s] | wall ratio | steps "
                 "| rhs | Jac | rhs ratio | LU |")
        L.append("|---|---|---|---|---|---|---|---|---|---|---|---|")
        base = {}
        for r in st.jac_runs:
            if r.jac == "analytic":
                base[(r.method, r.rtol)] = r
            b = base.get((r.method, r.rtol))
            if r.status != "ok":
                L.append(f"| {r.method} | {r.rtol:.0e} | {r.jac} | **{r.status}** | "
                         f"{md_cell(r.message)} | | | | | | | |")
                continue
            ok = b is not None and b.status == "ok"
            wr = f"{r.wall / b.wall:.2f}" if ok else ""
            fr = f"{r.nfev / b.nfev:.2f}" if ok and b.nfev else ""
            L.append(f"| {r.method} | {r.rtol:.0e} | {r.jac} | ok | {r.err:.2e} | "
                     f"{r.wall:.3g} ({len(r.walls)}) | {wr} | {r.nsteps} | {r.nfev} | {r.njev} | "
                     f"{fr} | "
                     f"{r.nlu} |")
        L.append("")
    for img in images:
        L.append(f"![{Path(img).stem}]({Path(img).name})\n")
    _write(path, "\n".join(L), inputs)


_MARK = {"RK45": "o", "RK23": "^", "DOP853": "s", "Radau": "D", "BDF": "v", "LSODA": "P",
         "Rodas4": "X"}


def _finish(plt, fig, ax, agree, xlabel, title, path, inputs=None):
    """Log-log axes of error against cost, the reference's resolution as a floor; saved."""
    ax.axhline(max(agree, 1e-300), color="k", ls=":", lw=1,
               label=f"reference agreement {agree:.1e}")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("max output error (relative to peak)")
    ax.set_title(title)
    ax.legend(fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    _write(path, buf.getvalue(), inputs)
    return path


def plot_study(st: Study, out_dir, inputs=None) -> list:
    from bgc.base.outfiles import prepare_folder
    from bgc.run.plots import _mpl

    plt = _mpl()
    out_dir = prepare_folder(out_dir, "--out")
    files = []
    agree = st.agreement["err"]
    for xkey, xlabel, suffix in (("wall", "wall time [s] (median)", "wp_time"),
                                 ("nfev", "rhs evaluations", "wp_rhs")):
        fig, ax = plt.subplots(figsize=(7.2, 4.8))
        for m in st.settings["methods"]:
            rs = [r for r in st.runs if r.method == m and r.status == "ok"]
            bad = [r for r in st.runs if r.method == m and r.status != "ok"]
            lab = m + (f" ({len(bad)} over budget/failed)" if bad else "")
            if not rs:
                ax.plot([], [], marker=_MARK.get(m, "o"), ls="-", label=lab + ": no result")
                continue
            xs = [getattr(r, xkey) for r in rs]
            ys = [max(r.err, 1e-300) for r in rs]
            line, = ax.plot(xs, ys, marker=_MARK.get(m, "o"), ms=5, lw=1.4, label=lab)
            for r, x_, y_ in zip(rs, xs, ys):
                if r.rtol in (rs[0].rtol, rs[-1].rtol):
                    ax.annotate(f"{r.rtol:.0e}", (x_, y_), textcoords="offset points",
                                xytext=(4, 3), fontsize=7, color=line.get_color())
        files.append(_finish(plt, fig, ax, agree, xlabel,
                             f"{st.setup.name}: work-precision, t = {st.setup.t_span[0]:g}.."
                             f"{st.setup.t_span[1]:g} s (labels: rtol)",
                             out_dir / f"{st.setup.name}_{suffix}.png", inputs))
    if st.jac_runs:
        fig, ax = plt.subplots(figsize=(7.2, 4.8))
        styles = {"analytic": "-", "sparse-fd": "--", "dense-fd": ":"}
        colors = {}
        for m in st.settings["jac_methods"]:
            for mode in JAC_MODES:
                rs = [r for r in st.jac_runs if r.method == m and r.jac == mode
                      and r.status == "ok"]
                if not rs:
                    continue
                kw = {"color": colors[m]} if m in colors else {}
                line, = ax.plot([r.wall for r in rs], [max(r.err, 1e-300) for r in rs],
                                marker=_MARK.get(m, "o"), ls=styles[mode], lw=1.4, ms=5,
                                label=f"{m}, {mode}", **kw)
                colors.setdefault(m, line.get_color())
        files.append(_finish(plt, fig, ax, agree, "wall time [s] (median)",
                             f"{st.setup.name}: analytic Jacobian vs finite differences (rtol "
                             f"{', '.join(f'{t:.0e}' for t in st.settings['jac_tols'])})",
                             out_dir / f"{st.setup.name}_jacobian.png", inputs))
    return files


def write_all(st: Study, out_dir, inputs=None) -> list:
    out_dir = Path(out_dir)
    imgs = plot_study(st, out_dir, inputs)
    csvf = out_dir / f"{st.setup.name}_runs.csv"
    md = out_dir / f"{st.setup.name}_accuracy.md"
    write_csv(st, csvf, inputs)
    write_markdown(st, md, imgs, inputs)
    return [csvf, md] + imgs


# --------------------------------------------------------------------------------------------
# parameter sweeps (the 3R2S's penalty stiffness)


@dataclass
class SweepPoint:
    value: float
    status: str
    message: str = ""
    wall: float = math.nan
    nfev: int = 0
    njev: int = 0
    nlu: int = 0
    metrics: dict = field(default_factory=dict)
    nsteps: int = 0


def param_sweep(setup: Setup, param, values, metrics_fn, method="Radau", rtol=1e-6,
                atol=1e-9, budget=60.0, repeats=1, progress=None) -> list:
    """Simulate with p[param] = each value; metrics_fn(setup, p, res) -> {name: float}."""
    say = progress or (lambda msg: None)
    pts = []
    for v in values:
        s = replace(setup, p={**(setup.p or {}), param: float(v)})

        def work():
            walls, start, out = [], time.perf_counter(), None
            for _ in range(max(1, repeats)):
                t0 = time.perf_counter()
                try:
                    res, st = solve(s, method, rtol, atol, "analytic", start + budget)
                except BudgetExceeded:
                    if walls:
                        break
                    raise
                walls.append(time.perf_counter() - t0)
                out = out or (res, st)
                if time.perf_counter() - start + walls[-1] > budget:
                    break
            res, st = out
            return float(np.median(walls)), st, metrics_fn(s, s.p, res)

        status, val = run_isolated(work, budget + _GRACE)
        if status == "ok":
            wall, st, met = val
            pt = SweepPoint(float(v), "ok", "", wall, st["nfev"], st["njev"], st["nlu"], met,
                            st["nsteps"])
            say(f"{param} = {v:.3g}: {wall:.2f} s, {st['nfev']} rhs, " + ", ".join(
                f"{k} {x:.3g}" for k, x in met.items()))
        else:
            kind = "budget" if isinstance(val, BudgetExceeded) else "failed"
            pt = SweepPoint(float(v), kind, str(val)[:200])
            say(f"{param} = {v:.3g}: {kind.upper()} {val}")
        pts.append(pt)
    return pts
