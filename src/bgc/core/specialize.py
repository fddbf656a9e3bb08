"""Scene specialisation: compile only the effects and outputs a scene calls for.

Three passes, each reported in the generated module's header:

1. **Effects** (graph level, before causality). Elements, component instances and auxiliary
   states carry effect tags (``effects: [gravity]``); an instance's tags apply to everything in
   it. Turning an effect off removes its elements with their bonds: a removed element
   contributes nothing to its junction (zero effort on a 1-junction, zero flow on a
   0-junction). The removal cascades: a two-port left with one port and a one-port left with
   no bond go too; a junction left with one bond is a zero source of its own kind (a 1-junction
   imposes zero effort, a 0-junction zero flow), which is nothing to a neighbouring junction
   of the same kind (then it goes as well) and is kept as an ``Se``/``Sf`` of zero otherwise;
   a junction left with two bonds passing straight through is a plain connection and is
   replaced by one bond (unless an expression names it or its bonds). Expressions that read a
   removed element read zero. Causality is assigned again; the header lists every element
   whose causal form changed, and derivative causality is an error that names the effect and
   the elements, located at the scene's ``effects`` entry.
2. **Outputs and folding** (symbolic). Only the requested outputs are built. An output that
   exists only through removed elements is an error when the scene asks for it (located at
   its ``outputs`` entry, naming the effect) and is left out otherwise. Parameters the scene
   sets are folded in as numbers (sympy drops what they zero out); those it marks ``free``
   stay parameters of the module.
3. **Slicing** (equation level). States (storage and auxiliary) that cannot reach a requested
   output are removed, with the intermediate variables only they need. Dependencies are read
   off the causal assignments, so a thermal branch that only receives heat disappears, while
   one that feeds back (a temperature-dependent resistance) stays.

A plan that changes nothing (no effect off, no parameter folded, outputs omitted or all of
them with nothing to slice) gives the full model byte for byte.

The removal of pass 1 is graph surgery of its own and lives in bgc.core.effects; this module
holds the plan, the causality after the removal, and passes 2 and 3.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from bgc.base.errors import Coord, ModelError
from bgc.core.causality import Causality, assign_causality, derivative_message
from bgc.core.effects import Refs, Removal, remove_effects
from bgc.core.eqtypes import Equations, state_label
from bgc.core.graph import BondGraph
from bgc.format.whitelist import Expr


@dataclass(frozen=True)
class Plan:
    """What a scene asks for."""

    effects_off: frozenset = frozenset()
    fold: dict = field(default_factory=dict)  # parameter id -> value (number or nested tuple)
    outputs: tuple[str, ...] = ()  # empty: all outputs, no slicing
    scene: str = ""
    effect_coords: dict = field(default_factory=dict)  # effect -> Coord of its scene entry
    output_coords: dict = field(default_factory=dict)  # output -> Coord of its scene entry
    coord: Coord | None = None  # the scene file
    free: tuple[str, ...] = ()  # parameters the scene sets but keeps as parameters

    @property
    def trivial(self) -> bool:
        return not self.effects_off and not self.fold and not self.outputs


# ---------------------------------------------------------------------------------------------
# Pass 1: effects (the removal itself is bgc.core.effects'), causality after the removal


def recausal(full: BondGraph, full_caus: Causality, rem: Removal, plan: Plan
             ) -> tuple[Causality, tuple]:
    """Causality of the specialised graph, and what changed against the full model's."""
    off = plan.effects_off
    try:
        caus = assign_causality(rem.graph, allow_derivative=True)
    except ModelError as exc:
        eff = _culprit(full, plan, lambda c: False)
        raise ModelError(plan.effect_coords.get(eff, exc.coord),
                         f"with effect {eff!r} off, causality cannot be assigned: "
                         f"{exc.message} (at {exc.coord})") from None
    if caus.derivative:
        eff = _culprit(full, plan, lambda c: bool(c.derivative))
        ids = [k for k, why in rem.removed.items() if why == f"effect {eff!r} off"]
        removed = ", ".join(ids[:8]) + (", ..." if len(ids) > 8 else "")
        raise ModelError(plan.effect_coords.get(eff, rem.graph.element(caus.derivative[0]).coord),
                         f"turning effect {eff!r} off (it removes {removed}) leaves "
                         + derivative_message(rem.graph, caus).replace(
                             ". Join the storage", " (declared at "
                             + str(rem.graph.element(caus.derivative[0]).coord)
                             + "). Keep the effect on, or join the storage"))
    changes = []
    for el in rem.graph.elements:
        if el.type in ("0", "1") or el.id in rem.zero_sources:
            continue
        try:
            before, after = full_caus.form(full, full.element(el.id)), caus.form(rem.graph, el)
        except (StopIteration, KeyError):
            continue
        if before != after:
            changes.append(f"{el.type} {el.id}: {before} -> {after}")
    moved = [b.id for b in rem.graph.bonds
             if b.id in full_caus.effort_by and (b.src, b.dst) == (full.bond(b.id).src,
                                                              full.bond(b.id).dst)
             and (caus.effort_by[b.id] == b.src) != (full_caus.effort_by[b.id] == b.src)]
    if changes or moved:
        note = "causality after removal: " + "; ".join(changes or ["element forms unchanged"])
        if moved:
            note += f" (strokes moved on bonds {', '.join(moved)})"
    else:
        note = "causality after removal: unchanged on every remaining bond"
    return caus, (note,)


def _culprit(full: BondGraph, plan: Plan, bad) -> str:
    """The first effect (in scene order) whose removal alone makes the causality bad."""
    order = [e for e in plan.effect_coords if e in plan.effects_off] or sorted(plan.effects_off)
    if len(order) > 1:
        for eff in order:
            try:
                c = assign_causality(remove_effects(full, frozenset([eff])).graph,
                                     allow_derivative=True)
            except ModelError:
                return eff
            if bad(c):
                return eff
    return order[0]


# ---------------------------------------------------------------------------------------------
# Pass 2: outputs


def select_outputs(full: BondGraph, rem: Removal, plan: Plan) -> tuple[BondGraph, tuple]:
    """The graph with only the outputs to build: the requested ones (all if none are), less
    those that exist only through removed elements (an error if the scene asks for one)."""
    model = full.model
    outs = model.body.outputs
    names = [o.name for o in outs]
    seen = set()
    for w in plan.outputs:
        c = plan.output_coords.get(w, plan.coord)
        if w not in names:
            raise ModelError(c, f"the model has no output {w!r} (outputs: {', '.join(names)})")
        if w in seen:
            raise ModelError(c, f"output {w!r} is listed twice")
        seen.add(w)
    wanted = set(plan.outputs) if plan.outputs else set(names)
    refs = Refs(full)
    if rem.removed_states:  # what stays must not read a removed auxiliary state
        readers = [(f"{el.type} {el.id!r}", el.law[1], el.scope) for el in rem.graph.elements
                   if el.law is not None]
        readers += [(f"state {st.id!r}", st.derivative, st.scope) for st in rem.graph.states]
        for what, expr, scope in readers:
            hit = sorted(refs.of(expr, scope) & set(rem.removed_states))
            if hit:
                eff = _effects_behind(full, rem, {hit[0]}, plan)[0]
                raise ModelError(plan.effect_coords.get(eff, expr.coord),
                                 f"turning effect {eff!r} off removes state {hit[0]!r}, which "
                                 f"{what} still reads (at {expr.coord}): keep the effect on, "
                                 "or tag the reader too")
    gone = set(rem.removed) | set(rem.removed_states) | set(k for k in rem.zero)
    # auxiliary states whose derivative reads only removed things are gone too (constant)
    changed = True
    while changed:
        changed = False
        for st in rem.graph.states:
            if st.id in gone:
                continue
            r = {x for x in refs.of(st.derivative, st.scope) if x != st.id and _live_kind(full, x)}
            if r and r <= gone:
                gone.add(st.id)
                changed = True
    keep, dropped, partial = [], [], []
    for o in outs:
        if o.name not in wanted:
            continue
        r = {x for x in refs.of(o.expr, ()) if _live_kind(full, x)}
        lost = r & gone
        if r and lost == r:
            effs = _effects_behind(full, rem, lost, plan)
            if plan.outputs:
                raise ModelError(plan.output_coords.get(o.name, plan.coord),
                                 f"output {o.name!r} exists only through what effect "
                                 f"{' and '.join(map(repr, effs))} adds "
                                 f"({', '.join(sorted(lost)[:6])}"
                                 f"{', ...' if len(lost) > 6 else ''}), which the scene turns "
                                 "off: drop the output or keep the effect on")
            dropped.append(f"{o.name} (exists only through effect "
                           f"{', '.join(map(repr, effs))})")
            continue
        if lost & set(rem.removed_states):
            st = sorted(lost & set(rem.removed_states))[0]
            raise ModelError(plan.output_coords.get(o.name, plan.coord),
                             f"output {o.name!r} reads state {st!r}, which effect "
                             f"{' and '.join(map(repr, _effects_behind(full, rem, {st}, plan)))} "
                             "removes")
        if lost:
            partial.append(o.name)
        keep.append(o)
    notes = []
    if dropped:
        notes.append("outputs left out: " + "; ".join(dropped))
    if partial:
        notes.append("outputs reading removed elements (their terms are zero): "
                     + ", ".join(partial))
    if plan.outputs:
        left = [n for n in names if n not in wanted]
        if left:
            notes.append("outputs not requested: " + ", ".join(left))
    if len(keep) == len(outs):
        return rem.graph, tuple(notes)
    body = dataclasses.replace(model.body, outputs=tuple(keep))
    g = rem.graph
    new = BondGraph(dataclasses.replace(model, body=body), g.params, g.elements, g.bonds,
                    g.states, g.scopes)
    return new, tuple(notes)


def _live_kind(bg: BondGraph, ident: str) -> bool:
    """Ids that carry the model's behaviour (not inputs)."""
    try:
        bg.element(ident)
        return True
    except KeyError:
        pass
    try:
        bg.bond(ident)
        return True
    except KeyError:
        pass
    return any(s.id == ident for s in bg.states)


def _effects_behind(full: BondGraph, rem: Removal, ids, plan: Plan) -> list[str]:
    """The effects turned off that removed these ids (directly or by the cascade)."""
    found = []
    for i in sorted(ids):
        tags = ()
        try:
            tags = full.element(i).effects
        except KeyError:
            st = [s for s in full.states if s.id == i]
            if st:
                tags = st[0].effects
        found += [t for t in tags if t in plan.effects_off]
    if not found:  # removed by the cascade, or a state left constant: every effect off
        found = sorted(plan.effects_off)
    return sorted(set(found))


# ---------------------------------------------------------------------------------------------
# Pass 3: slicing


def slice_outputs(eq: Equations) -> tuple[Equations, tuple, dict]:
    """Keep only the states (and intermediate variables) the outputs need."""
    state_syms = {sv.symbol: i for i, sv in enumerate(eq.states)}
    deps: dict = {}

    def states_of(expr) -> set[int]:
        acc: set[int] = set()
        for s in expr.free_symbols:
            if s in state_syms:
                acc.add(state_syms[s])
            elif s in deps:
                acc |= deps[s]
        return acc

    for a in eq.assignments:
        deps[a.symbol] = states_of(a.expr)
    need: set[int] = set()
    for _, _, vals in eq.outputs:
        for v in vals:
            need |= states_of(v)
    for ev in eq.events:  # what an event reads and the states it sets stay
        need |= set().union(*map(states_of, ev.exprs()), {state_syms[s] for s, _ in ev.resets})
    # the violation states of components dropped as redundant stay: their rates are the
    # residuals a run watches (bgc.run.watch)
    dropped = set(getattr(eq, "constraint_dropped", ()))
    need |= {i for i, sv in enumerate(eq.states) if sv.name in dropped}
    frontier = list(need)
    while frontier:
        i = frontier.pop()
        for j in states_of(eq.derivatives[i]):
            if j not in need:
                need.add(j)
                frontier.append(j)
    keep = sorted(need)
    if len(keep) == len(eq.states):
        return eq, (), {"states": 0, "assignments": 0}
    removed = [eq.states[i].name for i in range(len(eq.states)) if i not in need]
    index = {old: new for new, old in enumerate(keep)}
    jac = {(index[i], index[j]): v for (i, j), v in eq.jacobian.items()
           if i in index and j in index}
    derivatives = tuple(eq.derivatives[i] for i in keep)
    # intermediate variables: those the kept derivatives, outputs and Jacobian entries read
    # (Jacobian intermediates read assignments, never the other way round)
    wanted = set()
    for e in list(derivatives) + list(jac.values()) + [v for _, _, vs in eq.outputs for v in vs] \
            + [v for ev in eq.events for v in ev.exprs()]:
        wanted |= e.free_symbols
    jassigns = []
    for a in reversed(eq.jac_assignments):
        if a.symbol in wanted:
            jassigns.append(a)
            wanted |= a.expr.free_symbols
    assigns = []
    for a in reversed(eq.assignments):
        if a.symbol in wanted:
            assigns.append(a)
            wanted |= a.expr.free_symbols
    assigns.reverse()
    jassigns.reverse()
    new = dataclasses.replace(eq, states=tuple(eq.states[i] for i in keep),
                              derivatives=derivatives, jacobian=jac,
                              assignments=tuple(assigns), jac_assignments=tuple(jassigns))
    n_assign = len(eq.assignments) - len(assigns)
    notes = ()
    if n_assign:
        notes += (f"removed intermediate variables (needed only by removed states): "
                  f"{n_assign}",)
    return new, notes, {"states": len(removed), "assignments": n_assign}


def state_owners(bg: BondGraph, caus: Causality) -> list[tuple[str, str]]:
    """(state name as in STATE_NAMES, owning element or state id), in the module's order."""
    out = []
    for el in bg.elements:
        if el.type in ("I", "C") and el.id not in caus.derivative:
            n = bg.bonds_of(el.id)[0].n
            letter = "p" if el.type == "I" else "q"
            out += [(f"{el.id}.{letter}" + (f"[{k}]" if n > 1 else ""), el.id) for k in range(n)]
    for st in bg.states:
        size = 1
        for d in st.shape:
            size *= d
        out += [(state_label(st.id, st.shape, k), st.id) for k in range(size)]
    return out


def states_note(full: list[tuple[str, str]], kept: set[str], rem: Removal | None) -> str:
    """One header line: how many states are kept, and each removed one with its reason."""
    groups: dict[str, list[str]] = {}
    for name, owner in full:
        if name in kept:
            continue
        why = None
        if rem is not None:
            why = rem.removed.get(owner) or rem.removed_states.get(owner)
        groups.setdefault(why or "cannot reach a requested output", []).append(name)
    parts = [f"{', '.join(names)} ({why})" for why, names in groups.items()]
    return (f"states: {len(kept)} of {len(full)} kept; removed: " + "; ".join(parts))


def plan_for(scene, graph_params) -> Plan:
    """The specialisation a scene (a bgc.format.scene.Scene) asks for: effects off, parameters
    to fold, outputs."""
    known = {p.id: p for p in graph_params}
    fold = {}
    for pid, (v, coord) in scene.params.items():
        if pid not in known or isinstance(known[pid].value, Expr):
            raise ModelError(coord, f"the model has no parameter {pid!r}"
                             + (" (it is derived from others)" if pid in known else ""))
        if pid not in scene.free:
            fold[pid] = v
    off = frozenset(k for k, (on, _) in scene.effects.items() if not on)
    return Plan(off, fold, scene.outputs, scene.name,
                {k: c for k, (_, c) in scene.effects.items()}, dict(scene.output_coords),
                scene.coord, tuple(f for f in scene.free))
