"""Work-precision study of a scene: error against cost for scipy's integrators and bgc's own
Rosenbrock method Rodas4.

    bgc accuracy SCENE.yaml [--out DIR] [--methods RK45,DOP853,Radau,BDF,LSODA,Rodas4]
                 [--tols 1e-3:1e-10] [--budget 60] [--repeats 3] [--workers N | --scheduler ADDR]

What is measured (everything through the generated module's own ``simulate``):

* a reference solution, computed two independent ways at ``ref_rtol`` (1e-12) with the
  analytic Jacobian: Radau and BDF when the scene is stiff, Radau and DOP853 when it is not
  (stiff: the largest |eigenvalue| of the Jacobian, at t0 and along a loose pilot run before
  its shortest steps and at evenly spread ones, times the span exceeds 1e3). Their
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

This module is the study itself (one after another, or on Dask); its parts are
:mod:`bgc.studies.runs` (the setup, one solve, the reference, errors, measured runs),
:mod:`bgc.studies.accuracy_report` (CSV, markdown, plots) and :mod:`bgc.studies.stiffness`
(a parameter stepped through values); their public names are importable from here too.
"""
from __future__ import annotations

import contextlib
import math
import multiprocessing as mp
import time
from dataclasses import replace

from bgc.backends.load import load_module
from bgc.base.errors import ModelError
from bgc.base.limits import LIMITS
from bgc.studies.accuracy_report import (  # noqa: F401
    cheapest,
    md_cell,
    skipped_lines,
    write_all,
    write_csv,
)
from bgc.studies.runs import (  # noqa: F401 (the study's parts, as bgc.studies.accuracy.*)
    ALL_METHODS,
    C_ALL,
    C_METHODS,
    DEFAULT_TOLS,
    FD_JACOBIAN,
    IMPLICIT,
    JAC_MODES,
    METHODS,
    STIFF_THRESHOLD,
    BudgetExceeded,
    Reference,
    Run,
    Setup,
    Study,
    c_available,
    c_module,
    errors,
    is_stiff,
    measure,
    prepare,
    reference,
    run_isolated,
    solve,
    warm_up,
    with_errors,
)
from bgc.studies.stiffness import SweepPoint, param_sweep  # noqa: F401


def parse_tols(text: str, what: str = "--tols") -> tuple:
    """'1e-3:1e-10' (every decade between) or '1e-3,1e-6,...' (``what``: the option's name)."""
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
        raise ModelError(None, f"{what} {text!r}: give 1e-3:1e-10 or a comma list") from None
    if not tols or not all(0 < t < 1 for t in tols):
        raise ModelError(None, f"{what} {text!r}: tolerances lie strictly between 0 and 1")
    low = LIMITS.min_rtol
    if any(t < low * (1 - 1e-9) for t in tols):
        raise ModelError(None, f"{what} {text!r}: {min(tols):g} is below {low:g}, the smallest "
                               "relative tolerance double precision resolves (a scene's rtol "
                               "has the same bound)")
    return tols


def parse_methods(text, allowed=ALL_METHODS) -> tuple:
    ms = tuple(s.strip() for s in text.split(",") if s.strip())
    for m in ms:
        if m not in allowed:
            raise ModelError(None, f"unknown method {m!r} (one of {', '.join(allowed)})")
    if not ms:
        raise ModelError(None, "no methods given")
    return ms


def default_references(stiff: bool, c_ok: bool) -> tuple[tuple, str]:
    """(the two reference methods, a note): the C backend's Radau, checked with its Rodas4
    (stiff) or DOP853 (not stiff), where a compiler works: the whole step loop in C, minutes
    faster at rtol 1e-12 than scipy's; numpy's Radau and BDF or DOP853 otherwise, with a
    note."""
    if c_ok:
        return ("C-Radau", "C-Rodas4" if stiff else "C-DOP853"), ""
    return (("Radau", "BDF") if stiff else ("Radau", "DOP853"),
            "no C compiler or C runtime: the references run on the numpy backend "
            "(scipy's step loop, much slower at a tight tolerance)")


def _study_head(setup: Setup, ref_methods, ref_rtol):
    """(stiff, stiffness index, reference methods, reference atol, the study's first progress
    line, a note on the references' backend), the same whether the runs go one after another
    or on Dask."""
    stiff, index = is_stiff(setup)
    note = ""
    if ref_methods is None:
        ref_methods, note = default_references(stiff, c_available())
    head = (f"{setup.name}: {setup.module.N_STATES} states, t = {setup.t_span[0]:g}..."
            f"{setup.t_span[1]:g} s, {len(setup.t_eval)} output points; stiffness index "
            f"{index:.3g} ({'stiff' if stiff else 'not stiff'}); atol = rtol x "
            f"{setup.atol_scale:g}")
    return stiff, index, ref_methods, ref_rtol * setup.atol_scale, head, note


def _sweep(setup, say, ref, method, tols, budget, limits, repeats, long_run,
           jac_mode="analytic", kind="study", stiff=False) -> list:
    """One method's runs, loosest tolerance first. The tighter ones are skipped (a run with
    status 'skipped' that says why) once a run exceeds the per-run budget, once the sweep's
    runs together have taken more than its budget (tighter tolerances cost at least as much),
    once the whole study's deadline has passed, or once an explicit method on a stiff scene has
    not finished a run. limits: (the sweep's budget, the study's
    deadline (perf_counter), the study's budget)."""
    sweep_budget, deadline, study_budget = limits
    runs, why = [], None
    spent = 0.0
    jac = jac_mode if method in IMPLICIT else "none"
    for tol in sorted(tols, reverse=True):
        left = deadline - time.perf_counter()
        if why is None and left <= 0:
            why = f"the study's {study_budget:g} s budget was spent before this run"
        if why is not None:
            runs.append(Run(method, tol, tol * setup.atol_scale, jac, "skipped",
                            f"skipped: {why}", kind=kind))
            continue
        r = measure(setup, ref, method, tol, jac_mode=jac_mode, budget=min(budget, left),
                    repeats=repeats, long_run=long_run)
        if kind != "study":
            r = replace(r, kind=kind)
        runs.append(r)
        say(_line(r))
        spent += sum(r.walls) if r.status == "ok" else (budget if r.status == "budget" else 0)
        if r.status != "ok" and stiff and method not in IMPLICIT:
            why = (f"an explicit method on a stiff scene: it did not finish at rtol {tol:g} "
                   "and tighter tolerances only ask for more steps")
        elif r.status == "budget" and left < budget:
            why = f"the study's {study_budget:g} s budget was spent at rtol {tol:g}"
        elif r.status == "budget":
            why = f"over the {budget:.3g} s budget at rtol {tol:g}"
        elif spent > sweep_budget:
            why = (f"the sweep had taken {spent:.1f} s by rtol {tol:g}, past its "
                   f"{sweep_budget:g} s budget")
    return runs


def study(setup: Setup, methods=METHODS, tols=DEFAULT_TOLS, budget=60.0, repeats=3,
          ref_rtol=1e-12, ref_methods=None, ref_budget=900.0, jac_methods=("Radau", "BDF"),
          jac_tols=(1e-4, 1e-6, 1e-8), progress=None, client=None, study_budget=math.inf,
          sweep_budget=None, long_run=math.inf) -> Study:
    """The study; with a dask.distributed client, its runs are Dask tasks (see _Grid).

    study_budget: seconds all the measured runs together may take (the references not
    counted); what is left when it is spent is skipped, and says so. sweep_budget: seconds one
    sweep (a method over the tolerances; for the Jacobian comparison, a method in one
    Jacobian mode) may take before its tighter tolerances are skipped; by default the study's
    budget shared evenly among the sweeps. long_run: a run that took longer than this many
    seconds is not repeated."""
    say = progress or (lambda msg: None)
    if client is not None:
        return _study_on(client, setup, methods, tols, budget, repeats, ref_rtol, ref_methods,
                         ref_budget, jac_methods, jac_tols, say)
    warm_up(setup)
    if any(m in C_ALL for m in (*methods, *(ref_methods or ()))) or (
            ref_methods is None and c_available()):  # before the forked children
        say("building the C backend's module for the C methods")
        c_module(setup)
    stiff, index, ref_methods, ref_atol, head, ref_note = _study_head(setup, ref_methods,
                                                                      ref_rtol)
    say(head)
    if ref_note:
        say(ref_note)
    refs, check_note = _references(setup, say, ref_methods, ref_rtol, ref_atol, ref_budget)
    ref_methods = tuple(r.method for r in refs)
    agree = errors(setup, refs[0], refs[1].t, refs[1].x, refs[1].y)
    say(f"reference agreement ({ref_methods[1]} vs {ref_methods[0]}): output error "
        f"{agree['err']:.2e} ({agree['err_output']}), final state {agree['final_err']:.2e}")
    ref = refs[0]
    if sweep_budget is None:
        sweep_budget = study_budget / max(1, len(methods) + len(jac_methods) * len(JAC_MODES))
    limits = (sweep_budget, time.perf_counter() + study_budget, study_budget)
    runs = []
    for m in methods:
        runs += _sweep(setup, say, ref, m, tols, budget, limits, repeats, long_run,
                       stiff=stiff)
    jac_runs = []
    for m in jac_methods:
        for mode in JAC_MODES:
            jac_runs += _sweep(setup, say, ref, m, jac_tols, budget, limits, repeats,
                               long_run, jac_mode=mode, kind="jacobian")
    jac_runs.sort(key=lambda r: (jac_methods.index(r.method), -r.rtol, JAC_MODES.index(r.jac)))
    settings = {"ref_rtol": ref_rtol, "ref_atol": ref_atol, "ref_methods": tuple(ref_methods),
                "budget": budget, "repeats": repeats, "atol_scale": setup.atol_scale,
                "tols": tuple(tols), "methods": tuple(methods), "jac_tols": tuple(jac_tols),
                "jac_methods": tuple(jac_methods), "check_note": check_note,
                "ref_note": ref_note, "sweep_budget": sweep_budget, "long_run": long_run,
                "study_budget": study_budget}
    return Study(setup, tuple(refs), agree, stiff, index, runs, jac_runs, settings)


def _references(setup, say, ref_methods, ref_rtol, ref_atol, ref_budget):
    """The two reference solutions, and a note when the second had to fall back to the first
    method at a 10x looser tolerance."""
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
    return refs, check_note


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


    key = hashlib.sha256(bare.source.encode()).hexdigest()
    if key not in _WORKER_SETUPS:
        mod = load_module(bare.source, f"{bare.name}_acc_{key[:8]}")
        _WORKER_SETUPS[key] = replace(bare, module=mod)
        warm_up(_WORKER_SETUPS[key])
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
    stiff, index, ref_methods, ref_atol, head, ref_note = _study_head(setup, ref_methods,
                                                                      ref_rtol)
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
                "jac_methods": tuple(jac_methods), "check_note": check_note,
                "ref_note": ref_note}
    return Study(setup, refs, agree, stiff, index, runs, jac_runs, settings)


# --------------------------------------------------------------------------------------------
# outputs

