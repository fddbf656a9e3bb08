"""Lowering a hybrid model's events (bgc.core.events) to IR functions every printer reads: one
function of all the guards (results keyed by event index) and, per event, one function of the
new values of the states it sets (results keyed by state index; the other states are kept).
Each is pruned, CSE'd and scheduled like rhs (bgc.lower.ir.lower_function)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import PurePath

from bgc.core.equations import Equations
from bgc.lower.ir import Function, lower_function


@dataclass(frozen=True)
class LoweredEvents:
    names: tuple[str, ...]
    where: tuple[str, ...]  # "file:line:col" of each event's declaration (the file's name)
    directions: tuple[int, ...]  # +1 rising, -1 falling, 0 either
    guards: Function  # results keyed by event index
    resets: tuple[Function, ...]  # per event: results keyed by state index, in order
    timed: tuple[bool, ...] = ()  # time events: the runtimes stop at their times (breakpoints)


def lower_events(eq: Equations) -> LoweredEvents | None:
    """The events' functions; None for a model without events (its module is unchanged)."""
    if not eq.events:
        return None
    index = {sv.symbol: i for i, sv in enumerate(eq.states)}
    assigns = list(eq.assignments)
    guards = lower_function(eq, [ev.guard for ev in eq.events], assigns,
                            list(range(len(eq.events))))
    resets = []
    for ev in eq.events:
        pairs = sorted((index[s], v) for s, v in ev.resets)
        resets.append(lower_function(eq, [v for _, v in pairs], assigns, [k for k, _ in pairs]))
    # the model file by its name only: the module is the same wherever the model lies
    where = tuple(f"{PurePath(ev.coord.file).name}:{ev.coord.line}:{ev.coord.column}"
                  for ev in eq.events)
    return LoweredEvents(tuple(ev.name for ev in eq.events), where,
                         tuple(ev.direction for ev in eq.events), guards, tuple(resets),
                         tuple(ev.timed for ev in eq.events))
