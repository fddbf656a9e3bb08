"""Stage 4: causal bond graph -> state equations with sympy.

Every bond carries an effort and a flow symbol per component (``e_b3``, ``f_link1__b7_2``). The
element that causality makes responsible for a variable defines it by one assignment; the
assignments are sorted into causal order (algebraic loops, found as strongly connected
components, are solved symbolically when linear). Plain copies across junctions are inlined,
everything else stays an assignment, so expressions never swell. The Jacobian is derived in
forward mode along the same assignments (chain rule), never by differentiating an expanded
right-hand side. No ``simplify`` anywhere.

This module is the derivation's outline (``derive``); its parts live beside it:
bgc.core.eqtypes (the records and shared helpers), bgc.core.context (symbols and names),
bgc.core.laws (each element's equations), bgc.core.loops (causal order, algebraic loops,
derivative causality) and bgc.core.forward (the Jacobian and the linearisation's B, C, D).
"""
from __future__ import annotations

import itertools
from dataclasses import replace as dc_replace

import sympy as sp

from bgc.base.errors import ModelError
from bgc.core.canon import replaced
from bgc.core.causality import Causality
from bgc.core.assembly import consistent_initial, constraint_values, numeric_redundancy
from bgc.core.constraints import alpha_of, constraint_states, dropped_states, stabilise
from bgc.core.context import Context, check_names
from bgc.core.eqtypes import (
    SYMBOLIC_MAX,
    Assignment,
    Equations,
    StateVar,
    T,
    flat,
    is_trivial,
    shape_name,
    state_label,
    symbol_array,
    symbol_vector,
)
from bgc.core.events import build_events, flat_events, mode_ids
from bgc.core.forward import TooDeep, jacobian
from bgc.core.graph import BondGraph, FlatElement, code_name
from bgc.core.laws import check_value, element_equations
from bgc.core.loops import causal_order, time_derivatives
from bgc.core.modes import derive_switched, switches
from bgc.format.expr import shape_of


def derive(bg: BondGraph, caus: Causality, progress=None, fold: dict | None = None,
           zero: dict | None = None, symbolic_max: int = SYMBOLIC_MAX,
           newton: bool = True, switched: bool = False) -> Equations:
    """State equations of a causal bond graph.

    ``fold``: parameter id -> value, turned into numbers; ``zero``: removed element id ->
    cardinality, whose variables read as zero (both from scene specialisation). A graph with
    switches (``Sw``) is derived mode by mode and merged (bgc.core.modes; ``caus`` is then
    assigned per mode, and ``switched`` marks one mode's derivation)."""
    if switches(bg):
        return derive_switched(bg, fold, zero, lambda g, c: derive(
            g, c, progress, fold, zero, symbolic_max, newton, switched=True), _declare)
    ctx = Context(bg, caus, fold, zero)
    _declare(ctx)
    defs: dict[sp.Symbol, Assignment] = {}
    owner: dict[sp.Symbol, str] = {}
    derivs: dict[sp.Symbol, object] = {}
    state_vars: list[StateVar] = []
    define = _definer(defs, owner)
    for el in bg.elements:
        element_equations(ctx, el, define, derivs, state_vars)
    _auxiliary_states(ctx, derivs, state_vars)
    constraint_states(ctx, derivs, state_vars)
    outputs = _outputs(ctx)

    tear_sets = ()
    dependent = []
    residual = frozenset()
    if ctx.dependent or ctx.constraints:
        dependent = _dependent(ctx, defs, state_vars)
        if progress:
            progress("differentiating along the causal paths of dependent storage elements")
        seeds = [f for c in ctx.constraints for f in c.flow]
        tear_sets = time_derivatives(ctx, defs, owner, derivs, state_vars, seeds)
        if ctx.constraints:
            dropped = numeric_redundancy(ctx, defs, state_vars)
            residual = stabilise(ctx, defs, owner, alpha_of(bg.model), dropped)
    if progress:
        progress("ordering assignments")
    nloops: list = [] if newton else None
    order, loops = causal_order(bg, defs, owner, tear_sets, symbolic_max, nloops, residual)
    events = build_events(ctx, bg, state_vars, T, switched) if flat_events(bg) else ()
    kept, subs = _inline(order, defs)
    events = tuple(ev.replace(subs) for ev in events)
    rates = tuple((s, d.xreplace(subs), s.xreplace(subs)) for _, syms, dots in ctx.dependent
                  for s, d in zip(syms, dots))
    derivatives = tuple(replaced(derivs[sv.symbol], subs) for sv in state_vars)
    outputs = tuple((n, shp, tuple(replaced(e, subs) for e in vals)) for n, shp, vals in outputs)
    ctx_derived = [ctx.derived[k] for k in ctx.derived_order]
    _check_declared(ctx, state_vars, ctx_derived, kept, derivatives, outputs,
                    [e for ev in events for e in ev.exprs()])
    cvals = constraint_values(ctx, state_vars, kept, subs, derivatives)
    notes = consistent_initial(ctx, state_vars, kept, derivatives, bg.model.project,
                               (cvals.get("constraint_values") or (None,))[-1])

    if progress:
        progress("deriving the Jacobian")
    nloops = [dc_replace(nl, g=tuple(e.xreplace(subs) for e in nl.g)) for nl in nloops or ()]
    tangents: list = []  # the Jacobian's sweep, which the linearisation's C goes on from
    try:
        jac, jac_assign = jacobian(kept, state_vars, derivatives, nloops, keep=tangents)
    except TooDeep as exc:
        el = bg.element(owner[exc.symbol]) if exc.symbol in owner else None
        where = f"{el.type} {el.id!r}" if el is not None else exc.why
        raise ModelError(el.coord if el is not None else None, f"{where}: its law is nested "
                         "too deeply to differentiate (nested where(...)? flatten the "
                         "conditions)") from None
    check_names(bg, ctx, state_vars)
    standing = tuple(w for w in caus.warnings if not w.startswith("R elements with causality"))
    standing += tuple(notes)
    return Equations(bg.model.name, tuple(state_vars), tuple(ctx.params.values()),
                     tuple(ctx_derived), tuple(ctx.inputs[i.name] for i in bg.model.inputs),
                     tuple(kept), derivatives, outputs, jac, tuple(jac_assign), tuple(loops),
                     warnings=standing, dependent=tuple(dependent), newton=tuple(nloops),
                     events=events, modes=mode_ids(bg), rates=rates,
                     redundant=tuple(ctx.redundant),
                     constraint_states=tuple(sv.name for sv in state_vars
                                             if sv.owner in {c.source for c in ctx.constraints}),
                     constraint_alpha=alpha_of(bg.model) if ctx.constraints else 0.0,
                     constraint_dropped=dropped_states(ctx), jac_tangents=tangents[0],
                     **cvals)


def _declare(ctx: Context) -> None:
    """States of storage elements, then auxiliary states, in declaration order; the inputs."""
    bg, caus = ctx.bg, ctx.caus
    for el in bg.elements:
        if el.type in ("I", "C") and el.id not in caus.derivative:
            n = bg.bonds_of(el.id)[0].n
            letter = "p" if el.type == "I" else "q"
            sym = symbol_vector(f"{letter}_{code_name(el.id)}", n)
            ctx.states[el.id] = sym
    for st in bg.states:
        ctx.states[st.id] = symbol_array("s_" + code_name(st.id), st.shape)
    for inp in bg.model.inputs:
        ctx.inputs_value(inp.name, inp.coord)


def _definer(defs: dict, owner: dict):
    """The ``define(var, value, element, why)`` the element laws call: one assignment per
    component of ``var``, its shape checked against the value's."""

    def define(var, value, el: FlatElement, why: str):
        if not shape_of(var) and shape_of(value) == (1, 1):  # e.g. M^T e2 of an n2 x 1 modulus
            value = value[0, 0]
        if shape_of(var) != shape_of(value):
            raise ModelError(el.coord, f"{el.type} {el.id!r}: cardinality mismatch: its law "
                                       f"gives {shape_name(shape_of(value))}, its bond "
                                       f"carries {shape_name(shape_of(var))}")
        targets = set(flat(var))
        for s, v in zip(flat(var), flat(value)):
            check_value(v, el, targets)
            defs[s] = Assignment(s, v, why)
            owner[s] = el.id

    return define


def _auxiliary_states(ctx: Context, derivs: dict, state_vars: list) -> None:
    """The derivatives and initial values of the model's auxiliary states."""
    for st in ctx.bg.states:
        val = ctx.build(st.derivative, st.scope, f"state {st.id!r} derivative")
        sym = ctx.states[st.id]
        if shape_of(val) != shape_of(sym):
            raise ModelError(st.derivative.coord, f"state {st.id!r}: derivative has shape "
                                                  f"{shape_name(shape_of(val))}, the state "
                                                  f"{shape_name(shape_of(sym))}")
        init = ctx.build(st.initial, st.scope, f"state {st.id!r} initial", params_only=True)
        if shape_of(init) != shape_of(sym) and not (init == 0 or init == sp.Integer(0)):
            raise ModelError(st.initial.coord, f"state {st.id!r}: initial value has shape "
                                               f"{shape_name(shape_of(init))}, the state "
                                               f"{shape_name(shape_of(sym))}")
        inits = flat(init) if shape_of(init) else [init] * len(flat(sym))
        for k, (s, v, i0) in enumerate(zip(flat(sym), flat(val), inits)):
            derivs[s] = v
            state_vars.append(StateVar(state_label(st.id, st.shape, k), s, st.id, i0))


def _outputs(ctx: Context) -> list:
    """(name, shape, flat expressions) of each output the model declares."""
    outputs = []
    for out in ctx.bg.model.body.outputs:
        val = ctx.build(out.expr, (), f"output {out.name!r}")
        shp = shape_of(val)
        if shp and shp[1] == 1:
            shp = (shp[0],)
        outputs.append((out.name, shp, tuple(flat(val))))
    return outputs


def _dependent(ctx: Context, defs: dict, state_vars: list) -> list:
    """(element id, the state names it follows from) of each storage element in derivative
    causality."""
    dependent = []
    names = {sv.symbol: sv.name for sv in state_vars}
    for eid, syms, _ in ctx.dependent:
        seen, stack, on = set(), list(syms), set()
        while stack:
            v = stack.pop()
            if v in seen:
                continue
            seen.add(v)
            if v in names:
                on.add(v)
            elif v in defs:
                stack.extend(defs[v].expr.free_symbols)
        dependent.append((eid, tuple(sv.name for sv in state_vars if sv.symbol in on)))
    return dependent


def _inline(order: list, defs: dict) -> tuple[list, dict]:
    """Inline plain copies (junction equalities, sign flips, constants): they are not work.
    Returns the assignments kept, in order, and the substitution of the inlined ones."""
    subs: dict = {}
    kept: list[Assignment] = []
    for s in order:
        a = defs[s]
        v = replaced(a.expr, subs)  # (xreplace, plain sums and products built directly)
        if is_trivial(v):
            subs[s] = v
        else:
            kept.append(Assignment(s, v, a.why))
    return kept, subs


def _check_declared(ctx: Context, state_vars, ctx_derived, kept, derivatives, outputs,
                    events=()) -> None:
    """Every free symbol must be declared: a state, a parameter, an input, t, or an
    assignment (``events``: the events' guards and resets)."""
    known = {sv.symbol for sv in state_vars} | {T}
    for pv in ctx.params.values():
        known.update(pv.symbols)
    for a in ctx_derived:
        known.add(a.symbol)
    for iv in ctx.inputs.values():
        known.update(iv.symbols)
    known.update(a.symbol for a in kept)
    for expr in itertools.chain((a.expr for a in kept), derivatives,
                                (e for _, _, v in outputs for e in v), events):
        stray = expr.free_symbols - known
        if stray:
            names = ", ".join(sorted(map(str, stray)))
            raise ModelError(ctx.bg.model.coord, f"internal: undeclared symbols {names} "
                                                 "(a derivative-causality element referenced?)")
