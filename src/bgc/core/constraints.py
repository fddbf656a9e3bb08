"""Constraints: flow sources that close a kinematic loop, held by an unknown reaction.

When SCAP meets a closed kinematic loop, or a non-square modulus that a zero-flow source
would have to invert (a joint that locks only part of a multibond), causality
(bgc.core.causality) turns that source into a *constraint*: causally an effort source whose
effort is an unknown reaction lambda, one per component of its bond. What the source imposed
becomes an equation: the bond's flow f (now computed by the other end) must equal the
source's flow s(t).

The constraint's violation q (the relative displacement of the two sides, q(0) = 0: the given
configuration is the assembled one) is a state, q' = f - s. The reaction follows from the
acceleration-level constraint, stabilised (Baumgarte):

    q'' + 2 alpha q' + alpha^2 q = 0,

linear in lambda: q'' = d/dt f - s', and d/dt f reaches the efforts through the state
derivatives. Its ``_dt_`` symbols come from the chain rule of bgc.core.loops
(``time_derivatives``) and the system is solved with the dependent storage elements'
derivatives by tearing (a residual row per component). The result is an ODE that every
backend, solver and the FMU carry as they are; q decays critically damped at rate alpha
instead of drifting.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import sympy as sp

from bgc.base.errors import ModelError
from bgc.core.causality import closed_loop
from bgc.core.context import Context
from bgc.core.eqtypes import Assignment, StateVar, T, clean_derivative, flat, real_symbol, symbol_vector
from bgc.core.graph import FlatElement, code_name

#: The default stabilisation rate alpha (1/s), chosen by measurement (docs/closed_loops.md).
DEFAULT_ALPHA = 20.0


@dataclass(frozen=True)
class Constraint:
    source: str  # the flow source's element id
    bond: str  # its bond
    lam: tuple  # the reaction (the bond's effort), one symbol per component
    flow: tuple  # the bond's flow, computed by the other end
    target: tuple  # the source's flow: expressions of t and parameters
    q: tuple  # the violation's state symbols
    closure: tuple | None = None  # the position residual (`closure:`), in states and parameters


def constraint_source(ctx: Context, el: FlatElement, b, target, define, closure=None) -> None:
    """The law of a flow source turned constraint: its effort is the unknown reaction.
    ``closure``: the position residual the user gives (`closure:`), n expressions that may read
    states, parameters and t only (not flows or efforts: it is a position)."""
    n = b.n
    lam = symbol_vector(f"lam_{code_name(el.id)}", n)
    define(ctx.e[b.id], lam, el, f"{el.id} (constraint): reaction effort")
    q = symbol_vector(f"q_{code_name(el.id)}", n)
    if closure is not None:
        closure = tuple(sp.sympify(x) for x in flat(closure))
        allowed = {T} | {s for v in ctx.states.values() for s in flat(v)}
        allowed |= {s for pv in ctx.params.values() for s in pv.symbols}
        allowed |= {a.symbol for a in ctx.derived.values()}
        bad = sorted(str(x) for c in closure for x in c.free_symbols if x not in allowed)
        if bad:
            raise ModelError(el.closure.coord, f"Sf {el.id!r}: its closure may read states, "
                             f"parameters and t only (a position), not {', '.join(bad)}")
    ctx.constraints.append(Constraint(el.id, b.id, tuple(flat(lam)), tuple(flat(ctx.f[b.id])),
                                      tuple(flat(target)), tuple(flat(q)), closure))


def dropped_states(ctx: Context) -> tuple:
    """The violation states of the components dropped as redundant (reaction 0), in the order
    they were found: their q' = f - s is the velocity residual a run watches
    (bgc.run.watch), since what was redundant at the start may not stay so."""
    sizes = {c.source: len(c.q) for c in ctx.constraints}
    return tuple(f"{src}.q" + (f"[{k}]" if sizes[src] > 1 else "")
                 for src, k in ctx.redundant if src in sizes)


def constraint_states(ctx: Context, derivs: dict, state_vars: list) -> None:
    """The violation states q, q' = f - s, q(0) = 0."""
    for c in ctx.constraints:
        n = len(c.q)
        for k, (q, f, s) in enumerate(zip(c.q, c.flow, c.target)):
            derivs[q] = f - s
            label = f"{c.source}.q" + (f"[{k}]" if n > 1 else "")
            state_vars.append(StateVar(label, q, c.source, sp.Integer(0)))


def stabilise(ctx: Context, defs: dict, owner: dict, alpha: float,
              dropped: set = frozenset()) -> frozenset:
    """Each reaction component defined by its residual q'' + 2 alpha q' + alpha^2 q (q the
    closure where one is given; its ``_dt_`` flows defined by ``time_derivatives``
    beforehand). ``dropped``: (source, component) found numerically redundant at the initial
    state (bgc.core.assembly), whose reaction is 0 like a structurally redundant one's.
    Returns the reactions."""
    bg = ctx.bg
    lams = {lam for c in ctx.constraints for lam in c.lam}
    inputs = {s for iv in ctx.inputs.values() for s in iv.symbols}
    out: set = set()
    residuals: dict = {}
    owner_of = {lam: c.source for c in ctx.constraints for lam in c.lam}
    c_index = {lam: k for c in ctx.constraints for k, lam in enumerate(c.lam)}
    for c in ctx.constraints:
        el = bg.element(c.source)
        reach = closure_of(defs, c.flow)
        own = reach & lams
        if own:
            raise ModelError(el.coord, f"constraint {c.source!r} (the flow source that closes "
                             "a kinematic loop): the flow it holds depends on a reaction "
                             f"({', '.join(sorted(map(str, own)))}) through a resistive path, "
                             "not only on the motion; bgc cannot hold it (index > 3): make a "
                             "connection on that path compliant")
        for lam, f, s, q, pos in zip(c.lam, c.flow, c.target, c.q, c.closure or c.q):
            if sp.sympify(s).free_symbols & inputs:
                raise ModelError(el.coord, f"constraint {c.source!r}: its flow follows input "
                                 "signals, whose time derivative a rigid constraint needs; make "
                                 "the signal an expression of t, or the connection compliant")
            ds = clean_derivative(sp.diff(s, T))
            qdot = f - s
            r = real_symbol(f"_dt_{f}") - ds + 2 * alpha * qdot + alpha ** 2 * pos
            residuals[lam] = r
    for lam, r in residuals.items():
        src = owner_of[lam]
        if (src, c_index[lam]) in dropped or not (closure_of(defs, r.free_symbols) & lams):
            # no reaction reaches this component's acceleration: the motion already holds it
            # (an out-of-plane component of a planar loop written with 3-D bonds)
            defs[lam] = Assignment(lam, sp.Integer(0), f"{src} (constraint): redundant "
                                   "component, its reaction is zero")
            ctx.redundant.append((src, c_index[lam]))
        else:
            defs[lam] = Assignment(lam, r, f"{src} (constraint): reaction, from "
                                   f"q'' + 2 alpha q' + alpha^2 q = 0 (alpha = {alpha:g} 1/s)")
            out.add(lam)
        owner[lam] = src
    return frozenset(out)


def closure_of(defs: dict, syms) -> set:
    seen, stack = set(), list(syms)
    while stack:
        s = stack.pop()
        if s in seen:
            continue
        seen.add(s)
        if s in defs:
            stack.extend(defs[s].expr.free_symbols)
    return seen


def alpha_of(model) -> float:
    return model.stabilisation if model.stabilisation is not None else DEFAULT_ALPHA


def parameter_values(ctx: Context, vals: dict | None = None) -> dict | None:
    """Every parameter symbol at the model's value (sympy Floats), derived ones in their
    order, added to ``vals``; None where a derived one is not a finite number."""
    vals = {} if vals is None else vals
    for pv in ctx.params.values():
        flatv = _flat_floats(pv.value) if isinstance(pv.value, tuple) else [pv.value]
        for s, v in zip(pv.symbols, flatv):
            vals[s] = sp.Float(float(v))
    for key in ctx.derived_order:
        a = ctx.derived[key]
        for s, e in zip(flat(a.symbol), flat(a.expr)):
            v = number_of(e, vals)
            if v is None:
                return None
            vals[s] = v
    return vals


def initial_values(ctx: Context, state_vars) -> dict | None:
    vals = parameter_values(ctx, {T: sp.Float(0)})
    if vals is None:
        return None
    for iv in ctx.inputs.values():
        if iv.table is not None:
            return None
        for s, e in zip(iv.symbols, iv.default):
            v = number_of(e, vals)
            if v is None:
                return None
            vals[s] = v
    for sv in state_vars:
        v = number_of(sv.initial, vals)
        if v is None:
            return None
        vals[sv.symbol] = v
    return vals


def _flat_floats(value) -> list[float]:
    """A parameter's value (a number, or nested tuples of them) as floats in row-major order
    (without numpy, which `bgc check` does not load)."""
    if isinstance(value, tuple):
        return [f for v in value for f in _flat_floats(v)]
    return [float(value)]


def number_of(expr, vals) -> float | None:
    try:
        v = complex(sp.sympify(expr).xreplace(vals).evalf())
    except (TypeError, ValueError, AttributeError):
        return None
    return sp.Float(v.real) if abs(v.imag) <= 1e-300 and math.isfinite(v.real) else None


def lock_of(bg, source: str):
    """The non-square modulus a flow source sits behind (a revolute joint's lock: the source
    holds the small side's components), else None."""
    (b,) = bg.bonds_of(source)
    other = bg.element(b.src if b.dst == source else b.dst)
    if other.type in ("MTF", "MGY") and len({x.n for x in bg.bonds_of(other.id)}) > 1:
        return other
    return None


def _lock_parts(bg) -> frozenset:
    """Every lock's flow source and the junctions on its modulus's large side: a loop that
    one of them closes does not run through another's (a lock holds part of a multibond)."""
    out = set()
    for el in bg.elements:
        if el.type == "Sf" and lock_of(bg, el.id) is not None:
            m = lock_of(bg, el.id)
            out.add(el.id)
            out.update(x.src if x.dst == m.id else x.dst for x in bg.bonds_of(m.id))
    return frozenset(out)


def loop_text(bg, source: str) -> str:
    """The loop a constraint closes, by its elements (at most 24 named). The loop a pin
    closes does not run through the revolute locks (their sources, their junctions)."""
    avoid = frozenset() if lock_of(bg, source) is not None else _lock_parts(bg)
    names = [x for x in closed_loop(bg, source, avoid - {source}) or closed_loop(bg, source)
             if x != "ground"]
    if not names:
        return f"at {source!r}"
    more = f", ... ({len(names)} elements)" if len(names) > 24 else ""
    return "through " + ", ".join(names[:24]) + more


def constraint_report(bg, caus, eqs) -> str:
    """What `bgc check` says about closed loops: each loop by its elements, its constraint
    (source, bond, components), the coordinates kept independent (the states in integral
    causality), the dependent storage elements, the redundant components dropped, alpha."""
    if not caus.constraints:
        return ""
    alpha = alpha_of(bg.model)
    lines = [f"closed loops (constraints held by reactions; violation q stabilised by "
             f"q'' + 2 alpha q' + alpha^2 q = 0, alpha = {alpha:g} 1/s):"]
    qs = {c: [sv.name for sv in eqs.states if sv.owner == c] for c in caus.constraints}
    redundant = {(src, k) for src, k in getattr(eqs, "redundant", ())}
    for k, src in enumerate(caus.constraints, 1):
        el = bg.element(src)
        (b,) = bg.bonds_of(src)
        lock = lock_of(bg, src)
        kind = (f" (a lock: {b.n} of the {max(x.n for x in bg.bonds_of(lock.id))} components "
                f"behind {lock.type} {lock.id})" if lock is not None else "")
        lines.append(f"  loop {k} {loop_text(bg, src)}{kind}")
        lines.append(f"    constraint: Sf {src} (line {el.coord.line}) on bond {b.id} "
                     f"({b.src} -> {b.dst}), {b.n} component(s): its flow held, its effort the "
                     f"reaction; violation state(s) {', '.join(qs[src])}")
        dropped = [qs[src][i] for i in range(b.n) if (src, i) in redundant]
        lines.append(f"    redundant components: {', '.join(dropped) or 'none'}")
    cons = {n for v in qs.values() for n in v}
    kept = [sv.name for sv in eqs.states if sv.name not in cons]
    lines.append(f"  coordinates kept independent: {', '.join(kept) or 'none'}")
    lines.append(f"  dependent storage elements: {', '.join(caus.derivative) or 'none'}")
    red = [f"{src}.q[{k}]" if bg.bonds_of(src)[0].n > 1 else f"{src}.q"
           for src, k in getattr(eqs, "redundant", ())]
    lines.append("  redundant constraint components dropped (reaction 0): "
                 + (", ".join(red) if red else "none"))
    return "\n".join(lines) + "\n"
