"""The model's ``modes:`` and ``events:`` sections (hybrid models): what the user writes, read
with a place for every value. Names are resolved later (bgc.core.events), by the stage that
knows the states.

    modes:                       # discrete mode variables: name: initial value (of parameters)
      stuck: 1
    events:
      impact:
        when: "h"                # a zero crossing of an expression of states, inputs, t, ...
        direction: falling       # rising | falling | either (the default)
        do:                      # actions, all computed from the values before the event
          "p(ball)": "-e_r*p(ball)"
      release:
        at: "t_off"              # a time event: an expression of parameters
        do: {stuck: 0}
      sample:
        every: "T_s"             # a periodic time event: at 'at' (default: one period), then
        do: {...}                # every T_s; how often it fired is the state sample_count

Time events are no zero crossings to locate: the runtimes integrate exactly up to them (a
breakpoint) and fire them there.

A mode variable is a discrete state: the solver sees it as a state whose derivative is zero, so
every law, output and event may read it (``where(stuck == 1, ...)``) and only an event changes it.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field

import yaml

from bgc.base.errors import Coord, ModelError
from bgc.format.expr import Expr
from bgc.format.reader import IDENT, Reader, check_name, require

DIRECTIONS = {"rising": 1, "falling": -1, "either": 0}
#: how many events a model may declare (each is a function the solver evaluates every step)
MAX_EVENTS = 1000
_TARGET = re.compile(r"\s*([pq])\(\s*([A-Za-z][A-Za-z0-9_.]*)\s*\)\s*")  # with fullmatch


@dataclass(frozen=True)
class Action:
    """``target: value``: the state (``p(X)``, ``q(X)``, an auxiliary state or a mode) gets
    the value, an expression evaluated just before the event."""
    func: str  # "p", "q", or "" (a named state or mode)
    path: tuple[str, ...]
    value: Expr
    coord: Coord  # of the target key

    @property
    def label(self) -> str:
        name = ".".join(self.path)
        return f"{self.func}({name})" if self.func else name


@dataclass(frozen=True)
class Event:
    name: str
    condition: Expr | None  # zero crossing of this expression (None: a time event)
    at: Expr | None  # time event: the time, an expression of parameters
    direction: int  # +1 rising, -1 falling, 0 either
    actions: tuple[Action, ...]
    coord: Coord
    every: Expr | None = None  # periodic time event: the period (from ``at``, default one period)
    description: str = field(default="", compare=False)  # documentation only (bgc library)

    @property
    def count_state(self) -> str:
        """A periodic event's state: how many times it fired (the next time is at + n every,
        one rounding however long the run)."""
        return f"{self.name}_count"


@dataclass(frozen=True)
class Mode:
    name: str
    initial: Expr
    coord: Coord
    description: str = field(default="", compare=False)  # documentation only (bgc library)


def read_modes(r: Reader, node) -> tuple[Mode, ...]:
    """``modes: {name: initial}`` (or ``name: {initial: expr, description: text}``)."""
    modes = []
    for mname, (kn, vn) in r.mapping(node, "modes").items():
        check_name(mname, r.coord(kn), "mode")
        desc = ""
        if isinstance(vn, yaml.MappingNode):
            mm = r.mapping(vn, f"mode {mname!r}")
            require(r, mm, vn, ("initial", "description"), f"mode {mname!r}",
                    required=("initial",))
            if "description" in mm:
                desc = r.string(mm["description"][1], f"mode {mname!r} description")
            vn = mm["initial"][1]
        modes.append(Mode(mname, r.expr(vn, f"mode {mname!r} initial"), r.coord(kn), desc))
    return tuple(modes)


def read_events(r: Reader, node) -> tuple[Event, ...]:
    """The ``events:`` mapping: name -> {when | at, direction, do}."""
    events = []
    em = r.mapping(node, "events")
    if len(em) > MAX_EVENTS:
        raise ModelError(r.coord(node), f"events: more than {MAX_EVENTS} events")
    for ename, (kn, vn) in em.items():
        check_name(ename, r.coord(kn), "event", allow_reserved=True)
        events.append(_event(r, ename, kn, vn))
    return tuple(events)


def _event(r: Reader, ename: str, kn, vn) -> Event:
    what = f"event {ename!r}"
    m = r.mapping(vn, what)
    require(r, m, vn, ("when", "at", "every", "direction", "do", "description"), what,
            required=("do",))
    if ("when" in m) == ("at" in m or "every" in m):
        raise ModelError(r.coord(vn), f"{what}: give one of 'when' (a zero crossing) or 'at' "
                                      "(a time) or 'every' (a period)")
    direction = 0
    if "direction" in m:
        if "when" not in m:
            raise ModelError(r.coord(m["direction"][0]), f"{what}: a time event ('at', "
                                                          "'every') has no direction")
        word = r.string(m["direction"][1], f"{what} direction")
        if word not in DIRECTIONS:
            raise ModelError(r.coord(m["direction"][1]),
                             f"{what}: direction {word!r} is not one of rising, falling, either")
        direction = DIRECTIONS[word]
    cond = r.expr(m["when"][1], f"{what} condition") if "when" in m else None
    at = r.expr(m["at"][1], f"{what} time") if "at" in m else None
    every = r.expr(m["every"][1], f"{what} period") if "every" in m else None
    actions = []
    dm = r.mapping(m["do"][1], f"{what} actions")
    if not dm:
        raise ModelError(r.coord(m["do"][1]), f"{what}: 'do' lists no action")
    for target, (tk, tv) in dm.items():
        func, path = _target(r, target, tk, what)
        actions.append(Action(func, path, r.expr(tv, f"{what}, action on {target.strip()!r}"),
                              r.coord(tk)))
    desc = r.string(m["description"][1], f"{what} description") if "description" in m else ""
    return Event(ename, cond, at, direction if cond is not None else 1, tuple(actions),
                 r.coord(kn), every, desc)


def _target(r: Reader, text: str, node, what: str) -> tuple[str, tuple[str, ...]]:
    """An action's target: ``p(X)`` or ``q(X)`` (X an I or C element), or the name of an
    auxiliary state or mode (dotted into component instances)."""
    m = _TARGET.fullmatch(text)
    func, name = (m.group(1), m.group(2)) if m else ("", text.strip())
    path = tuple(name.split("."))
    if not all(IDENT.fullmatch(part) for part in path):
        raise ModelError(r.coord(node), f"{what}: cannot assign to {text[:40]!r}: an action "
                                        "sets p(X), q(X), a state or a mode")
    return func, path
