"""The library's documentation, from the library's own text: ``bgc library [NAME]`` and
docs/library.md (scripts/library_docs.py) print what :func:`describe`, :func:`library_text`
and :func:`catalogue` make of the component files in bgc/format/library (bgc.format.library):
each component's description, ports with their domains, parameters with their units, defaults
and descriptions, states and laws, and a hybrid component's modes and events."""
from __future__ import annotations

import textwrap

from bgc.base.errors import Coord
from bgc.format.library import PREFIX, names, resolve
from bgc.format.parse import parse_file

WIDTH = 92


def _value_text(value) -> str:
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, tuple):
        return "[" + ", ".join(_value_text(v) for v in value) + "]"
    return str(getattr(value, "text", value))


def _para(text: str, markdown: bool) -> list[str]:
    """One paragraph or list item (its leading spaces kept), wrapped for a terminal."""
    indent = text[:len(text) - len(text.lstrip(" "))]
    text = " ".join(text.split())
    if markdown:
        return [indent + text]
    return textwrap.wrap(text, WIDTH, initial_indent=indent,
                         subsequent_indent=indent + "  " if indent else "")


def cardinality(comp, target: str) -> int:
    """The cardinality of the bonds a component's element ``target`` holds inside (1 when
    it holds none: a rigid pin's junction takes the cardinality of what is bonded to it)."""
    return max((b.n for b in comp.body.bonds if target in (b.src[0], b.dst[0])), default=1)


def describe(comp, lib: str, markdown: bool = False) -> str:
    """The documentation of one component of the library ``lib``, from its own text."""
    code = (lambda s: f"`{s}`") if markdown else (lambda s: s)
    head = (lambda s: f"**{s}**") if markdown else (lambda s: f"{s}:")
    item = "- " if markdown else "  "
    title = (f"### `{comp.name}`" if markdown else f"{comp.name} ({PREFIX}{lib})")
    lines = [title, ""] + _para(comp.description, markdown) + ["", head("Ports")]
    for pname, target, _ in comp.ports:
        domain, desc = comp.port_doc(pname)
        n = cardinality(comp, target)
        card = f", {n}-vector" if n > 1 else ""
        lines += _para(f"{item}{code(pname)} ({domain}{card}): {desc}", markdown)
    lines += ["", head("Parameters")]
    for p in comp.body.params:
        lines += _para(f"{item}{code(p.name)} = {code(_value_text(p.value))} [{p.unit or '-'}]: "
                       f"{p.description}", markdown)
    if not comp.body.params:
        lines.append(f"{item}(none)")
    discrete = set(comp.modes) | {ev.count_state for ev in comp.events if ev.every is not None}
    states = [s for s in comp.body.states if s.name not in discrete]
    if states:
        lines += ["", head("States")]
        for s in states:
            lines += _para(f"{item}{code(s.name)} [{s.unit or '-'}]: d/dt = "
                           f"{code(s.derivative.text)}", markdown)
    # what an output reads as instance.element: e(), f(), p() of an I, q() of a C
    lines += ["", head("Elements")] + _para(
        f"{item}" + ", ".join(f"{code(e.name)} ({e.type})" for e in comp.body.elements),
        markdown)
    lines += ["", head("Laws")]
    for law in comp.laws:
        lines += _para(f"{item}{law}", markdown)
    return "\n".join(lines + _hybrid_text(comp, code, head, item, markdown)) + "\n"


def _hybrid_text(comp, code, head, item, markdown: bool) -> list[str]:
    """A hybrid component's modes (initial value, meaning) and events (guard or time, the
    resets, meaning): what each instance owns as ``instance.name``."""
    lines = []
    if comp.mode_docs:
        lines += ["", head("Modes")]
        for m in comp.mode_docs:
            lines += _para(f"{item}{code(m.name)} (initially {code(m.initial.text)}): "
                           f"{m.description}", markdown)
    if comp.events:
        lines += ["", head("Events")]
        way = {1: "rises", -1: "falls", 0: "crosses"}
        for ev in comp.events:
            if ev.condition is not None:
                when = f"when {code(ev.condition.text)} {way[ev.direction]} through 0"
            elif ev.every is not None:
                when = f"every {code(ev.every.text)}" + (f" from {code(ev.at.text)}"
                                                          if ev.at is not None else "")
            else:
                when = f"at t = {code(ev.at.text)}"
            acts = ", ".join(f"{code(_target(a) + ' = ' + a.value.text)}" for a in ev.actions)
            lines += _para(f"{item}{code(ev.name)}: {when}, sets {acts}"
                           + (f" ({ev.description})" if ev.description else ""), markdown)
    return lines


def _target(action) -> str:
    path = ".".join(action.path)
    return f"{action.func}({path})" if action.func else path


def load(name: str):
    """The parsed library file ``name`` (a bgc.format.parse.Model)."""
    return parse_file(resolve(PREFIX + name, Coord("<library>", 1, 1)))


def library_text(name: str, markdown: bool = False) -> str:
    """One library file: its description and every component in full."""
    model = load(name)
    head = f"## `{PREFIX}{name}`" if markdown else f"{PREFIX}{name}"
    body = [describe(c, name, markdown) for c in model.components]
    return "\n".join([head, ""] + _para(model.description, markdown) + [""] + body)


def catalogue(markdown: bool = False) -> str:
    """Every library file with its components, one line each."""
    out = []
    for name in names():
        model = load(name)
        out += [f"{PREFIX}{name}" if not markdown else f"- `{PREFIX}{name}`: "
                + " ".join(model.description.split())]
        for c in model.components:
            first = " ".join(c.description.split()).split(". ")[0].rstrip(".")
            if markdown:
                out.append(f"  - [`{c.name}`](#{c.name}): {first}")
            else:
                out += textwrap.wrap(f"{c.name:<23} {first}", WIDTH, initial_indent="  ",
                                     subsequent_indent=" " * 26)
    return "\n".join(out) + "\n"


def find(name: str):
    """(library name, component) for a component's name, or (library name, None) for a
    library's; None when the library has neither."""
    if name in names():
        return name, None
    for lib in names():
        for c in load(lib).components:
            if c.name == name:
                return lib, c
    return None
