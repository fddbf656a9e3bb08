"""The constraint components dropped as redundant, watched over a run (issue 24).

The compile judges redundancy at the initial state (bgc.core.assembly): a component whose row
of the velocity constraints' Jacobian adds nothing there gets reaction 0 and is no longer
held. Where the mechanism moves out of that configuration (a change point, a pose where the
row only happened to vanish) the component becomes independent and nothing holds it. Its
violation state q stays a state of the generated module, and q' = f - s, the component's
velocity residual, is its row of ``rhs`` (lowered and printed like every function, numpy and
C alike); the module names those states in ``CONSTRAINT_DROPPED``. After the integration,
:func:`dropped_drift` evaluates ``rhs`` at the output times (one batched call) and reports the largest residual
beyond the run's tolerance scale.
"""
from __future__ import annotations

import numpy as np

#: how far past the run's own tolerance scale a residual may go before it is reported: the
#: kept components hold their rows to the integration error, and a dropped row that stays a
#: combination of kept ones inherits that error, amplified by the combination
FACTOR = 100.0


def dropped_residuals(mod, t, x, p=None) -> tuple[tuple[str, ...], np.ndarray]:
    """(names, residuals): the dropped components' velocity residuals at each output time,
    shape (len(t), len(names)); empty where the module drops none."""
    names = tuple(n for n in getattr(mod, "CONSTRAINT_DROPPED", ())
                  if n in mod.STATE_NAMES)
    if not names:
        return (), np.zeros((len(t), 0))
    idx = [mod.STATE_NAMES.index(n) for n in names]
    x = np.asarray(x, dtype=float)  # (n, len(t)), as simulate returns it
    # one call over the whole trajectory: the output times as a batch (t broadcast with x's
    # batch axis, as the generated rhs takes it on both backends), not one call per sample
    rates = np.asarray(mod.rhs(np.asarray(t, dtype=float), x, p), dtype=float)
    return names, rates[idx].T.reshape(len(t), len(names))


def dropped_drift(mod, t, x, p, rtol: float, atol: float) -> str | None:
    """A warning (one line) when a dropped component's velocity residual at an output time
    exceeds FACTOR * (atol + rtol * S), S the run's state scale (1 at least, as the start
    check's): it names the component, the largest residual and its time. None otherwise."""
    x = np.asarray(x, dtype=float)
    if x.ndim != 2 or not x.size:  # one run, x of shape (n, len(t)); not a batched one
        return None
    names, r = dropped_residuals(mod, t, x, p)
    if not names:
        return None
    scale = max(1.0, float(np.nanmax(np.abs(x))))
    tol = FACTOR * (float(atol) + float(rtol) * scale)
    mags = np.abs(r)
    worst = np.unravel_index(int(np.nanargmax(mags)), mags.shape)
    if not mags[worst] > tol:
        return None
    name = names[worst[1]]
    src = name.split(".q")[0]
    first = float(t[int(np.argmax(mags[:, worst[1]] > tol))])
    return (f"constraint {src!r}: the component {name} was dropped as redundant at the start "
            f"(reaction 0), but its velocity residual reaches {r[worst]:.3g} at t = "
            f"{float(t[worst[0]]):.6g} s (tolerance {tol:.3g}, first passed at t = "
            f"{first:.6g} s): the mechanism left the configuration in which {name} was "
            "redundant, and nothing held it; the results after that time do not respect the "
            "constraint")
