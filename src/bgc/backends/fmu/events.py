"""A hybrid model's events in an FMU (Model Exchange): the guards become the event indicators
and each event's resets a C function (bgc.backends.c.events); the glue
(templates/c/fmu/bgc_fmi2.c) fires them in fmi2NewDiscreteStates. Co-Simulation would need the
FMU's step to locate events inside it: not written yet, a located error."""
from __future__ import annotations

from bgc.backends.c.events import c_events
from bgc.base.errors import ModelError


def fmu_events(eq, kind: str, parts) -> dict | None:
    """The template's ``events`` value (None without events); a located error unless the FMU
    is Model Exchange only."""
    if eq.events and kind != "me":
        ev = eq.events[0]
        raise ModelError(ev.coord, f"event {ev.name!r}: an FMU with events is Model Exchange "
                                   "only (events inside Co-Simulation steps are not located "
                                   "yet): export with --kind me")
    return c_events(eq, parts)
