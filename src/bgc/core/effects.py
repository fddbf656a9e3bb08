"""Scene specialisation, pass 1: the bond graph without the effects a scene turns off.

Elements, component instances and auxiliary states carry effect tags; turning an effect off
removes its elements with their bonds, and the removal cascades (bgc.core.specialize's
docstring gives the rules). This is graph surgery before causality, with the reasons kept for
the generated module's header; :class:`Refs` (what an expression names) serves the later
passes too.
"""
from __future__ import annotations

import ast
import dataclasses
from dataclasses import dataclass

from bgc.base.errors import ModelError
from bgc.core.graph import BondGraph, FlatBond, join
from bgc.format.whitelist import BOND_FUNCTIONS, Expr, dotted_path


@dataclass(frozen=True)
class Removal:
    graph: BondGraph
    removed: dict  # element id -> reason
    removed_states: dict  # aux state id -> reason
    zero: dict  # removed element or bond id -> cardinality: reads of it give zero
    zero_sources: tuple[str, ...]  # junctions left with one bond, now zero sources
    merged: dict  # junction id -> the bond that replaces it and its two bonds
    notes: tuple[str, ...]


# ---------------------------------------------------------------------------------------------
# What expressions refer to


def raw_refs(expr: Expr) -> set[tuple[str, ...]]:
    """Dotted paths an expression names: values and the arguments of e/f/p/q/power."""
    out: set[tuple[str, ...]] = set()
    stack = [expr.tree()]
    while stack:
        node = stack.pop()
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) \
                and node.func.id in BOND_FUNCTIONS:
            p = dotted_path(node.args[0]) if node.args else None
            if p is not None:
                out.add(p)
            continue
        if isinstance(node, ast.Call):
            stack.extend(node.args)
            continue
        p = dotted_path(node)
        if p is not None:
            if len(p) > 1 and p[-1] == "T":
                p = p[:-1]
            out.add(p)
            continue
        stack.extend(ast.iter_child_nodes(node))
    return out


class Refs:
    """Resolves the names of a bond graph's expressions to flat ids (elements, bonds, states,
    inputs), following component parameters bound to expressions of the parent scope."""

    def __init__(self, bg: BondGraph):
        self.bg = bg
        self.memo: dict = {}

    def of(self, expr: Expr, scope: tuple[str, ...], depth: int = 0) -> set[str]:
        out: set[str] = set()
        try:
            paths = raw_refs(expr)
        except ModelError:
            return out
        for p in paths:
            out |= self._resolve(scope, p, depth)
        return out

    def _resolve(self, scope, path, depth) -> set[str]:
        sc = self.bg.scopes.get(scope)
        if sc is None or depth > 16:
            return set()
        kind = sc.names.get(path[0])
        if kind is None:
            return set()
        if kind == "instance":
            return self._resolve(scope + (path[0],), path[1:], depth) if len(path) > 1 else set()
        if len(path) != 1:
            return set()
        if kind == "param":
            b = sc.bindings.get(path[0])
            if b is not None and b.kind == "expr":
                key = (scope, path[0])
                if key not in self.memo:
                    self.memo[key] = set()  # guards a cycle (reported by the equations stage)
                    self.memo[key] = self.of(b.target, b.scope, depth + 1)
                return self.memo[key]
            return set()
        return {join(scope, path[0])}

    def everywhere(self) -> set[str]:
        """Every id any expression of the graph names."""
        bg = self.bg
        out: set[str] = set()
        for el in bg.elements:
            if el.law is not None:
                out |= self.of(el.law[1], el.scope)
        for st in bg.states:
            out |= self.of(st.derivative, st.scope)
        for o in bg.model.body.outputs:
            out |= self.of(o.expr, ())
        for inp in bg.model.inputs:
            out |= self.of(inp.default, ())
        for sc in bg.scopes.values():
            for b in sc.bindings.values():
                if b.kind == "expr":
                    out |= self.of(b.target, b.scope)
        return out


def known_effects(bg: BondGraph) -> set[str]:
    out = set()
    for el in bg.elements:
        out.update(el.effects)
    for st in bg.states:
        out.update(st.effects)
    return out


def _zero_text(n: int) -> str:
    return "0" if n == 1 else "[" + ", ".join(["0"] * n) + "]"


def remove_effects(bg: BondGraph, off: frozenset, coord=None) -> Removal:
    """The bond graph without the elements of the effects turned off."""
    if not off:
        return Removal(bg, {}, {}, {}, (), {}, ())
    effects = known_effects(bg)
    unknown = sorted(set(off) - effects)
    if unknown:
        raise ModelError(coord, f"the model has no effect {unknown[0]!r} "
                                f"(effects: {', '.join(sorted(effects)) or 'none'})")
    removed, kind, touched = _cascade(bg, off)
    zero: dict[str, int] = {}
    for eid in removed:
        bonds = bg.bonds_of(eid)
        zero[eid] = bonds[0].n if bonds else 1
    for b in bg.bonds:
        if b.src in removed or b.dst in removed:
            zero[b.id] = b.n
    states = {}
    for st in bg.states:
        hit = [e for e in st.effects if e in off]
        if hit:
            states[st.id] = f"effect {hit[0]!r} off"

    # The remaining graph: zero sources in place of one-bond junctions, straight-through
    # two-bond junctions merged into one bond.
    sources = tuple(eid for eid, t in kind.items() if eid not in removed and t != bg.element(eid).type)
    elements = []
    for el in bg.elements:
        if el.id in removed:
            continue
        if el.id in sources:
            n = _live(bg, removed, el.id)[0].n
            key = "effort" if kind[el.id] == "Se" else "flow"
            el = dataclasses.replace(el, type=kind[el.id],
                                     law=(key, Expr(_zero_text(n), el.coord)))
        elements.append(el)
    bonds = [b for b in bg.bonds if b.id not in zero]
    bonds, elements, merged = _merge_through(bg, removed, sources, kind, touched, bonds, elements)
    kept_states = tuple(s for s in bg.states if s.id not in states)
    new_bg = BondGraph(bg.model, bg.params, tuple(elements), tuple(bonds), kept_states,
                       bg.scopes)
    notes = _notes(bg, removed, states, sources, kind, merged)
    return Removal(new_bg, removed, states, zero, sources, merged, notes)


def _live(bg: BondGraph, removed: dict, eid: str) -> list:
    """An element's bonds that do not touch a removed element."""
    return [b for b in bg.bonds_of(eid) if b.src not in removed and b.dst not in removed]


def _cascade(bg: BondGraph, off: frozenset) -> tuple[dict, dict, set]:
    """The elements the effects remove, directly or by the cascade (element id -> reason);
    the elements' kinds after it (a junction left with one bond becomes a zero source); the
    junctions that lost a bond."""
    removed: dict[str, str] = {}
    for el in bg.elements:
        hit = [e for e in el.effects if e in off]
        if hit:
            removed[el.id] = f"effect {hit[0]!r} off"
    origin: dict[str, set] = {eid: {why.split("'")[1]} for eid, why in removed.items()}
    kind = {el.id: el.type for el in bg.elements}
    touched: set[str] = set()  # junctions that lost a bond

    def cause(eid):
        """The effects behind the removal of an element's dead neighbours."""
        acc = set()
        for b in bg.bonds_of(eid):
            for x in (b.src, b.dst):
                acc |= origin.get(x, set()) if x != eid else set()
        origin[eid] = acc
        return ", ".join(repr(e) for e in sorted(acc))

    changed = True
    while changed:
        changed = False
        for el in bg.elements:
            if el.id in removed:
                continue
            lv = _live(bg, removed, el.id)
            if len(lv) < len(bg.bonds_of(el.id)):
                touched.add(el.id)
            t = kind[el.id]
            why = None
            if t in ("0", "1"):
                if not lv:
                    why = f"left without bonds by {cause(el.id)}"
                elif len(lv) == 1:
                    b = lv[0]
                    other = b.dst if b.src == el.id else b.src
                    if kind[other] == t:
                        # a zero source of the neighbour's own kind: nothing to it
                        why = f"left with one bond by {cause(el.id)}"
                    else:
                        kind[el.id] = "Se" if t == "1" else "Sf"
                        changed = True
                        continue
            elif t in ("TF", "GY", "MTF", "MGY"):
                if len(lv) < 2:
                    why = f"left with one port by {cause(el.id)}"
            elif not lv:
                why = f"left unconnected by {cause(el.id)}"
            elif t != el.type:  # a junction turned zero source: alone with another, both go
                b = lv[0]
                other = b.dst if b.src == el.id else b.src
                if kind[other] != bg.element(other).type:
                    why = f"left with one bond by {cause(el.id)}"
            if why:
                removed[el.id] = why
                changed = True
    return removed, kind, touched


def _merge_through(bg: BondGraph, removed, sources, kind, touched, bonds, elements):
    """Junctions left with two bonds passing straight through (one in, one out), that no
    expression names, replaced by one bond. Returns the bonds, the elements and the merged
    junctions (id -> the bond that replaces it and its two bonds)."""
    named = Refs(bg).everywhere()
    merged: dict[str, tuple[str, str, str]] = {}
    for jid in sorted(touched, key=lambda j: [e.id for e in bg.elements].index(j)):
        if jid in removed or jid in sources or kind[jid] not in ("0", "1"):
            continue
        lv = [b for b in bonds if jid in (b.src, b.dst)]
        if len(lv) != 2 or jid in named or any(b.id in named for b in lv):
            continue
        ins = [b for b in lv if b.dst == jid]
        outs = [b for b in lv if b.src == jid]
        if len(ins) != 1 or len(outs) != 1:
            continue  # both bonds in (or out): a sign flip, not a plain connection
        bi, bo = ins[0], outs[0]
        if bi.src == bo.dst:
            continue
        new = FlatBond(bi.id, bi.src, bo.dst, bi.n, bi.coord, bi.index)
        bonds = [new if b.id == bi.id else b for b in bonds if b.id != bo.id]
        elements = [e for e in elements if e.id != jid]
        merged[jid] = (bi.id, bi.id, bo.id)
    return bonds, elements, merged


def _notes(bg: BondGraph, removed, states, sources, kind, merged) -> tuple[str, ...]:
    """The header's lines on what the effects removed and what became of the junctions."""
    notes = []
    by_reason: dict[str, list[str]] = {}
    for eid, why in removed.items():
        by_reason.setdefault(why, []).append(eid)
    for why, ids in by_reason.items():
        notes.append(f"removed ({why}): {', '.join(ids)}")
    if states:
        for why in sorted(set(states.values())):
            notes.append(f"removed auxiliary states ({why}): "
                         + ", ".join(s for s, w in states.items() if w == why))
    for eid in sources:
        t0 = bg.element(eid).type
        notes.append(f"{t0}-junction {eid} left with one bond: a zero "
                     f"{'effort' if t0 == '1' else 'flow'} source ({kind[eid]})")
    if merged:
        notes.append("junctions left with two bonds, replaced by one bond: "
                     + ", ".join(f"{j} ({b1} + {b2} -> {nb})" for j, (nb, b1, b2) in merged.items()))
    return tuple(notes)
