"""The model's events as equations: each event's guard g(t, x, u, p) (a zero crossing in the
given direction; a time event ``at: T`` is g = t - T, rising) and its resets (a state's new
value, an expression of the values just before the event). Built by
:func:`bgc.core.equations.derive` with the same name resolution as the laws, so a guard or a
reset may read states, modes, inputs, parameters, t and the bond variables e(), f(), p(), q().
"""
from __future__ import annotations

from dataclasses import dataclass

import sympy as sp

from bgc.base.errors import Coord, ModelError
from bgc.core.constraints import parameter_values
from bgc.core.graph import join
from bgc.format.expr import Expr, shape_of


@dataclass(frozen=True)
class EventEq:
    name: str
    coord: Coord
    guard: object  # sympy scalar: the event fires where it crosses zero
    direction: int  # +1 rising, -1 falling, 0 either
    resets: tuple[tuple[sp.Symbol, object], ...]  # (state symbol, new value)
    #: a time event (``at``, ``every``): its guard is t - (its time), which the runtimes do not
    #: search: they integrate up to the time (a breakpoint) and fire it there
    timed: bool = False

    def replace(self, subs: dict) -> EventEq:
        """The same event with ``subs`` applied (derive inlines plain copies)."""
        if not subs:
            return self
        return EventEq(self.name, self.coord, self.guard.xreplace(subs), self.direction,
                       tuple((s, v.xreplace(subs)) for s, v in self.resets), self.timed)

    def exprs(self):
        yield self.guard
        for _, v in self.resets:
            yield v


def flat_events(bg) -> list:
    """(scope, event) of the model's events, then of each component instance's, in the
    order the instances were expanded: an instance's events are its own (names prefixed)."""
    out = [((), ev) for ev in bg.model.events]
    for scope in bg.scopes.values():
        comp = bg.model.component(scope.component) if scope.component else None
        if comp is not None:
            out += [(scope.prefix, ev) for ev in comp.events]
    return out


def mode_ids(bg) -> tuple[str, ...]:
    """The flat ids of the mode variables: the model's, then each instance's (prefixed)."""
    out = list(bg.model.modes)
    for scope in bg.scopes.values():
        comp = bg.model.component(scope.component) if scope.component else None
        if comp is not None:
            out += [join(scope.prefix, m) for m in comp.modes]
    return tuple(out)


def _flat(v) -> list:
    return list(v) if isinstance(v, sp.MatrixBase) else [v]


def build_events(ctx, bg, state_vars, t_symbol, switched=False) -> tuple[EventEq, ...]:
    """Every event of the model (``bg.model.events``), resolved in the model's top scope.
    ``switched``: one mode of a switched graph (bgc.core.modes), where a storage element in
    derivative causality keeps its state in the merged equations, so an action may set it."""
    symbols = {sv.symbol for sv in state_vars}
    if switched:
        symbols |= {s for _, syms, _ in ctx.dependent for s in syms}
    return tuple(_event(ctx, bg, scope, ev, symbols, t_symbol)
                 for scope, ev in flat_events(bg))


def _event(ctx, bg, scope, ev, symbols, t_symbol) -> EventEq:
    name = join(scope, ev.name)
    what = f"event {name!r}"
    if ev.condition is not None:
        guard = ctx.build(ev.condition, scope, f"{what} condition")
        where = ev.condition.coord
    elif ev.every is not None:  # at + n every, n the event's count (a state its reset moves on)
        where = ev.every.coord
        period = ctx.build(ev.every, scope, f"{what} period", params_only=True)
        first = period if ev.at is None else ctx.build(ev.at, scope, f"{what} time",
                                                       params_only=True)
        count = ctx.build(Expr(ev.count_state, ev.coord), scope, f"{what} count")
        guard = t_symbol - (first + count * period)
    else:
        guard = t_symbol - ctx.build(ev.at, scope, f"{what} time", params_only=True)
        where = ev.at.coord
    if shape_of(guard):
        raise ModelError(where, f"{what}: the condition must be a scalar, not of shape "
                                f"{'x'.join(map(str, shape_of(guard)))}")
    inputs = {s for iv in ctx.inputs.values() if iv is not None for s in iv.symbols}
    if not guard.free_symbols & (symbols | inputs | {t_symbol}):
        raise ModelError(where, f"{what}: the condition reads no state, input or t: it "
                                "never crosses zero")
    resets: dict = {}
    for act in ev.actions:
        target = _target(ctx, bg, scope, act, symbols, what)
        value = ctx.build(act.value, scope, f"{what}, action on {act.label!r}")
        if shape_of(value) != shape_of(target):
            raise ModelError(act.value.coord, f"{what}: {act.label!r} has shape "
                                              f"{_shape(target)}, the value {_shape(value)}")
        for s, v in zip(_flat(target), _flat(value)):
            if s in resets:
                raise ModelError(act.coord, f"{what}: {act.label!r} is set twice")
            resets[s] = v
    if ev.every is not None:
        if shape_of(period):
            raise ModelError(where, f"{what}: the period must be a scalar")
        value = _with_defaults(ctx, period)
        if value is not None and not value > 0:  # (false for nan too)
            raise ModelError(where, f"{what}: the period is {value:g} with the parameters' "
                                    "values (the model's, or a scene's): it must be positive")
        if shape_of(first):
            raise ModelError(ev.at.coord, f"{what}: the time must be a scalar")
        if count in resets:
            raise ModelError(ev.coord, f"{what}: {ev.count_state!r} is the event's own count: "
                                       "an action may not set it")
        resets[count] = count + 1
    return EventEq(name, ev.coord, guard, ev.direction, tuple(resets.items()),
                   ev.condition is None)


def _with_defaults(ctx, expr) -> float | None:
    """A scalar expression of parameters at their default values (derived ones in their
    order), or None where it is not a number."""
    vals = parameter_values(ctx)
    if vals is None:
        return None
    try:
        v = expr.xreplace(vals)
        return float(v) if v.is_number and v.is_real else None
    except (TypeError, ValueError, AttributeError):
        return None


def _shape(v) -> str:
    shp = shape_of(v)
    return "x".join(map(str, shp)) if shp else "scalar"


def _target(ctx, bg, scope, act, symbols, what):
    """The state symbol(s) an action sets; a located error for anything that is not a state."""
    label = act.label
    if act.func:
        kind = bg.scopes[scope].names.get(act.path[0]) if len(act.path) == 1 else "element"
        eid = join(scope, ".".join(act.path))
        if kind == "element" and eid not in ctx.states and _is_storage(bg, eid):
            raise ModelError(act.coord, f"{what}: {label} has no state of its own (the "
                                        "element is in derivative causality): reset an "
                                        "independent one")
    value = ctx.build(Expr(label, act.coord), scope, f"{what}, action")
    if not all(s in symbols for s in _flat(value)):
        raise ModelError(act.coord, f"{what}: cannot assign to {label!r}: it is not a state "
                                    "(an action sets p(X), q(X), an auxiliary state or a mode)")
    return value


def _is_storage(bg, eid: str) -> bool:
    try:
        return bg.element(eid).type in ("I", "C")
    except KeyError:
        return False
