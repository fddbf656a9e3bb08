"""A hybrid model's events in an FMU (Model Exchange): the guards become the event indicators
and each event's resets a C function, printed as parts like rhs (bgc.backends.c.printer); the
glue (templates/c/fmu/bgc_fmi2.c) fires them in fmi2NewDiscreteStates. Co-Simulation would
need the C integrators to locate events inside a step: not written yet, a located error."""
from __future__ import annotations

from bgc.base.errors import ModelError
from bgc.lower.events import lower_events


def fmu_events(eq, kind: str, parts) -> dict | None:
    """The template's ``events`` value (None without events): ``parts(name, fn)`` prints one
    lowered function as C parts."""
    low = lower_events(eq)
    if low is None:
        return None
    if kind != "me":
        ev = eq.events[0]
        raise ModelError(ev.coord, f"event {ev.name!r}: an FMU with events is Model Exchange "
                                   "only (events inside Co-Simulation steps are not located "
                                   "yet): export with --kind me")
    resets = [{"fn": parts(f"reset{k}", fn), "index": [key for key, _ in fn.results]}
              for k, fn in enumerate(low.resets)]
    return {"nev": len(low.names), "dirs": list(low.directions), "names": list(low.names),
            "guards": parts("guards", low.guards), "resets": resets}
