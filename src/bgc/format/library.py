"""The component library shipped with bgc: YAML component files in ``bgc/format/library``.

A model imports one with ``imports: [{from: "bgc:NAME"}]``. ``NAME`` is a dotted name
(``mechanics.spatial``) checked against the files this package holds, and nothing else: it is
never joined to a user's path, so no user file can shadow it and no name can climb out of the
library's folder. The files are ordinary component files (parsed by :mod:`bgc.format.parse`,
like any import); their components carry their own documentation (``description``, ``laws``,
each port's ``domain`` and each parameter's unit, default and description), which
:mod:`bgc.format.catalogue` turns into the text of ``bgc library`` and of docs/library.md.
"""
from __future__ import annotations

import os
import re

import yaml

from bgc.base.errors import Coord, ModelError
from bgc.base.paths import PACKAGE_DIR
from bgc.format.reader import Reader, require, short

#: What marks a library import: ``from: "bgc:NAME"`` (a user's file is named with ``file:``).
PREFIX = "bgc:"
#: The folder of the library's files (package data of bgc.format).
LIBRARY_DIR = os.path.join(PACKAGE_DIR, "format", "library")
_NAME = re.compile(r"[a-z][a-z0-9_]*(\.[a-z][a-z0-9_]*){0,3}")
#: The domains a port may declare (the words of bgc check --units, shortened).
DOMAINS = ("translation", "rotation", "electrical", "hydraulic", "thermal")


def names() -> list[str]:
    """The library's file names (``mechanics.spatial``, ...), sorted."""
    try:
        files = os.listdir(LIBRARY_DIR)
    except OSError:
        return []
    return sorted(f[:-5] for f in files if f.endswith(".yaml") and _NAME.fullmatch(f[:-5]))


def resolve(spec: str, coord: Coord) -> str:
    """The package file a ``from: "bgc:NAME"`` import means; a located error otherwise."""
    if not spec.startswith(PREFIX):
        raise ModelError(coord, f"import from {short(spec)}: a library import reads "
                                f"'{PREFIX}NAME' (a file of your own is imported with 'file:')")
    name = spec[len(PREFIX):]
    known = names()
    if not _NAME.fullmatch(name) or name not in known:
        raise ModelError(coord, f"import from {short(spec)}: no such library (the library "
                                f"holds: {', '.join(known) or 'nothing'})")
    return os.path.join(LIBRARY_DIR, name + ".yaml")


def read_port(r: Reader, cname: str, pname: str, node) -> tuple[str, str, str]:
    """A component's port: ``PORT: ELEMENT``, or ``PORT: {element: E, domain: D,
    description: TEXT}`` -> (element, domain, description)."""
    if not isinstance(node, yaml.MappingNode):
        return r.string(node, f"port {pname!r}"), "", ""
    pm = r.mapping(node, f"component {cname!r} port {pname!r}")
    require(r, pm, node, ("element", "domain", "description"),
            f"component {cname!r} port {pname!r}", required=("element",))
    target = r.string(pm["element"][1], f"port {pname!r} element")
    domain = ""
    if "domain" in pm:
        domain = r.string(pm["domain"][1], "domain")
        if domain not in DOMAINS:
            raise ModelError(r.coord(pm["domain"][1]), f"component {cname!r} port {pname!r}: "
                                                       f"domain {short(domain)} is not one of "
                                                       f"{', '.join(DOMAINS)}")
    desc = r.string(pm["description"][1], "description") if "description" in pm else ""
    return target, domain, desc


def read_laws(r: Reader, cname: str, node) -> tuple[str, ...]:
    """A component's ``laws:``: a list of lines of text (documentation only: the elements are
    the equations)."""
    return tuple(" ".join(r.string(i, f"component {cname!r} law").split())
                 for i in r.seq(node, f"component {cname!r} laws"))
