"""A run's initial state against the model's closed-loop constraints (issue 24): a scene's
``initial:`` values or an API caller's x0 are checked at run start, as the compile checks the
model's own initial state (bgc.core.assembly).

From the generated module alone: with q the constraints' violation states (CONSTRAINT_STATES),
the velocity residual is q' = rhs[q] and, as the reaction holds
q'' + 2 alpha q' + alpha^2 Phi = 0 (Phi the `closure:` residual where one is given, else q),
the position residual is Phi = -(q'' + 2 alpha q') / alpha^2 with q'' = (J rhs + d/dt rhs)[q]
(J the analytic Jacobian; d/dt by central differences, nonzero only for flows of t).
"""
from __future__ import annotations

import numpy as np

from bgc.base.errors import ModelError

_TOL = 1e-8  # relative to the state's scale (1 at least)


def start_residuals(mod, t0: float, x0, p=None) -> dict | None:
    """{constraint source: (position residual, velocity residual)} at (t0, x0), None where the
    module has no constraints."""
    names = tuple(getattr(mod, "CONSTRAINT_STATES", ()))
    idx = [i for i, s in enumerate(mod.STATE_NAMES) if s in names]
    if not idx:
        return None
    x0 = np.asarray(x0, dtype=float)
    alpha = float(mod.CONSTRAINT_ALPHA)
    f = np.asarray(mod.rhs(t0, x0, p), dtype=float)
    jac = np.asarray(mod.jacobian(t0, x0, p), dtype=float)
    h = 1e-6 * max(1.0, abs(t0))
    dft = (np.asarray(mod.rhs(t0 + h, x0, p), dtype=float)
           - np.asarray(mod.rhs(t0 - h, x0, p), dtype=float)) / (2 * h)
    acc = (jac @ f + dft)[idx]
    vel = f[idx]
    pos = -(acc + 2 * alpha * vel) / alpha ** 2
    out: dict = {}
    for k, i in enumerate(idx):
        src = mod.STATE_NAMES[i].split(".q")[0]
        p_, v_ = out.get(src, ([], []))
        out[src] = (p_ + [float(pos[k])], v_ + [float(vel[k])])
    return out


def check_loop_start(mod, t0: float, x0, p, coord, what: str) -> None:
    """A located error (at ``coord``: the scene's `initial:`, or None for an API call) when
    ``x0`` violates a constraint: the positions (its closure) or the velocities."""
    res = start_residuals(mod, t0, x0, p)
    if not res:
        return
    x0 = np.asarray(x0, dtype=float)
    scale = max(1.0, float(np.abs(x0).max()))
    for src, (pos, vel) in res.items():
        for kind, vals, unit in (("positions violate its closure", pos, "displacement"),
                                 ("velocities violate it", vel, "flow")):
            if max(abs(v) for v in vals) > _TOL * scale:
                shown = ", ".join(f"{v:.6g}" for v in vals)
                raise ModelError(coord, f"{what}: constraint {src!r} closing a kinematic loop: "
                                 f"the initial {kind}: the residual is [{shown}] (SI units of "
                                 f"the bond's {unit}); give an initial state that closes the "
                                 "loop, or set `constraints: {initial: project}` in the model "
                                 "and leave these states to it")
