"""Stage 2: a :class:`~bgc.format.parse.Model` -> a flat, checked bond graph (its networkx
view, ``BondGraph.graph``, is built only when asked for).

Component instances are expanded here: an element ``It`` inside instance ``link1`` becomes the
flat element ``link1.It`` (``link1__It`` in generated code). Each flat element remembers its
*scope*, so its expressions resolve names the way they were written. The bond's direction is the
power direction; every bond has a cardinality. The checks that need the whole graph (ports,
arity, cardinality agreement on junctions, dangling elements) are done here.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field

from bgc.base.errors import Coord, ModelError
from bgc.base.limits import LIMITS
from bgc.core.units import check_units
from bgc.format.library import LIBRARY_DIR, PREFIX
from bgc.format.parse import ELEMENT_TYPES as _TYPES
from bgc.format.parse import JUNCTIONS, STORAGE, TWO_PORTS, Body, Component, Model
from bgc.format.reader import outside
from bgc.format.whitelist import Expr

MAX_DEPTH = LIMITS.component_depth


@dataclass(frozen=True)
class ParamBinding:
    """What a component parameter means in one instance."""

    kind: str  # "global": a module parameter id; "expr": an expression in the parent scope
    target: object  # str (global id) or Expr
    scope: tuple[str, ...] = ()


@dataclass(frozen=True)
class Scope:
    prefix: tuple[str, ...]
    names: dict  # local name -> kind: element / state / param / input / instance / bond
    bindings: dict  # component parameter name -> ParamBinding (empty at top level)
    component: str = ""


def _within_bounds(inst: str, comp: str, param, val, coord) -> None:
    """An instance's number for a component parameter within the parameter's ``min`` and
    ``max`` (as the component's own value must be); an expression's value is the run's."""
    if param.min is None and param.max is None:
        return
    try:
        v = float(str(getattr(val, "text", val)).strip())
    except ValueError:
        return
    out = outside(v, param.min, param.max)
    if out is not None:
        raise ModelError(coord, f"instance {inst!r}: parameter {param.name!r} = {v:g} is "
                                f"{out[0]} the {out[1]} {out[2]:g} of component {comp!r}")


@dataclass(frozen=True)
class FlatParam:
    id: str
    value: object  # float, tuple of tuples, or Expr (derived)
    scope: tuple[str, ...]
    coord: Coord
    unit: str = ""
    min: float | None = None
    max: float | None = None
    description: str = ""
    free: bool = True


@dataclass(frozen=True)
class FlatElement:
    id: str
    type: str
    scope: tuple[str, ...]
    coord: Coord
    law: tuple[str, Expr] | None
    initial: Expr | None
    effects: tuple[str, ...]
    component: str = ""
    closure: Expr | None = None  # Sf: the position residual of the loop it may close


@dataclass(frozen=True)
class FlatBond:
    id: str
    src: str
    dst: str
    n: int
    coord: Coord
    index: int  # position in the flat list, for stable ordering


@dataclass(frozen=True)
class FlatState:
    id: str
    shape: tuple[int, ...]
    initial: Expr
    derivative: Expr
    scope: tuple[str, ...]
    coord: Coord
    unit: str = ""
    effects: tuple[str, ...] = ()


@dataclass(frozen=True)
class BondGraph:
    model: Model
    params: tuple[FlatParam, ...]
    elements: tuple[FlatElement, ...]
    bonds: tuple[FlatBond, ...]
    states: tuple[FlatState, ...]
    scopes: dict
    units: object = field(default=None, repr=False, compare=False)  # bgc.core.units.UnitReport

    def element(self, eid: str) -> FlatElement:
        return self._el[eid]

    def bond(self, bid: str) -> FlatBond:
        return self._bd[bid]

    def bonds_of(self, eid: str) -> list[FlatBond]:
        """The element's bonds in declaration order."""
        return self._adj[eid]

    @property
    def graph(self):
        """The bond graph as a ``networkx.MultiDiGraph`` (elements as nodes with their
        ``type``, bonds as edges keyed by bond id with their cardinality ``n``), built on first
        use: the compile itself reads the elements and bonds, never this view, and a cold run
        does not import networkx for it."""
        g = self.__dict__.get("_nx")
        if g is None:
            import networkx as nx  # lazy: only a caller that asks for the graph view needs it

            g = nx.MultiDiGraph()
            for el in self.elements:
                g.add_node(el.id, type=el.type)
            for bd in self.bonds:
                g.add_edge(bd.src, bd.dst, key=bd.id, n=bd.n)
            object.__setattr__(self, "_nx", g)
        return g

    def __post_init__(self):
        object.__setattr__(self, "_el", {e.id: e for e in self.elements})
        object.__setattr__(self, "_bd", {b.id: b for b in self.bonds})
        adj: dict[str, list[FlatBond]] = {e.id: [] for e in self.elements}
        for b in self.bonds:
            adj[b.src].append(b)
            adj[b.dst].append(b)
        object.__setattr__(self, "_adj", adj)


def code_name(path: str) -> str:
    """``link1.It`` -> ``link1__It``: the identifier used in generated code."""
    return path.replace(".", "__")


def join(prefix: tuple[str, ...], name: str) -> str:
    return ".".join(prefix + (name,))


def build_graph(model: Model) -> BondGraph:
    b = _Flattener(model)
    b.body(model.body, (), None, {}, (), 0)
    for inp in model.inputs:
        b.scopes[()].names[inp.name] = "input"
    bg = BondGraph(model, tuple(b.params), tuple(b.elements), tuple(b.bonds), tuple(b.states),
                   b.scopes)
    _check(bg)
    # dimensions: a located error where a law, unit or output disagrees; the report (each
    # bond's, output's and state's dimension) stays with the graph for units of FMI and plots
    object.__setattr__(bg, "units", check_units(bg))
    return bg


class _Flattener:
    def __init__(self, model: Model):
        self.model = model
        self.params: list[FlatParam] = []
        self.elements: list[FlatElement] = []
        self.bonds: list[FlatBond] = []
        self.states: list[FlatState] = []
        self.scopes: dict[tuple[str, ...], Scope] = {}
        self.ports: dict[tuple[str, ...], dict[str, str]] = {}
        #: prefix inside a library part -> (the user's instance coord, "bgc:LIB PART"): what
        #: the part brings in is located at the instance that brought it (the library's own
        #: lines are not the user's to fix), naming the element's full path
        self.via: dict[tuple[str, ...], tuple[Coord, str]] = {}

    def at(self, prefix, coord: Coord, kind: str, fid: str) -> Coord:
        """``coord``, or inside a library part the user's instance line naming ``fid``."""
        if prefix not in self.via:
            return coord
        where, part = self.via[prefix]
        return Coord(where.file, where.line, where.column,
                     via=f"{kind} {fid!r} (from {part})")

    def enter(self, prefix, sub_prefix, el, sub: Component) -> None:
        """Record where a library part's instance is: the line in the user's files that
        names the part (a part inside a library part keeps it)."""
        if prefix in self.via:
            self.via[sub_prefix] = self.via[prefix]
        elif os.path.dirname(os.path.abspath(sub.coord.file)) == os.path.abspath(LIBRARY_DIR):
            lib = os.path.splitext(os.path.basename(sub.coord.file))[0]
            self.via[sub_prefix] = (el.coord, f"{PREFIX}{lib} {sub.name}")

    def body(self, body: Body, prefix, comp: Component | None, bindings, effects, depth):
        names: dict[str, str] = {}
        for p in body.params:
            names[p.name] = "param"
        for el in body.elements:
            names[el.name] = "instance" if el.type not in _TYPES else "element"
        for s in body.states:
            names[s.name] = "state"
        for bd in body.bonds:
            if bd.auto and bd.name in names:  # an automatic name gives way to the user's
                continue
            if bd.name in names and names[bd.name] != "bond":
                kind = {"param": "parameter"}.get(names[bd.name], names[bd.name])
                raise ModelError(bd.coord, f"bond name {bd.name!r} is also the name of "
                                           f"{_article(kind)} {kind}: rename one of them")
            names.setdefault(bd.name, "bond")
        self.scopes[prefix] = Scope(prefix, names, bindings, comp.name if comp else "")
        # Parameters: at top level all are module parameters; in a component, those the
        # instance did not bind become module parameters named instance__param.
        for p in body.params:
            if p.name in bindings:
                continue
            pid = join(prefix, p.name)
            self.params.append(FlatParam(pid, p.value, prefix,
                                         self.at(prefix, p.coord, "parameter", pid),
                                         p.unit, p.min, p.max,
                                         p.description, p.free))
            if prefix:
                bindings[p.name] = ParamBinding("global", pid)
        instances = [el for el in body.elements if el.type not in _TYPES]
        if len(instances) > LIMITS.instances_per_level:
            el = instances[LIMITS.instances_per_level]
            raise ModelError(el.coord, f"element {el.name!r}: more than "
                                       f"{LIMITS.instances_per_level} component instances in one "
                                       "body (the limit of instances per level)")
        for el in body.elements:
            self.count(el.coord, el.name)
            eff = tuple(dict.fromkeys(effects + el.effects))
            if el.type in _TYPES:
                eid = join(prefix, el.name)
                self.elements.append(FlatElement(eid, el.type, prefix,
                                                 self.at(prefix, el.coord, "element", eid),
                                                 el.law(), el.initial, eff,
                                                 comp.name if comp else "", el.closure))
                continue
            sub = self.model.component(el.type)
            if sub is None:
                raise ModelError(el.coord, f"element {el.name!r}: unknown element type "
                                           f"{el.type!r} (not an element type or a component)")
            if depth >= MAX_DEPTH:
                raise ModelError(el.coord, f"element {el.name!r}: components nested deeper "
                                           f"than {MAX_DEPTH} (a component instantiating itself?)")
            declared = {p.name: p for p in sub.body.params}
            sub_bind: dict[str, ParamBinding] = {}
            for key, val, coord in el.args:
                if key not in declared:
                    raise ModelError(coord, f"instance {el.name!r}: component {sub.name!r} has "
                                            f"no parameter {key!r}")
                _within_bounds(el.name, sub.name, declared[key], val, coord)
                sub_bind[key] = ParamBinding("expr", val, prefix)
            sub_prefix = prefix + (el.name,)
            self.enter(prefix, sub_prefix, el, sub)
            self.ports[sub_prefix] = {pn: target for pn, target, _ in sub.ports}
            self.body(sub.body, sub_prefix, sub, sub_bind, eff, depth + 1)
        for s in body.states:
            sid = join(prefix, s.name)
            self.states.append(FlatState(sid, s.shape, s.initial, s.derivative, prefix,
                                         self.at(prefix, s.coord, "state", sid), s.unit,
                                         tuple(dict.fromkeys(effects + s.effects))))
        scope = self.scopes[prefix]
        for bd in body.bonds:
            src = self.endpoint(scope, bd.src, bd.coord, bd.name)
            dst = self.endpoint(scope, bd.dst, bd.coord, bd.name)
            if src == dst:
                raise ModelError(bd.coord, f"bond {bd.name!r} joins {src!r} to itself")
            bid = join(prefix, bd.name)
            self.bonds.append(FlatBond(bid, src, dst, bd.n, self.at(prefix, bd.coord, "bond", bid),
                                       len(self.bonds)))

    def count(self, coord: Coord, name: str) -> None:
        """Refuse a model whose flattened form grows past the limit (instances of instances
        multiply: 16 instances on each of 7 levels are 268 million leaves)."""
        total = len(self.elements) + len(self.bonds) + len(self.params) + len(self.states)
        if total >= LIMITS.flat_elements:
            raise ModelError(coord, f"{name!r}: the flattened model has more than "
                                    f"{LIMITS.flat_elements} elements, bonds, parameters and "
                                    "states (the limit of instantiated elements)")

    def endpoint(self, scope: Scope, path: tuple[str, ...], coord: Coord, bname: str) -> str:
        head = path[0]
        kind = scope.names.get(head)
        if kind is None:
            raise ModelError(coord, f"bond {bname!r}: no element {head!r}")
        if kind == "element":
            if len(path) != 1:
                raise ModelError(coord, f"bond {bname!r}: {head!r} is an element, not a "
                                        "component instance: it has no ports")
            return join(scope.prefix, head)
        if kind == "instance":
            if len(path) != 2:
                raise ModelError(coord, f"bond {bname!r}: {head!r} is a component instance: "
                                        f"name one of its ports as {head}.PORT")
            sub = scope.prefix + (head,)
            ports = self.ports[sub]
            if path[1] not in ports:
                raise ModelError(coord, f"bond {bname!r}: instance {head!r} has no port "
                                        f"{path[1]!r} (ports: {', '.join(ports)})")
            target = ports[path[1]]
            if self.scopes[sub].names.get(target) != "element":
                raise ModelError(coord, f"bond {bname!r}: port {path[1]!r} of {head!r} must "
                                        "lead to an element, not a nested instance")
            return join(sub, target)
        kind = {"param": "parameter"}.get(kind, kind)
        raise ModelError(coord, f"bond {bname!r}: {head!r} is {_article(kind)} {kind}, not an "
                                "element")


def _article(word: str) -> str:
    return "an" if word[:1].lower() in "aeiou" else "a"


def a_kind(kind: str) -> str:
    """'param' -> 'a parameter', 'input' -> 'an input': a scope kind in words."""
    word = {"param": "parameter"}.get(kind, kind)
    return f"{_article(word)} {word}"



def _check(bg: BondGraph) -> None:
    for el in bg.elements:
        bonds = bg.bonds_of(el.id)
        n = len(bonds)
        if el.type in JUNCTIONS:
            if n < 2:
                raise ModelError(el.coord, f"junction {el.id!r} has {n} bond(s): a junction "
                                           "needs at least two (dangling junction)")
            if n > LIMITS.junction_bonds:
                raise ModelError(el.coord, f"junction {el.id!r} has {n} bonds, more than "
                                           f"{LIMITS.junction_bonds} (the limit of bonds on one "
                                           "junction): split it into joined junctions")
            cards = {b.n for b in bonds}
            if len(cards) > 1:
                detail = ", ".join(f"{b.id} (n={b.n})" for b in bonds)
                raise ModelError(el.coord, f"junction {el.id!r}: cardinality mismatch across "
                                           f"its bonds: {detail}")
        elif el.type in TWO_PORTS:
            ins = [b for b in bonds if b.dst == el.id]
            outs = [b for b in bonds if b.src == el.id]
            if n != 2 or len(ins) != 1 or len(outs) != 1:
                raise ModelError(el.coord, f"{el.type} {el.id!r} needs exactly one incoming and "
                                           f"one outgoing bond, it has {len(ins)} in and "
                                           f"{len(outs)} out")
        else:
            if n != 1:
                raise ModelError(el.coord, f"{el.type} {el.id!r} is a one-port element: it needs "
                                           f"exactly one bond, it has {n}")
            # (a source whose bond points into it absorbs power: allowed, the sign follows)
        if el.type in STORAGE and el.law is None:
            raise ModelError(el.coord, f"{el.type} {el.id!r} has no constitutive law")
