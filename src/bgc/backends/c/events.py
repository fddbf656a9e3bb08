"""A hybrid model's events in C (the C backend and the FMU): the lowered guards and resets
(bgc.lower.events) printed as parts like rhs, for the templates' ``events`` value."""
from __future__ import annotations

from bgc.lower.events import lower_events


def c_events(eq, parts) -> dict | None:
    """The template's ``events`` value (None without events): ``parts(name, fn)`` prints one
    lowered function as C parts; each reset writes the states it sets, listed in ``index``."""
    low = lower_events(eq)
    if low is None:
        return None
    resets = [{"fn": parts(f"reset{k}", fn), "index": [key for key, _ in fn.results]}
              for k, fn in enumerate(low.resets)]
    return {"nev": len(low.names), "dirs": list(low.directions), "names": list(low.names),
            "timed": [int(t) for t in low.timed],
            "guards": parts("guards", low.guards), "resets": resets}


def event_parts(events) -> list:
    """The parts the events' functions were printed into (none without events)."""
    if events is None:
        return []
    return [p for f in [events["guards"]] + [r["fn"] for r in events["resets"]] for p in f.parts]
