"""The numpy module's part for a hybrid model's events: the lowered guards and resets
(bgc.lower.events) printed for templates/numpy/events.py.j2. A model without events gets None
and its module is exactly what it was before events existed."""
from __future__ import annotations

from bgc.core.equations import Equations
from bgc.lower.events import lower_events


def events_part(eq: Equations, printer, printed) -> dict | None:
    """The template's ``events`` value: names, places, directions, the guard function and one
    reset function per event, each printed by ``printed(fn, printer)``."""
    low = lower_events(eq)
    if low is None:
        return None
    return {"names": list(low.names), "where": list(low.where),
            "directions": list(low.directions), "timed": [int(t) for t in low.timed],
            "guards": printed(low.guards, printer),
            "resets": [printed(fn, printer) for fn in low.resets],
            "modes": [sv.name for sv in eq.states if sv.owner in eq.modes]}
