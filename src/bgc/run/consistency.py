"""A run's initial state against the model's closed-loop constraints (issue 24): a scene's
``initial:`` values or an API caller's x0 are checked at run start, as the compile checks the
model's own initial state (bgc.core.assembly), and a scene's ``constraints: {initial:
project}`` projects them there.

From the generated module alone (numpy or C, the same names): ``constraint_residuals(t, x, p)``
gives each constraint component's position residual (its `closure:`, else its violation q) and
velocity residual (f - s), ``kinetic_energy(t, x, p)`` the metric of the velocity projection,
``constraint_violation`` the message the module's own ``simulate`` raises; CLOSURE_STATES and
MOMENTUM_STATES name what a projection moves (bgc.core.projection: Newton on the positions,
then the momenta of least kinetic-energy distance).
"""
from __future__ import annotations

import numpy as np

from bgc.base.errors import ModelError
from bgc.core.projection import (
    NEWTON_ITER,
    affine_rows,
    changes,
    kinetic_projection,
    newton_positions,
    quadratic_hessian,
)

_ADVICE = ("give an initial state that closes the loop, or set `constraints: {initial: "
           "project}` in the scene (or the model) and leave these states to it")


def check_loop_start(mod, t0: float, x0, p, coord, what: str) -> None:
    """A located error (at ``coord``: the scene's `initial:`, or None for an API call) when
    ``x0`` violates a constraint: the positions (its closure) or the velocities; the message
    is the module's own (``constraint_violation``)."""
    violation = getattr(mod, "constraint_violation", None)
    if violation is None or not hasattr(mod, "constraint_residuals"):
        return
    msg = violation(t0, x0, p)
    if msg:
        raise ModelError(coord, f"{what}: {msg}; {_ADVICE}")


def project_start(mod, t0: float, x0, p, coord) -> tuple[np.ndarray, list[str]]:
    """(x, notes): x0 projected onto the constraints at t0: the states the closures read by
    Newton's method on the closures (minimum-norm steps), then the momenta by the change of
    least kinetic-energy distance onto the velocity constraints. ``notes`` say what changed
    (old -> new), as the model-level projection's. Unchanged for a model without constraints."""
    x = np.array(x0, dtype=float)
    if not hasattr(mod, "constraint_residuals") or x.ndim != 1:
        return x, []
    names = list(mod.STATE_NAMES)
    notes: list[str] = []
    rows = [k for k, closed in enumerate(mod.CONSTRAINT_CLOSED) if closed]
    pos = [names.index(s) for s in mod.CLOSURE_STATES]
    if rows and pos:
        def phi(v):
            y = x.copy()
            y[pos] = v
            return np.asarray(mod.constraint_residuals(t0, y, p)[0], dtype=float)[rows]

        new, r = newton_positions(phi, x[pos])
        if not np.isfinite(new).all() or np.abs(r).max() > 1e-12 * max(1.0, np.abs(new).max()):
            raise ModelError(coord, "constraints: initial: project found no configuration that "
                             "closes the loop near the given one (residual "
                             f"[{', '.join(f'{v:.6g}' for v in r)}] after {NEWTON_ITER} Newton "
                             "steps); give initial positions closer to an assembled one")
        text = changes([names[i] for i in pos], x[pos], new)
        x[pos] = new
        if text:
            notes.append(f"initial positions projected onto the loop closure: {text}")
    mom = [names.index(s) for s in mod.MOMENTUM_STATES]
    if mom:
        old = x[mom].copy()

        def at(v, k):
            y = x.copy()
            y[mom] = v
            return (np.asarray(mod.constraint_residuals(t0, y, p)[1], dtype=float) if k == 0
                    else float(np.asarray(mod.kinetic_energy(t0, y, p))))

        metric = True
        for _ in range(2):  # the second pass removes what rounding left
            r0, g = affine_rows(lambda v: at(v, 0), x[mom])
            dp, metric = kinetic_projection(r0, g, quadratic_hessian(lambda v: at(v, 1), x[mom]))
            x[mom] = x[mom] + dp
        text = changes([names[i] for i in mom], old, x[mom])
        how = ("least kinetic-energy change" if metric else
               "minimum-norm change: no kinetic energy known")
        if text:
            notes.append(f"initial momenta projected onto the velocity constraints ({how}): "
                         f"{text}")
    return x, notes
