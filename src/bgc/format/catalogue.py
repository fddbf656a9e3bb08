"""The library's documentation, from the library's own text: ``bgc library [NAME]`` and
docs/library.md (scripts/library_docs.py) print what :func:`describe` and :func:`catalogue`
make of the component files in bgc/format/library (bgc.format.library)."""
from __future__ import annotations

from bgc.base.errors import Coord
from bgc.format.library import PREFIX, names, resolve
from bgc.format.parse import parse_file


def _value_text(value) -> str:
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, tuple):
        return "[" + ", ".join(_value_text(v) for v in value) + "]"
    return str(getattr(value, "text", value))


def describe(comp, markdown: bool = False) -> str:
    """The documentation of one library component, from its own text."""
    h = (lambda s: f"### `{s}`") if markdown else (lambda s: s)
    item = "- " if markdown else "  "
    code = (lambda s: f"`{s}`") if markdown else (lambda s: s)
    lines = [h(comp.name), ""]
    if comp.description:
        lines += [" ".join(comp.description.split()), ""]
    lines.append("Ports:" if not markdown else "**Ports**")
    for pname, target, _ in comp.ports:
        domain, desc = comp.port_doc(pname)
        n = cardinality(comp, target)
        card = f", {n}-vector" if n > 1 else ""
        lines.append(f"{item}{code(pname)} ({domain or 'any domain'}{card}): {desc}".rstrip(": "))
    lines += ["", "Parameters:" if not markdown else "**Parameters**"]
    for p in comp.body.params:
        unit = p.unit or "-"
        desc = f": {p.description}" if p.description else ""
        lines.append(f"{item}{code(p.name)} = {code(_value_text(p.value))} [{unit}]{desc}")
    if not comp.body.params:
        lines.append(f"{item}(none)")
    states = [s for s in comp.body.states]
    if states:
        lines += ["", "States:" if not markdown else "**States**"]
        lines += [f"{item}{code(s.name)} [{s.unit or '-'}]: d/dt = {code(s.derivative.text)}"
                  for s in states]
    if comp.laws:
        lines += ["", "Laws:" if not markdown else "**Laws**"]
        lines += [f"{item}{law}" for law in comp.laws]
    return "\n".join(lines) + "\n"


def cardinality(comp, target: str) -> int:
    """The cardinality of the bonds a component's element ``target`` holds inside (1 when
    it holds none: a rigid pin's junction takes the cardinality of what is bonded to it)."""
    return max((b.n for b in comp.body.bonds if target in (b.src[0], b.dst[0])), default=1)


def load(name: str):
    """The parsed library file ``name`` (a bgc.format.parse.Model)."""
    return parse_file(resolve(PREFIX + name, Coord("<library>", 1, 1)))


def catalogue(markdown: bool = False) -> str:
    """Every library file with its components, one line each."""
    out = []
    for name in names():
        model = load(name)
        out.append(f"## `{PREFIX}{name}`" if markdown else f"{PREFIX}{name}: {model.description}")
        if markdown:
            out += ["", " ".join(model.description.split()), ""]
        for c in model.components:
            first = " ".join(c.description.split()).split(". ")[0].rstrip(".")
            out.append(f"- `{c.name}`: {first}" if markdown else f"  {c.name:<24} {first}")
        out.append("")
    return "\n".join(out)


def find(name: str):
    """(file name, component) for a component name, or (file name, None) for a library file's
    name; None when the library has neither."""
    if name in names():
        return name, None
    for lib in names():
        for c in load(lib).components:
            if c.name == name:
                return lib, c
    return None
