"""Checks of `bgc linearize` that turn a model's numerical failure into one located line: an
equilibrium search on a right-hand side that is not finite (a zero mass, a root of a negative
parameter), and a linearisation whose matrices are not finite (a ``k/q`` law at q = 0)."""
from __future__ import annotations

import numpy as np

from bgc.base.errors import ModelError


def equilibrium(mod, p, t, coord):
    """mod.equilibrium(p, t), or a ModelError at coord when the search fails numerically."""
    with np.errstate(all="ignore"):
        try:
            x, info = mod.equilibrium(p=p, t=t)
        except (np.linalg.LinAlgError, ValueError, FloatingPointError) as exc:
            raise ModelError(coord, f"no equilibrium found: the search failed ({exc}); is the "
                                    "right-hand side finite near the initial state?") from None
    if not np.all(np.isfinite(x)):
        raise ModelError(coord, "no equilibrium found: the search reached a state that is "
                                "not finite")
    return x, info


def linearization(mod, t, x, p, coord, where: str):
    """mod.linearize(t, x, None, p) whose A, B, C, D are finite, else a ModelError at coord
    naming the first entry of A that is not (its state's equation and owner)."""
    with np.errstate(all="ignore"):
        try:
            lin = mod.linearize(t, x, None, p)
        except (np.linalg.LinAlgError, ValueError, FloatingPointError) as exc:
            raise ModelError(coord, f"cannot linearise at {where}: {exc}") from None
    for name, m in zip("ABCD", lin):
        bad = np.argwhere(~np.isfinite(np.asarray(m, dtype=float)))
        if bad.size:
            i, j = (int(v) for v in bad[0][:2])
            owner = ""
            if name == "A" and i < len(getattr(mod, "STATE_OWNERS", ())):
                owner = f" (the equation of state {mod.STATE_NAMES[i]!r}, element " \
                        f"{mod.STATE_OWNERS[i]!r})"
            raise ModelError(coord, f"cannot linearise at {where}: {name}[{i}, {j}] is "
                                    f"{np.asarray(m)[i, j]:g}{owner}")
    return lin
