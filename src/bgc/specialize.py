"""Scene specialisation: compile only the effects and outputs a scene calls for.

Three passes, each reported in the generated module's header:

1. **Effects** (graph level, before causality): an element, component instance or auxiliary
   state tagged with an effect the scene turns off is removed with its bonds. A removed one-port
   contributes nothing to its junction (zero effort on a 1-junction, zero flow on a 0-junction);
   junctions left with a single bond, and whatever hangs only from them, go too. Expressions
   that read a removed element's variables read zero. Causality is then assigned again and any
   bond whose stroke moved is listed; derivative causality names the effect responsible.
2. **Folding** (symbolic): parameters the scene fixes become numbers, so sympy drops whatever
   they zero out; parameters the scene marks ``free`` stay parameters.
3. **Slicing** (equation level): states and assignments that cannot reach a requested output
   are removed. Dependencies are read off the causal assignments, so a thermal branch that
   only receives heat disappears, while one that feeds back (a temperature-dependent
   resistance) stays.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from .causality import Causality, assign_causality, derivative_message
from .errors import ModelError
from .equations import Equations
from .graph import BondGraph, FlatElement


@dataclass(frozen=True)
class Plan:
    """What a scene asks for."""

    effects_off: frozenset = frozenset()
    fold: dict = field(default_factory=dict)  # parameter id -> value (number or nested tuple)
    outputs: tuple[str, ...] = ()  # empty: all outputs, no slicing
    scene: str = ""

    @property
    def trivial(self) -> bool:
        return not self.effects_off and not self.fold and not self.outputs


@dataclass(frozen=True)
class Removal:
    graph: BondGraph
    removed: dict  # element id -> reason
    removed_states: dict  # aux state id -> reason
    zero: dict  # element id -> cardinality of its (first) bond, for reads of removed elements
    notes: tuple[str, ...]


def known_effects(bg: BondGraph) -> set[str]:
    out = set()
    for el in bg.elements:
        out.update(el.effects)
    for st in bg.states:
        out.update(st.effects)
    return out


def remove_effects(bg: BondGraph, off: frozenset, coord=None) -> Removal:
    """The bond graph without the elements of the effects turned off."""
    if not off:
        return Removal(bg, {}, {}, {}, ())
    unknown = sorted(set(off) - known_effects(bg))
    if unknown:
        raise ModelError(coord, f"the model has no effect {unknown[0]!r} "
                                f"(effects: {', '.join(sorted(known_effects(bg))) or 'none'})")
    removed: dict[str, str] = {}
    for el in bg.elements:
        hit = sorted(set(el.effects) & off)
        if hit:
            removed[el.id] = f"effect {hit[0]!r} off"
    zero = {eid: bg.bonds_of(eid)[0].n for eid in removed if bg.bonds_of(eid)}
    # Cascade: junctions left with one bond contribute nothing; one-ports left without a bond
    # and two-ports left with one are dead too.
    changed = True
    while changed:
        changed = False
        for el in bg.elements:
            if el.id in removed:
                continue
            live = [b for b in bg.bonds_of(el.id)
                    if b.src not in removed and b.dst not in removed]
            dead = False
            if el.type in ("0", "1"):
                dead = len(live) <= 1
            elif el.type in ("TF", "GY", "MTF", "MGY"):
                dead = len(live) < 2
            else:
                dead = len(live) == 0
            if dead:
                removed[el.id] = "left unconnected by " + ", ".join(sorted(off))
                zero[el.id] = bg.bonds_of(el.id)[0].n
                changed = True
    states = {st.id: f"effect {sorted(set(st.effects) & off)[0]!r} off"
              for st in bg.states if set(st.effects) & off}
    elements = tuple(e for e in bg.elements if e.id not in removed)
    bonds = tuple(b for b in bg.bonds if b.src not in removed and b.dst not in removed)
    kept_states = tuple(s for s in bg.states if s.id not in states)
    g = bg.graph.copy()
    g.remove_nodes_from(removed)
    new = BondGraph(bg.model, bg.params, elements, bonds, kept_states, bg.scopes, g)
    notes = []
    if removed:
        by_reason: dict[str, list[str]] = {}
        for eid, why in removed.items():
            by_reason.setdefault(why, []).append(eid)
        for why, ids in by_reason.items():
            notes.append(f"removed ({why}): {', '.join(ids)}")
    if states:
        notes.append(f"removed states ({'; '.join(sorted(set(states.values())))}): "
                     f"{', '.join(states)}")
    return Removal(new, removed, states, zero, tuple(notes))


def recausal(full: BondGraph, full_caus: Causality, rem: Removal, off) -> tuple[Causality, tuple]:
    """Causality of the specialised graph, and the bonds whose stroke moved."""
    try:
        caus = assign_causality(rem.graph, allow_derivative=True)
    except ModelError as exc:
        raise ModelError(exc.coord, f"{exc.message} (after turning off {', '.join(sorted(off))})")
    if caus.derivative:
        el: FlatElement = rem.graph.element(caus.derivative[0])
        raise ModelError(el.coord, f"with {', '.join(sorted(off))} turned off, "
                                   + derivative_message(rem.graph, caus))
    moved = [b.id for b in rem.graph.bonds if caus.effort_by[b.id] != full_caus.effort_by[b.id]]
    notes = (f"causality changed on bonds: {', '.join(moved)}",) if moved else ()
    return caus, notes


def slice_outputs(eq: Equations, wanted: tuple[str, ...], coord=None) -> tuple[Equations, tuple]:
    """Keep the requested outputs and only the states they need."""
    names = [o[0] for o in eq.outputs]
    for w in wanted:
        if w not in names:
            raise ModelError(coord, f"the scene asks for output {w!r}, which the model "
                                    f"{'does not define' if w not in names else 'cannot produce'}"
                                    f" (outputs: {', '.join(names)})")
    outs = tuple(o for o in eq.outputs if o[0] in wanted)
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
    for _, _, vals in outs:
        for v in vals:
            need |= states_of(v)
    frontier = list(need)
    while frontier:
        i = frontier.pop()
        for j in states_of(eq.derivatives[i]):
            if j not in need:
                need.add(j)
                frontier.append(j)
    keep = sorted(need)
    removed = [eq.states[i].name for i in range(len(eq.states)) if i not in need]
    index = {old: new for new, old in enumerate(keep)}
    jac = {(index[i], index[j]): v for (i, j), v in eq.jacobian.items()
           if i in index and j in index}
    new = dataclasses.replace(eq, states=tuple(eq.states[i] for i in keep),
                              derivatives=tuple(eq.derivatives[i] for i in keep),
                              outputs=outs, jacobian=jac)
    notes = []
    if removed:
        notes.append(f"removed states (cannot reach a requested output): {', '.join(removed)}")
    dropped = [n for n in names if n not in wanted]
    if dropped:
        notes.append(f"outputs not requested: {', '.join(dropped)}")
    return new, tuple(notes)
