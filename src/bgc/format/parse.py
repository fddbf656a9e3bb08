"""Stage 1: YAML text -> a validated :class:`Model` (frozen dataclasses with a Coord each).

The YAML is read with PyYAML's safe *composer*, so every node keeps its start mark and every
error can point at the line and column it comes from. Duplicate keys are errors (plain YAML
loaders keep the last one silently). Expressions are checked here by the whitelisting parser of
:mod:`bgc.format.expr`; names are resolved later, by the stage that knows them.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import yaml

from bgc.base.errors import Coord, ModelError
from bgc.base.limits import LIMITS
from bgc.base.safeio import read_text_bounded
from bgc.format import library as _library
from bgc.format import tables as _tables
from bgc.format.reader import (  # noqa: F401
    IDENT,
    MAX_YAML_DEPTH,
    RESERVED,
    Reader,
    check_name,
    finite_number,
    outside,
    param_value,
    read_stabilisation,
    require,
    short,
)
from bgc.format.whitelist import Expr

ELEMENT_TYPES = ("Se", "Sf", "C", "I", "R", "TF", "GY", "MTF", "MGY", "0", "1", "Sw")

#: The element table: for each type, the law keys it accepts (exactly one unless noted).
LAWS: dict[str, tuple[str, ...]] = {
    "Se": ("effort",), "Sf": ("flow",),
    "I": ("inertia", "flow"), "C": ("stiffness", "compliance", "effort"),
    "R": ("resistance", "effort", "flow"),
    "TF": ("ratio",), "GY": ("ratio",), "MTF": ("modulus",), "MGY": ("modulus",),
    "0": (), "1": (),
    "Sw": ("closed",),  # an ideal switch: Se(0) where closed, Sf(0) where open (bgc.core.modes)
}
CLOSURE = {"Sf": ("closure",)}  # a flow source's optional position residual (a loop's closure)
STORAGE = ("I", "C")
TWO_PORTS = ("TF", "GY", "MTF", "MGY")
JUNCTIONS = ("0", "1")

MAX_CARDINALITY = LIMITS.cardinality


# ---------------------------------------------------------------------------------------------
# The model's dataclasses


@dataclass(frozen=True)
class Param:
    name: str
    value: object  # float, tuple of tuples (matrix), or Expr (derived parameter)
    coord: Coord
    unit: str = ""
    min: float | None = None
    max: float | None = None
    description: str = ""
    free: bool = True


@dataclass(frozen=True)
class Input:
    name: str
    default: Expr
    shape: tuple[int, ...]
    coord: Coord
    unit: str = ""
    table: object = None  # a bgc.format.tables.Table: the input is data (default is then "0")


@dataclass(frozen=True)
class Element:
    name: str
    type: str  # an element type, or a component name
    coord: Coord
    laws: tuple[tuple[str, Expr], ...] = ()
    initial: Expr | None = None
    args: tuple[tuple[str, object, Coord], ...] = ()  # component instance parameter values
    effects: tuple[str, ...] = ()
    closure: Expr | None = None  # Sf: the loop's position residual (bgc.core.constraints)

    def law(self) -> tuple[str, Expr] | None:
        return self.laws[0] if self.laws else None


@dataclass(frozen=True)
class Bond:
    name: str
    src: tuple[str, ...]
    dst: tuple[str, ...]
    n: int
    coord: Coord
    auto: bool = False  # named b1, b2, ... by its position (the user gave no name)


@dataclass(frozen=True)
class State:
    name: str
    shape: tuple[int, ...]
    initial: Expr
    derivative: Expr
    coord: Coord
    unit: str = ""
    effects: tuple[str, ...] = ()


@dataclass(frozen=True)
class Output:
    name: str
    expr: Expr
    coord: Coord
    unit: str = ""  # for plot axes ({expr: ..., unit: ...} in the model)


@dataclass(frozen=True)
class Body:
    """What a model and a component both hold."""

    params: tuple[Param, ...] = ()
    elements: tuple[Element, ...] = ()
    bonds: tuple[Bond, ...] = ()
    states: tuple[State, ...] = ()
    outputs: tuple[Output, ...] = ()


@dataclass(frozen=True)
class Component:
    name: str
    body: Body
    ports: tuple[tuple[str, str, Coord], ...]
    coord: Coord
    description: str = ""
    laws: tuple[str, ...] = ()  # documentation (bgc library): the elements are the equations
    port_docs: tuple[tuple[str, str, str], ...] = ()  # (port, domain, description)
    events: tuple = ()  # bgc.format.events.Event: each instance gets its own (names prefixed)
    modes: tuple[str, ...] = ()  # mode variables (the body's states whose derivative is 0)
    mode_docs: tuple = ()  # bgc.format.events.Mode of each of them (bgc library's docs)

    def port_doc(self, port: str) -> tuple[str, str]:
        return next(((d, t) for p, d, t in self.port_docs if p == port), ("", ""))


@dataclass(frozen=True)
class Model:
    name: str
    file: str
    body: Body
    inputs: tuple[Input, ...]
    components: tuple[Component, ...]
    description: str = ""
    source_hash: str = ""
    coord: Coord = field(default=None)  # type: ignore[assignment]
    strict_causality: bool = False  # `causality: strict`: derivative causality is an error
    events: tuple = ()  # bgc.format.events.Event: zero crossings and time events, with actions
    modes: tuple[str, ...] = ()  # the discrete mode variables (states whose derivative is 0)
    strict_units: bool = False  # `units: strict`: every parameter needs a unit
    #: `constraints: {stabilisation: alpha, initial: project}` (bgc.core.constraints): the rate
    stabilisation: float | None = None  # (1/s) of a loop's violation decay; None: the default
    project: bool = False  # project the initial state onto the constraints

    def component(self, name: str) -> Component | None:
        for c in self.components:
            if c.name == name:
                return c
        return None


# ---------------------------------------------------------------------------------------------
# YAML nodes with places

#: Deepest nesting of YAML collections in a model file.
# ---------------------------------------------------------------------------------------------


class _Imports:
    """What one parse shares across its imports: each file parsed once (cached by its resolved
    path), the chain of files being parsed (for cycles), and the number of files read."""

    def __init__(self):
        self.cache: dict[str, Model] = {}
        self.stack: list[str] = []
        self.files = 0  # distinct files begun


def parse_file(path: str | Path, _imports: _Imports | None = None,
               _coord: Coord | None = None) -> Model:
    """Read and validate one model file (and the files it imports)."""
    what = "model file" if _coord is None else "imported file"
    text = read_text_bounded(path, _coord, what, LIMITS.model_bytes)
    return parse_text(text, str(path), _imports)


def parse_text(text: str, path: str = "<model>", _imports: _Imports | None = None) -> Model:
    import hashlib

    _check_encodable(text, path)
    r = Reader(path, text)
    if len(text) > LIMITS.model_bytes:
        raise ModelError(Coord(path, 1, 1), f"model file is larger than the limit of "
                                            f"{LIMITS.model_bytes} bytes")
    root = r.compose()
    if root is None:
        raise ModelError(Coord(path, 1, 1), "the model file is empty")
    return parse_root(r, root, hashlib.sha256(text.encode()).hexdigest()[:16], _imports)


def parse_root(r: Reader, root, source_hash: str, _imports: _Imports | None = None) -> Model:
    """The model from its composed YAML node tree (each node with its place): the one
    validation of a model, shared by files, text and the Python builder (bgc.builder, whose
    nodes carry the places of the user's calls)."""
    path = r.path
    top = r.mapping(root, "the model")
    allowed = ("bgc", "name", "description", "parameters", "inputs", "elements", "bonds",
               "states", "outputs", "components", "imports", "causality", "modes", "events",
               "units", "constraints")
    require(r, top, root, allowed, "the model", required=("bgc", "name", "elements", "bonds"))
    strict = False
    if "causality" in top:
        mode = r.string(top["causality"][1], "causality")
        if mode not in ("strict", "eliminate"):
            raise ModelError(r.coord(top["causality"][1]), f"causality: {mode!r} is not one of "
                                                            "'strict', 'eliminate'")
        strict = mode == "strict"
    strict_units = False
    if "units" in top:
        mode = r.string(top["units"][1], "units")
        if mode not in ("strict", "check"):
            raise ModelError(r.coord(top["units"][1]), f"units: {short(mode)} is not one of "
                                                        "'strict', 'check'")
        strict_units = mode == "strict"
    version = r.scalar(top["bgc"][1], "bgc")
    if isinstance(version, bool) or version != 1:
        raise ModelError(r.coord(top["bgc"][1]), f"unsupported format version {version!r} "
                                                  "(this bgc reads version 1)")
    name = check_name(r.string(top["name"][1], "name"), r.coord(top["name"][1]), "model")
    description = r.string(top["description"][1], "description") if "description" in top else ""

    components: list[Component] = []
    if "imports" in top:
        imports = _imports if _imports is not None else _Imports()
        me = _resolve(path, Coord(path, 1, 1), path)
        imports.stack.append(me)
        try:
            components.extend(_read_imports(r, top["imports"][1], imports))
        finally:
            imports.stack.pop()
    if "components" in top:
        cm = r.mapping(top["components"][1], "components")
        known = {c.name: c for c in components}
        for cname, (kn, vn) in cm.items():
            check_name(cname, r.coord(kn), "component", allow_reserved=True)
            if cname in ELEMENT_TYPES:
                raise ModelError(r.coord(kn), f"component name {cname!r} is an element type")
            if cname in known:
                c0 = known[cname].coord
                raise ModelError(r.coord(kn), f"component {cname!r} is defined twice (also at "
                                              f"{c0})")
            known[cname] = _component(r, cname, kn, vn)
            components.append(known[cname])

    inputs = []
    if "inputs" in top:
        for iname, (kn, vn) in r.mapping(top["inputs"][1], "inputs").items():
            check_name(iname, r.coord(kn), "input")
            if _tables.is_table(r, vn):  # data: {table: FILE.csv, columns, interp, ...}
                tb = _tables.read_table(r, vn, f"input {iname!r}", ("unit", "description"))
                im = r.mapping(vn, f"input {iname!r}")
                unit = r.string(im["unit"][1], "unit") if "unit" in im else ""
                inputs.append(Input(iname, Expr("0", tb.coord), (), r.coord(kn), unit, tb))
                continue
            if isinstance(vn, yaml.MappingNode):
                im = r.mapping(vn, f"input {iname!r}")
                require(r, im, vn, ("default", "shape", "unit", "description"),
                         f"input {iname!r}", required=("default",))
                shape = r.shape(im["shape"][1], "shape") if "shape" in im else ()
                unit = r.string(im["unit"][1], "unit") if "unit" in im else ""
                default = r.expr(im["default"][1], f"input {iname!r} default")
            else:
                shape, unit = (), ""
                default = r.expr(vn, f"input {iname!r}")
            inputs.append(Input(iname, default, shape, r.coord(kn), unit))

    stabilisation, project = (read_stabilisation(r, top["constraints"][1]) if "constraints"
                              in top else (None, False))
    body = _body(r, top, root, "the model", is_component=False)
    body, events, modes = _hybrid(r, top, body)
    _check_unique(body, inputs)
    return Model(name=name, file=path, body=body, inputs=tuple(inputs),
                  components=tuple(components), description=description,
                  source_hash=source_hash, coord=r.coord(root), strict_causality=strict,
                  events=events, modes=tuple(m.name for m in modes),
                  strict_units=strict_units, stabilisation=stabilisation, project=project)


def _hybrid(r: Reader, top: dict, body: Body):
    """``modes:`` and ``events:`` (bgc.format.events); each mode joins the states (d/dt = 0)."""
    if "modes" not in top and "events" not in top:
        return body, (), ()
    # lazy: only a hybrid model has these sections
    from bgc.format import events as _events

    modes = _events.read_modes(r, top["modes"][1]) if "modes" in top else ()
    events = _events.read_events(r, top["events"][1]) if "events" in top else ()
    states = tuple(State(m.name, (), m.initial, Expr("0", m.initial.coord), m.coord)
                   for m in modes)
    # a periodic event's count: a state that only its own event moves (by one)
    states += tuple(State(ev.count_state, (), Expr("0", ev.every.coord),
                          Expr("0", ev.every.coord), ev.coord)
                    for ev in events if ev.every is not None)
    if states:
        body = replace(body, states=body.states + states)
    return body, events, modes


def _check_encodable(text: str, path: str) -> None:
    """Model text given as a str (bgc.compile) holds no lone surrogate: a file could never
    contain one, and every later stage writes the text as UTF-8."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError as exc:
        line = text.count("\n", 0, exc.start) + 1
        col = exc.start - (text.rfind("\n", 0, exc.start) + 1) + 1
        raise ModelError(Coord(path, line, col), f"the text holds a lone surrogate "
                                                 f"(U+{ord(text[exc.start]):04X}), which no "
                                                 "UTF-8 file can: not valid text") from None


def _resolve(path, coord: Coord, shown) -> str:
    """The absolute, symlink-free form of ``path``; a located error for a NUL byte or a
    symlink loop."""
    spath = str(path)
    if "\0" in spath:
        raise ModelError(coord, f"import path {short(str(shown))} contains a NUL byte")
    try:
        return str(Path(spath).resolve(strict=False))
    except (OSError, RuntimeError, ValueError):
        raise ModelError(coord, f"cannot resolve {short(str(shown))}: too many levels of "
                                "symbolic links (a symlink loop?)") from None


def _read_imports(r: Reader, node, imports: _Imports) -> list[Component]:
    """The components of the imported files, each file parsed once; a component reached along
    two import paths is the same object, and is listed once."""
    out: list[Component] = []
    listed: set[int] = set()
    for item in r.seq(node, "imports"):
        im = r.mapping(item, "an import")
        require(r, im, item, ("file", "from"), "an import")
        if ("file" in im) == ("from" in im):
            raise ModelError(r.coord(item), "an import names one of 'file:' (a file of yours) "
                                            "or 'from:' (the library, \"bgc:NAME\")")
        key = "file" if "file" in im else "from"
        fnode = im[key][1]
        coord = r.coord(fnode)
        rel = r.string(fnode, key)
        if "from" in im:  # the library: a package file, never a user's path
            rel = _library.resolve(rel, coord)
        elif not rel:
            raise ModelError(coord, "an import names an empty file path")
        target = _resolve(Path(r.path).parent / rel, coord, rel)
        if target in imports.stack:
            raise ModelError(coord, f"import cycle through {short(rel)}")
        sub = imports.cache.get(target)
        if sub is None:
            imports.files += 1
            if imports.files > LIMITS.import_files:
                raise ModelError(coord, f"more than {LIMITS.import_files} imported files "
                                        "(the limit of distinct files one model may import)")
            sub = parse_file(Path(r.path).parent / rel, imports, coord)
            imports.cache[target] = sub
        for c in sub.components:
            if id(c) in listed:
                continue
            if any(o.name == c.name for o in out):
                o = next(o for o in out if o.name == c.name)
                raise ModelError(coord, f"component {c.name!r} is defined twice (at {o.coord} "
                                        f"and {c.coord})")
            listed.add(id(c))
            out.append(c)
    return out


def _component(r: Reader, cname: str, kn, vn) -> Component:
    cm = r.mapping(vn, f"component {cname!r}")
    require(r, cm, vn, ("parameters", "ports", "elements", "bonds", "states", "description",
                         "laws", "modes", "events"),
            f"component {cname!r}", required=("ports", "elements", "bonds"))
    body = _body(r, cm, vn, f"component {cname!r}", is_component=True)
    body, events, mode_docs = _hybrid(r, cm, body)
    _check_unique(body, ())
    ports, docs = [], []
    elnames = {e.name for e in body.elements}
    for pname, (pk, pv) in r.mapping(cm["ports"][1], f"component {cname!r} ports").items():
        check_name(pname, r.coord(pk), "port", allow_reserved=True)
        target, domain, text = _library.read_port(r, cname, pname, pv)
        if target not in elnames:
            raise ModelError(r.coord(pv), f"component {cname!r}: port {pname!r} names "
                                          f"{target!r}, which is not one of its elements")
        ports.append((pname, target, r.coord(pk)))
        docs.append((pname, domain, text))
    if not ports:
        raise ModelError(r.coord(cm["ports"][1]), f"component {cname!r} has no ports")
    desc = r.string(cm["description"][1], "description") if "description" in cm else ""
    laws = _library.read_laws(r, cname, cm["laws"][1]) if "laws" in cm else ()
    return Component(cname, body, tuple(ports), r.coord(kn), desc, laws, tuple(docs),
                     events, tuple(m.name for m in mode_docs), mode_docs)


def _body(r: Reader, top: dict, node, what: str, is_component: bool) -> Body:
    params = []
    if "parameters" in top:
        for pname, (kn, vn) in r.mapping(top["parameters"][1], "parameters").items():
            check_name(pname, r.coord(kn), "parameter")
            params.append(_param(r, pname, kn, vn))
    elements = []
    for ename, (kn, vn) in r.mapping(top["elements"][1], "elements").items():
        check_name(ename, r.coord(kn), "element", allow_reserved=True)
        elements.append(_element(r, ename, kn, vn))
    bonds = []
    for i, bn in enumerate(r.seq(top["bonds"][1], "bonds"), start=1):
        bonds.append(_bond(r, i, bn))
    states = []
    if "states" in top:
        for sname, (kn, vn) in r.mapping(top["states"][1], "states").items():
            check_name(sname, r.coord(kn), "state")
            sm = r.mapping(vn, f"state {sname!r}")
            require(r, sm, vn, ("shape", "initial", "derivative", "unit", "description",
                                 "effects"),
                     f"state {sname!r}", required=("derivative",))
            shape = r.shape(sm["shape"][1], "shape") if "shape" in sm else ()
            init = (r.expr(sm["initial"][1], f"state {sname!r} initial") if "initial" in sm
                    else Expr("0", r.coord(vn)))
            states.append(State(sname, shape, init, r.expr(sm["derivative"][1],
                                                           f"state {sname!r} derivative"),
                                r.coord(kn), r.string(sm["unit"][1], "unit") if "unit" in sm else "",
                                _effects(r, sm)))
    outputs = []
    if "outputs" in top:
        if is_component:
            raise ModelError(r.coord(top["outputs"][0]), f"{what}: outputs belong to the model")
        for oname, (kn, vn) in r.mapping(top["outputs"][1], "outputs").items():
            check_name(oname, r.coord(kn), "output", allow_reserved=True)
            if isinstance(vn, yaml.MappingNode):  # {expr: "...", unit: "m"}
                om = r.mapping(vn, f"output {oname!r}")
                require(r, om, vn, ("expr", "unit"), f"output {oname!r}", required=("expr",))
                unit = r.string(om["unit"][1], "unit") if "unit" in om else ""
                outputs.append(Output(oname, r.expr(om["expr"][1], f"output {oname!r}"),
                                      r.coord(kn), unit))
                continue
            outputs.append(Output(oname, r.expr(vn, f"output {oname!r}"), r.coord(kn)))
    return Body(tuple(params), tuple(elements), tuple(bonds), tuple(states), tuple(outputs))


def _effects(r: Reader, m: dict) -> tuple[str, ...]:
    if "effects" not in m:
        return ()
    node = m["effects"][1]
    items = r.seq(node, "effects") if isinstance(node, yaml.SequenceNode) else [node]
    return tuple(check_name(r.string(i, "effect"), r.coord(i), "effect") for i in items)


def _param(r: Reader, pname: str, kn, vn) -> Param:
    unit, lo, hi, desc, free = "", None, None, "", True
    valnode = vn
    if isinstance(vn, yaml.MappingNode):
        pm = r.mapping(vn, f"parameter {pname!r}")
        require(r, pm, vn, ("value", "unit", "min", "max", "description", "free"),
                 f"parameter {pname!r}", required=("value",))
        valnode = pm["value"][1]
        unit = r.string(pm["unit"][1], "unit") if "unit" in pm else ""
        lo = r.number(pm["min"][1], "min") if "min" in pm else None
        hi = r.number(pm["max"][1], "max") if "max" in pm else None
        desc = r.string(pm["description"][1], "description") if "description" in pm else ""
        if "free" in pm:
            free = bool(r.scalar(pm["free"][1], "free"))
    value = param_value(r, pname, valnode)
    out = outside(value, lo, hi) if isinstance(value, float) else None
    if out is not None:
        raise ModelError(r.coord(valnode), f"parameter {pname!r}: value {value:g} is {out[0]} "
                                           f"its {out[1]} {out[2]:g}")
    return Param(pname, value, r.coord(kn), unit, lo, hi, desc, free)


def _element(r: Reader, ename: str, kn, vn) -> Element:
    em = r.mapping(vn, f"element {ename!r}")
    if "type" not in em:
        raise ModelError(r.coord(vn), f"element {ename!r}: missing key 'type'")
    tnode = em["type"][1]
    etype = r.scalar(tnode, "type")
    etype = str(etype) if isinstance(etype, int) and not isinstance(etype, bool) else etype
    if not isinstance(etype, str):
        raise ModelError(r.coord(tnode), f"element {ename!r}: type must be text")
    effects = _effects(r, em)
    if etype not in ELEMENT_TYPES:
        if not IDENT.fullmatch(etype):
            raise ModelError(r.coord(tnode), f"element {ename!r}: unknown element type {etype!r}")
        # A component instance: every other key is a parameter value (checked at flattening).
        args = []
        for key, (ak, av) in em.items():
            if key in ("type", "effects", "description"):
                continue
            check_name(key, r.coord(ak), "parameter")
            args.append((key, r.expr(av, f"{ename}.{key}"), r.coord(av)))
        return Element(ename, etype, r.coord(kn), args=tuple(args), effects=effects)
    allowed = ("type", "initial", "effects", "description", *LAWS[etype], *CLOSURE.get(etype, ()))
    for key, (ak, _) in em.items():
        if key not in allowed:
            hint = (f" ({etype} elements take {' or '.join(LAWS[etype])})" if LAWS[etype]
                    else f" (a {etype}-junction takes no law)")
            raise ModelError(r.coord(ak), f"element {ename!r}: unknown key {key!r}{hint}")
    laws = tuple((k, r.expr(em[k][1], f"element {ename!r} ({k})")) for k in LAWS[etype] if k in em)
    if LAWS[etype] and len(laws) != 1:
        raise ModelError(r.coord(kn), f"element {ename!r} ({etype}) needs exactly one of: "
                                      f"{', '.join(LAWS[etype])}")
    if "initial" in em and etype not in STORAGE:
        raise ModelError(r.coord(em["initial"][0]), f"element {ename!r}: only I and C elements "
                                                    "have an initial state")
    initial = r.expr(em["initial"][1], f"element {ename!r} (initial)") if "initial" in em else None
    closure = r.expr(em["closure"][1], f"element {ename!r} (closure)") if "closure" in em else None
    return Element(ename, etype, r.coord(kn), laws, initial, effects=effects, closure=closure)


def _endpoint(r: Reader, node, what) -> tuple[str, ...]:
    s = r.scalar(node, what)
    s = str(s) if isinstance(s, (int, float)) and not isinstance(s, bool) else s
    if not isinstance(s, str):
        raise ModelError(r.coord(node), f"{what} must name an element or a port")
    parts = tuple(s.split("."))
    if len(parts) > 2:
        raise ModelError(r.coord(node), f"{what} {s!r}: write element or instance.port")
    for part in parts:
        check_name(part, r.coord(node), "bond endpoint", allow_reserved=True)
    return parts


def _bond(r: Reader, i: int, bn) -> Bond:
    if isinstance(bn, yaml.SequenceNode):
        if len(bn.value) != 2:
            raise ModelError(r.coord(bn), f"bond {i}: write [from, to]")
        src = _endpoint(r, bn.value[0], f"bond {i} 'from'")
        dst = _endpoint(r, bn.value[1], f"bond {i} 'to'")
        return Bond(f"b{i}", src, dst, 1, r.coord(bn), auto=True)
    bm = r.mapping(bn, f"bond {i}")
    require(r, bm, bn, ("from", "to", "n", "name"), f"bond {i}", required=("from", "to"))
    name = f"b{i}"
    if "name" in bm:
        name = check_name(r.string(bm["name"][1], "name"), r.coord(bm["name"][1]), "bond")
    n = 1
    if "n" in bm:
        n = r.integer(bm["n"][1], "n")
        if not 1 <= n <= MAX_CARDINALITY:
            raise ModelError(r.coord(bm["n"][1]), f"bond {name!r}: cardinality must be 1.."
                                                  f"{MAX_CARDINALITY}, got {n}")
    return Bond(name, _endpoint(r, bm["from"][1], f"bond {name!r} 'from'"),
                _endpoint(r, bm["to"][1], f"bond {name!r} 'to'"), n, r.coord(bn),
                auto="name" not in bm)


def _check_unique(body: Body, inputs) -> dict:
    seen: dict[str, tuple[str, Coord]] = {}
    groups = [("parameter", body.params), ("input", inputs), ("element", body.elements),
              ("state", body.states), ("output", body.outputs)]
    for kind, items in groups:
        for it in items:
            if it.name in seen:
                k0, c0 = seen[it.name]
                raise ModelError(it.coord, f"duplicate name {it.name!r}: already "
                                           f"{'an' if k0[0] in 'aeiou' else 'a'} {k0} at line "
                                           f"{c0.line} (parameters, inputs, elements, states and "
                                           "outputs share one namespace)")
            seen[it.name] = (kind, it.coord)
    bnames: dict[str, Bond] = {}
    for b in body.bonds:
        if b.name in bnames:
            other = bnames[b.name]
            auto = other if other.auto else b if b.auto else None
            if auto is not None:  # a user's name equal to another bond's automatic name
                user = b if auto is other else other
                raise ModelError(user.coord, f"bond name {b.name!r} is the automatic name of the "
                                             f"bond at line {auto.coord.line}: choose another")
            raise ModelError(b.coord, f"duplicate bond name {b.name!r}")
        # An automatic name gives way to the user's names (the bond keeps it in generated code,
        # e_b3, but an expression's b3 means the user's parameter, element or state).
        if b.name in seen and not b.auto:
            kind = seen[b.name][0]
            raise ModelError(b.coord, f"bond name {b.name!r} is already "
                                      f"{'an' if kind[0] in 'aeiou' else 'a'} {kind}")
        bnames[b.name] = b
    return seen
