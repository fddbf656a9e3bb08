"""`method: auto`: an explicit method (DOP853) for a scene that is not stiff, Radau for one
that is, chosen from the model's own Jacobian along a short probe.

Conservative by design: a wrong explicit choice on a stiff model is the expensive mistake, so
Radau is the answer whenever anything is unclear. The probe runs Radau over the first
PROBE_FRACTION of the span and looks at the analytic Jacobian's eigenvalues at PROBE_POINTS
states along it (not at t0 alone: a contact model is smooth at its start and stiff once in
contact). A mode that decays within the span (Re(lambda) * span < -DECAYED) bounds an
explicit step by stability to about STABLE_HLAMBDA / |lambda|; when that bound asks for more
than STEP_BUDGET steps over the span at any probe point, the model is stiff for DOP853. An
undamped oscillation bounds the step through accuracy anyway and does not count. And should
the explicit run still fail (the numpy runtime's stiffness watch, or the step budget), the
run is repeated with Radau (:func:`bgc.run.runner.run_scene`).
"""
from __future__ import annotations

import numpy as np

EXPLICIT, IMPLICIT = "DOP853", "Radau"
PROBE_FRACTION = 0.05  # of the span
PROBE_POINTS = 5
PROBE_STEPS = 2000  # the probe's step budget
STEP_BUDGET = 500  # stability-bound explicit steps over the span above which Radau is chosen
STABLE_HLAMBDA = 5.9  # DOP853's stability limit, the smaller of the real- and imaginary-axis
DECAYED = 10.0  # a mode that decays by e^-10 over the span is a transient
SAMPLE = 8  # batch instances whose eigenvalues are computed at each probe point


def stability_steps(lam, span: float) -> float:
    """The explicit steps a span needs for stability alone, from eigenvalues lam."""
    lam = np.asarray(lam).ravel()
    if not np.all(np.isfinite(lam)):
        return np.inf
    fast = lam[-lam.real * span > DECAYED]
    return float(np.max(np.abs(fast)) * span / STABLE_HLAMBDA) if fast.size else 0.0


def _eigenvalues(mod, t, x, p) -> np.ndarray:
    n = mod.N_STATES
    J = np.asarray(mod.jacobian(t, x, p), dtype=float).reshape(n, n, -1)
    pick = np.unique(np.linspace(0, J.shape[2] - 1, SAMPLE).round().astype(int))
    J = np.moveaxis(J[:, :, pick], 2, 0)
    if not np.all(np.isfinite(J)):
        return np.array([np.inf])
    return np.linalg.eigvals(J).ravel()


def choose(mod, t_span, p=None, x0=None, breakpoints=(), max_step=np.inf) -> tuple[str, str]:
    """(method, why) for a run of mod over t_span: DOP853 when no probe point needs more than
    STEP_BUDGET stability-bound steps, else (or when the probe fails) Radau."""
    t0, t1 = float(t_span[0]), float(t_span[1])
    span = abs(t1 - t0)
    t_probe = t0 + PROBE_FRACTION * (t1 - t0)
    try:
        with np.errstate(all="ignore"):
            res = mod.simulate((t0, t_probe), t_eval=np.linspace(t0, t_probe, PROBE_POINTS),
                               method=IMPLICIT, p=p, x0=x0, breakpoints=breakpoints,
                               max_step=max_step, max_steps=PROBE_STEPS)
            worst = 0.0
            for k, t in enumerate(res.t):
                worst = max(worst, stability_steps(
                    _eigenvalues(mod, t, res.x[..., k], p), span))
    except (mod.SimulationError, ValueError, np.linalg.LinAlgError) as exc:
        return IMPLICIT, f"auto: Radau, the stiffness probe failed ({type(exc).__name__})"
    if worst > STEP_BUDGET:
        return IMPLICIT, (f"auto: stiff, DOP853 would need about {worst:.3g} steps for "
                          "stability alone")
    return EXPLICIT, f"auto: not stiff (at most {worst:.3g} stability-bound steps)"
