"""What a run's steps may miss: the step bound of a scene's periodic inputs, and the check
after a run that its solution did not step over something its outputs show.

An integrator judges its error only where its steps land. At a loose tolerance it can step over
what happens within a fraction of an input's period (a rectifier's diode conducts for a
millisecond of each 20 ms cycle) and return a smooth, wrong answer. A scene's periodic inputs
therefore bound the step by default (:func:`scene_max_step`), and :func:`stepped_over` compares
the solution with the model's own derivative along it (docs/model-format.md, "Scenes").
"""
from __future__ import annotations

import numpy as np

#: A periodic input bounds a scene's step to its period divided by this (docs/model-format.md).
STEPS_PER_PERIOD = 50


def scene_max_step(scene, mod) -> float:
    """The step bound of a run: the scene's solver max_step when it gives one, else 1/50 of
    the shortest period of the module's periodic inputs (INPUT_PERIODS), else none (inf)."""
    if scene.max_step != float("inf"):
        return scene.max_step
    periods = getattr(mod, "INPUT_PERIODS", None) or {}
    return min(periods.values()) / STEPS_PER_PERIOD if periods else float("inf")


def fastest_input(mod) -> str:
    """The periodic input with the shortest period ("" without any)."""
    periods = getattr(mod, "INPUT_PERIODS", None) or {}
    return min(periods, key=periods.get) if periods else ""


def stepped_over(mod, t, x, p=None, breakpoints=(), nsteps=None) -> str | None:
    """A warning when the run's solution misses something faster than its steps, else None.

    The solution's own derivative (central differences on the output grid) is compared with
    the model's, rhs(t, x(t)), along it: an integrator that stepped over a fast event (a diode's
    conduction pulse, a contact) interpolates smoothly across it while the model's derivative
    (and every output computed from it) shows the event. Where the two differ by more than half
    the derivative's largest value over five samples in a row, away from breakpoints, and the
    difference adds up to a twentieth of the state's range there, the run says when and for
    which state. Only a run whose steps are on average longer than three output intervals
    (nsteps, when given) can have stepped over something the output grid shows; shorter steps
    and a coarse grid would only alias a fast oscillation."""
    t = np.asarray(t, dtype=float)
    if t.size < 5:
        return None
    if nsteps and (t[-1] - t[0]) / nsteps < 3 * (t[-1] - t[0]) / (t.size - 1):
        return None
    n, nt = np.shape(x)[0], t.size
    X = np.asarray(x, dtype=float).reshape(n, -1, nt)
    try:
        with np.errstate(all="ignore"):
            f = np.asarray(mod.rhs(t, X, p), dtype=float).reshape(n, -1, nt)
    except Exception:  # noqa: BLE001 - a warning only: a model that cannot say, says nothing
        return None
    d = (X[..., 2:] - X[..., :-2]) / (t[2:] - t[:-2])
    f = f[..., 1:-1]
    scale = np.max(np.abs(f), axis=-1, keepdims=True)
    bad = (np.abs(d - f) > 0.5 * scale) & (scale > 0) & np.isfinite(f)
    tm = t[1:-1]
    for b in breakpoints:  # a jump in an input: the difference quotient straddles it
        bad &= ~(np.abs(tm - b) <= (t[-1] - t[0]) / (nt - 1) * 1.5)
    # ... over 5 samples in a row, the difference of one sign (not a fast oscillation the
    # output grid undersamples) and adding up to a twentieth of the state's range
    w = 5
    if bad.shape[-1] < w:
        return None
    def window(v):  # sums over w samples in a row
        c = np.cumsum(np.concatenate([np.zeros(v.shape[:-1] + (1,)), v], axis=-1), axis=-1)
        return c[..., w:] - c[..., :-w]
    gap = (f - d) * np.gradient(tm)
    added = np.abs(window(gap))
    run = (window(bad.astype(float)) == w) & (added > 0.05 * np.ptp(X, axis=-1, keepdims=True)) \
        & (added > 0.9 * window(np.abs(gap)))  # one sign: not an undersampled oscillation
    if not run.any():
        return None
    i, _, k = (int(v[0]) for v in np.nonzero(run))
    name = mod.STATE_NAMES[i] if i < len(mod.STATE_NAMES) else str(i)
    return (f"the solution misses something faster than its steps near t = {tm[k + 1]:.6g} s: "
            f"d{name}/dt of the model is {f.reshape(n, -1, nt - 2)[i].flat[k + 1]:.4g}, the "
            f"solution's {d[i].flat[k + 1]:.4g} (outputs there show what the state never saw); "
            "a smaller solver max_step resolves it")


#: atol dominates a state's error control where it exceeds rtol times the state's size by this.
ATOL_DOMINATES = 10.0
#: a state that never exceeds this fraction of atol is taken as zero (round-off, a component
#: that is zero by symmetry), not as a small quantity.
ATOL_NOISE = 1e-4


def tightened_atol(mod, x, rtol: float, atol: float) -> tuple[float, str] | None:
    """(a smaller atol, why) when the default atol, not rtol, held some state's error, else
    None.

    The integrators keep each state's local error below atol + rtol |x|. A state that stays
    small in its own unit (a microfarad capacitor's charge, 1e-6 C at 1 V; a millihenry
    inductor's flux linkage) is held to atol alone: at the default atol 1e-9 its relative
    error may reach 1e-3, not rtol. Such a state is one whose largest magnitude over the run,
    times rtol, lies more than ATOL_DOMINATES times below atol, and above ATOL_NOISE times atol
    (modes and closed loops' violation states, small by design, are left out). The atol
    returned is rtol times the smallest such size, rounded down to a power of ten: the run
    repeated with it holds every state to rtol (docs/model-format.md, "Scenes")."""
    skip = set(getattr(mod, "MODE_NAMES", ())) | set(getattr(mod, "CONSTRAINT_STATES", ()))
    X = np.abs(np.asarray(x, dtype=float).reshape(np.shape(x)[0], -1))
    with np.errstate(all="ignore"):
        size = np.where(np.isfinite(X), X, 0.0).max(axis=1)
    small = sorted((size[i], name) for i, name in enumerate(mod.STATE_NAMES)
                   if name not in skip and ATOL_NOISE * atol < size[i]
                   and rtol * size[i] * ATOL_DOMINATES < atol)
    if not small:
        return None
    least = small[0][0]
    new = float(10.0 ** np.floor(np.log10(rtol * least)))
    names = ", ".join(f"{name!r} (at most {s:.3g})" for s, name in small[:3])
    more = f" and {len(small) - 3} more" if len(small) > 3 else ""
    return new, (f"atol {new:g}: the state {names}{more} stays so small in its own unit that "
                 f"the default atol {atol:g} would hold it to a relative {atol / least:.1g}, not "
                 f"rtol {rtol:g}; rerunning (the scene's solver atol chooses)")


def rerun_tightened(mod, t_span, method: str, run: dict, res, say) -> tuple:
    """(result, what the summary line adds) of the run again at a smaller atol (``run["atol"]``
    updated, the reason said) where the default atol, not rtol, held some state's error
    (:func:`tightened_atol`), else (``res``, ""); a rerun that fails (its step budget, say)
    leaves the first run standing, with a warning."""
    _, x, _ = res
    tight = tightened_atol(mod, x, run["rtol"], run["atol"])
    if tight is None:
        return res, ""
    old, (run["atol"], note) = run["atol"], tight
    say(note)
    try:
        return (mod.simulate(t_span, method=method, **run),
                f"atol tightened from {old:g}: small states")
    except mod.SimulationError as exc:  # the first run stands, with what it holds to atol
        say(f"warning: the run at atol {run['atol']:g} failed ({exc}); the run at atol "
            f"{old:g} stands, its small states held to atol only")
        run["atol"] = old
        return res, ""
