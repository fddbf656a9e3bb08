"""Hybrid bond graphs: ideal switches whose mode changes causality (stage 3 and 4 per mode).

An ``Sw`` element (``{type: Sw, closed: <expression of modes>}``) is an ideal switch in the
sense of 20-sim's switch and of Mosterman and Biswas's controlled junctions: where it is closed
(the expression at least 1/2) it is a zero effort source, Se(0); where it is open, a zero flow
source, Sf(0). Either way the bond graph around it is an ordinary one, so each combination of
the switches' positions (a *mode*) gets its own causality (SCAP, with storage in derivative
causality eliminated as usual) and its own equations, all at compile time. A mode whose
causality cannot be assigned (a closed switch joining two effort sources, say) is a located
error naming the mode.

The modes are then merged into one set of equations over one state vector: the union of every
mode's states. A storage element in derivative causality in a mode keeps its state there, and
the state follows the constraint (its derivative is the constraint's time derivative, from the
elimination). Every derivative, output, event guard and reset becomes a choice on the mode
variables (nested ``Piecewise``: ``numpy.where`` per instance in numpy, ternaries in C), and
each mode's intermediate variables get a suffix ``_m<k>`` so that a symbol may be a state in
one mode and an assignment in another. The Jacobian is derived again along the merged
assignments. A mode change happens only in an event, whose resets must leave the states
consistent with the new mode's constraints (the clutch locking: momenta redistributed,
conserving the total); see docs/events.md.
"""
from __future__ import annotations

import itertools
from dataclasses import replace as dc_replace

import sympy as sp

from bgc.base.errors import ModelError
from bgc.core.causality import assign_causality
from bgc.core.context import Context
from bgc.core.eqtypes import Equations, StateVar
from bgc.core.events import EventEq, mode_ids
from bgc.core.forward import jacobian
from bgc.core.graph import BondGraph, FlatElement
from bgc.format.expr import shape_of
from bgc.format.whitelist import Expr

#: the most switches a model may have (every combination of positions is compiled)
MAX_SWITCHES = 6


def switches(bg: BondGraph) -> tuple[FlatElement, ...]:
    return tuple(el for el in bg.elements if el.type == "Sw")


def mode_label(sws, combo) -> str:
    return ", ".join(f"{sw.id} {'closed' if c else 'open'}" for sw, c in zip(sws, combo))


def mode_graph(bg: BondGraph, combo: tuple[bool, ...]) -> BondGraph:
    """The bond graph of one mode: each switch a zero effort (closed) or flow (open) source."""
    sws = {sw.id: c for sw, c in zip(switches(bg), combo)}
    elements = []
    for el in bg.elements:
        if el.id in sws:
            law = ("effort", Expr("0", el.coord)) if sws[el.id] else ("flow", Expr("0", el.coord))
            el = dc_replace(el, type="Se" if sws[el.id] else "Sf", law=law)
        elements.append(el)
    return BondGraph(bg.model, bg.params, tuple(elements), bg.bonds, bg.states, bg.scopes)


def derive_switched(bg: BondGraph, fold, zero, derive_one, declare) -> Equations:
    """Equations of a bond graph with switches: each mode's causality and equations, merged.

    ``derive_one(graph, causality)`` derives one mode (bgc.core.equations.derive without
    switches); ``declare(ctx)`` declares a context's states (to read the switches' positions)."""
    sws = switches(bg)
    if len(sws) > MAX_SWITCHES:
        raise ModelError(sws[MAX_SWITCHES].coord,
                         f"Sw {sws[MAX_SWITCHES].id!r}: more than {MAX_SWITCHES} switches "
                         f"({2 ** MAX_SWITCHES} modes, each compiled): join switches that "
                         "always move together into one")
    combos = list(itertools.product((True, False), repeat=len(sws)))
    per_mode, causes = [], []
    for combo in combos:
        g = mode_graph(bg, combo)
        try:
            caus = assign_causality(g, allow_derivative=True)
            eqs = derive_one(g, caus)
        except ModelError as err:
            message = err.message
            for sw, closed in zip(sws, combo):  # the switch by its own name, not its stand-in
                message = message.replace(f"{'Se' if closed else 'Sf'} {sw.id!r}",
                                          f"Sw {sw.id!r} ({'closed' if closed else 'open'})")
            raise ModelError(err.coord or sws[0].coord,
                             f"switch mode ({mode_label(sws, combo)}): {message}",
                             err.advice) from None
        if eqs.newton:
            raise ModelError(sws[0].coord, f"switch mode ({mode_label(sws, combo)}): a "
                                           "nonlinear algebraic loop in a switched model is not "
                                           "supported (solve it symbolically, or add a "
                                           "storage element)")
        per_mode.append(eqs)
        causes.append(caus)
    ctx = Context(mode_graph(bg, combos[0]), causes[0], fold, zero)
    declare(ctx)
    closed = [_position(ctx, sw) for sw in sws]
    return _merge(bg, closed, combos, per_mode)


def _position(ctx: Context, sw: FlatElement):
    """The switch's ``closed`` expression as a sympy condition of modes and parameters."""
    what = f"Sw {sw.id!r} (closed)"
    val = ctx.build(sw.law[1], sw.scope, what)
    if shape_of(val):
        raise ModelError(sw.law[1].coord, f"{what}: the position must be a scalar")
    modes = {ctx.states[m] for m in mode_ids(ctx.bg) if m in ctx.states}
    params = {s for pv in ctx.params.values() for s in pv.symbols}
    params |= {a.symbol for a in ctx.derived.values()}
    stray = val.free_symbols - modes - params
    if stray:
        raise ModelError(sw.law[1].coord, f"{what}: the position must be an expression of "
                                          "modes and parameters (only an event moves a "
                                          f"switch); it reads {', '.join(sorted(map(str, stray)))}")
    return sp.Gt(val, sp.Rational(1, 2))


def _renamed(eqs: Equations, k: int) -> dict:
    return {a.symbol: sp.Symbol(f"{a.symbol}_m{k}", **a.symbol.assumptions0)
            for a in eqs.assignments}


def _choose(closed, combos, leaves):
    """Nested Piecewise over the switches' positions; one leaf where every mode agrees."""
    if all(v == leaves[0] for v in leaves[1:]):
        return leaves[0]
    index = {c: v for c, v in zip(combos, leaves)}

    def tree(prefix):
        if len(prefix) == len(closed):
            return index[prefix]
        on, off = tree(prefix + (True,)), tree(prefix + (False,))
        return on if on == off else sp.Piecewise((on, closed[len(prefix)]), (off, True))

    return tree(())


def _merge(bg, closed, combos, per_mode) -> Equations:
    base = max(per_mode, key=lambda e: len(e.states))
    states = list(base.states)
    for eqs in per_mode:
        states += [sv for sv in eqs.states if sv.symbol not in {s.symbol for s in states}]
    renames = [_renamed(eqs, k) for k, eqs in enumerate(per_mode)]
    kept = []
    for eqs, ren in zip(per_mode, renames):
        kept += [dc_replace(a, symbol=ren[a.symbol], expr=a.expr.xreplace(ren))
                 for a in eqs.assignments]

    def pick(values):
        return _choose(closed, combos, [v.xreplace(r) for v, r in zip(values, renames)])

    derivs = []
    for sv in states:
        derivs.append(pick([_rate(bg, eqs, sv, combo, closed) for eqs, combo
                            in zip(per_mode, combos)]))
    outputs = tuple((name, shp, tuple(pick([eqs.outputs[i][2][j] for eqs in per_mode])
                                      for j in range(len(vals))))
                    for i, (name, shp, vals) in enumerate(base.outputs))
    events = tuple(_merge_event(ev, i, per_mode, pick) for i, ev in enumerate(base.events))
    events = _consistent(events, states, per_mode, pick)
    jac, jac_assign = jacobian(kept, states, derivs, ())
    loops = tuple(dict.fromkeys(lp for eqs in per_mode for lp in eqs.loops))
    warnings = tuple(dict.fromkeys(w for eqs in per_mode for w in eqs.warnings))
    dependent = tuple(dict.fromkeys(d for eqs in per_mode for d in eqs.dependent))
    return dc_replace(base, states=tuple(states), assignments=tuple(kept),
                      derivatives=tuple(derivs), outputs=outputs, jacobian=jac,
                      jac_assignments=tuple(jac_assign), loops=loops, warnings=warnings,
                      dependent=dependent, newton=(), events=events)


def _rate(bg, eqs: Equations, sv: StateVar, combo, closed):
    """The state's derivative in one mode: its own, or the constraint's (derivative causality)."""
    for own, d in zip(eqs.states, eqs.derivatives):
        if own.symbol == sv.symbol:
            return d
    rates = {s: d for s, d, _ in eqs.rates}
    if sv.symbol in rates:
        return rates[sv.symbol]
    raise ModelError(bg.element(sv.owner).coord if sv.owner in {e.id for e in bg.elements}
                     else bg.model.coord,
                     f"internal: state {sv.name!r} has no derivative in switch mode "
                     f"({mode_label(switches(bg), combo)})")


def _consistent(events, states, per_mode, pick):
    """Every event also sets each state that is dependent in some mode to its constraint's
    value where the event starts in that mode (unless the event sets it): the integrated state
    has drifted from the constraint by the solver's error, and the next mode starts from it."""
    values = [{s: v for s, _, v in eqs.rates} for eqs in per_mode]
    follow = [sv.symbol for sv in states if any(sv.symbol in v for v in values)]
    out = []
    for ev in events:
        own = {s for s, _ in ev.resets}
        extra = tuple((s, pick([v.get(s, s) for v in values])) for s in follow if s not in own)
        out.append(EventEq(ev.name, ev.coord, ev.guard, ev.direction, ev.resets + extra,
                           ev.timed))
    return tuple(out)


def _merge_event(ev: EventEq, i: int, per_mode, pick) -> EventEq:
    guard = pick([eqs.events[i].guard for eqs in per_mode])
    resets = tuple((s, pick([dict(eqs.events[i].resets)[s] for eqs in per_mode]))
                   for s, _ in ev.resets)
    return EventEq(ev.name, ev.coord, guard, ev.direction, resets, ev.timed)
