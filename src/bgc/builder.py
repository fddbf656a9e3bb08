"""Models from Python: a small builder that yields the model the YAML reader gives.

    import bgc
    b = bgc.Builder("msd", description="mass-spring-damper", units="strict")
    b.parameter("m", 2.0, unit="kg", min=0)
    b.element("mass", "I", inertia="m")
    b.bond("v", "mass")
    model = b.build()              # the frozen bgc.format.parse.Model
    text = b.to_yaml()             # the same model as YAML text

Every call records what the user wrote and where: the calling line of the user's file (the
first frame outside bgc). ``build()`` turns the record into YAML nodes that carry those places
and hands them to the reader's own validation (bgc.format.parse.parse_root): every check and
every message is the reader's, and an error reads ``file.py:LINE:COL: message`` at the call
that made the mistake. Nothing here checks a name or an expression itself, and nothing is
evaluated: values are numbers, text or (nested) lists of those, as in a YAML file.
"""
from __future__ import annotations

import hashlib
import os
import sys
from pathlib import Path

import yaml

from bgc.base.errors import Coord, ModelError
from bgc.format.parse import Model, parse_root
from bgc.format.reader import Reader

_PKG = str(Path(__file__).resolve().parent) + os.sep
_STR, _INT, _FLOAT, _BOOL, _NULL = (f"tag:yaml.org,2002:{t}" for t in
                                    ("str", "int", "float", "bool", "null"))
_MAP, _SEQ = "tag:yaml.org,2002:map", "tag:yaml.org,2002:seq"


def _caller() -> Coord:
    """The place of the user's call: the first frame whose file is not bgc's own."""
    frame = sys._getframe(1)
    while frame is not None and str(Path(frame.f_code.co_filename).resolve()).startswith(_PKG):
        frame = frame.f_back
    if frame is None:  # pragma: no cover - bgc calling itself
        return Coord("<builder>", 1, 1)
    col = 1
    try:
        positions = list(frame.f_code.co_positions())
        pos = positions[frame.f_lasti // 2]
        if pos[0] == frame.f_lineno and pos[2] is not None:
            col = pos[2] + 1
    except (AttributeError, IndexError):  # Python 3.10: no column
        pass
    return Coord(frame.f_code.co_filename, frame.f_lineno, col)


class _Entry:
    """One item the user added: its key, its value (plain data) and the place of the call."""

    __slots__ = ("key", "value", "coord")

    def __init__(self, key, value, coord: Coord):
        self.key, self.value, self.coord = key, value, coord


def _options(**kw) -> dict:
    """The keyword arguments that were given (None means: not given)."""
    return {k: v for k, v in kw.items() if v is not None}


class _Body:
    """What a model and a component both hold: parameters, elements, bonds, states."""

    def __init__(self, coord: Coord):
        self._coord = coord
        self._sections: dict[str, list[_Entry]] = {}

    def _add(self, section: str, key, value) -> None:
        self._sections.setdefault(section, []).append(_Entry(key, value, _caller()))

    def parameter(self, name, value, *, unit=None, min=None, max=None,  # noqa: A002
                  description=None, free=None):
        """A parameter: a number, a matrix (nested lists) or an expression of other
        parameters (text: a derived parameter), with its unit, bounds and description."""
        opts = _options(unit=unit, min=min, max=max, description=description, free=free)
        self._add("parameters", name, {"value": value, **opts} if opts else value)
        return self

    def element(self, name, type, **keys):  # noqa: A002
        """An element by its type (``"I"``, ``"C"``, ``"R"``, ``"0"``, ...) with its law keys
        (``inertia="m"``, ``initial=...``, ``effects=[...]``), or an instance of a component
        (``type`` the component's name, the keys its parameters' values)."""
        self._add("elements", name, {"type": type, **keys})
        return self

    def bond(self, src, dst, *, n=None, name=None) -> str:
        """A bond from ``src`` to ``dst`` (an element, or ``"instance.port"``); ``n``: its
        cardinality (a multibond). Returns its name (``b<i>`` when not given one)."""
        opts = _options(n=n, name=name)
        value = {"from": src, "to": dst, **opts} if opts else [src, dst]
        self._add("bonds", None, value)
        return name if name is not None else f"b{len(self._sections['bonds'])}"

    def state(self, name, derivative, *, initial=None, shape=None, unit=None,
              description=None, effects=None):
        """An auxiliary state: its derivative, initial value, shape and unit."""
        self._add("states", name, {"derivative": derivative, **_options(
            initial=initial, shape=shape, unit=unit, description=description,
            effects=effects)})
        return self

    # -- what both writers read ----------------------------------------------------------

    def _data(self) -> dict:
        out: dict = {}
        for section, entries in self._sections.items():
            if section in ("bonds", "imports"):
                out[section] = [e.value for e in entries]
            else:
                out[section] = {e.key: e.value for e in entries}  # duplicates: the last
        return out

    def _nodes(self, head: list) -> yaml.MappingNode:
        pairs = list(head)
        for section, entries in self._sections.items():
            first = entries[0].coord
            if section in ("bonds", "imports"):
                value = yaml.SequenceNode(_SEQ, [_node(e.value, e.coord) for e in entries],
                                          *_marks(first))
            else:  # every entry, duplicates too: the reader names the second one
                value = yaml.MappingNode(_MAP, [(_node(e.key, e.coord), _node(e.value, e.coord))
                                                for e in entries], *_marks(first))
            pairs.append((_node(section, first), value))
        return yaml.MappingNode(_MAP, pairs, *_marks(self._coord))


class Component(_Body):
    """A component defined once and instantiated many times: its parameters, elements, bonds,
    states and ports (``ports={"a": "element"}``). Add it to a model with
    :meth:`Builder.component`."""

    def __init__(self, ports=None, *, description=None):
        super().__init__(_caller())
        self._ports = dict(ports or {})
        self._description = description

    def port(self, name, element):
        """A port of the component: the element it connects to."""
        self._ports[name] = element
        return self

    def _head(self) -> dict:
        return _options(description=self._description)

    def _as_data(self) -> dict:
        out = {**self._head(), **self._data(), "ports": dict(self._ports)}
        out.setdefault("elements", {})
        out.setdefault("bonds", [])
        return out

    def _as_node(self) -> yaml.MappingNode:
        c = self._coord
        head = [(_node(k, c), _node(v, c)) for k, v in self._head().items()]
        head.append((_node("ports", c), _node(dict(self._ports), c)))
        for section, empty in (("elements", {}), ("bonds", [])):
            if section not in self._sections:
                head.append((_node(section, c), _node(empty, c)))
        return self._nodes(head)


class Builder(_Body):
    """A model built from Python. ``units``: ``"strict"`` or ``"check"`` (the model's
    ``units:`` key); ``causality``: ``"strict"`` or ``"eliminate"``."""

    def __init__(self, name, *, description=None, units=None, causality=None):
        super().__init__(_caller())
        self._head_values = {"bgc": 1, "name": name, **_options(
            description=description, units=units, causality=causality)}
        self._components: list[tuple[str, Component, Coord]] = []

    def input(self, name, default=None, *, shape=None, unit=None, description=None, **table):
        """An input signal: its default expression (``default``), shape and unit; or a table
        of data (``table="road.csv", columns=[...]``, as in YAML)."""
        if table:
            value = {**table, **_options(unit=unit, description=description)}
        else:
            opts = _options(shape=shape, unit=unit, description=description)
            value = {"default": default, **opts} if opts else default
        self._add("inputs", name, value)
        return self

    def output(self, name, expr, *, unit=None):
        """An output: an expression of efforts, flows, states, parameters, inputs and t."""
        self._add("outputs", name, {"expr": expr, "unit": unit} if unit is not None else expr)
        return self

    def mode(self, name, initial, *, description=None):
        """A discrete mode variable (``modes:``): its initial value, changed only by events."""
        opts = _options(description=description)
        self._add("modes", name, {"initial": initial, **opts} if opts else initial)
        return self

    def event(self, name, **keys):
        """An event (``events:``), its keys as in YAML: ``when=``, ``direction=``,
        ``do={"p(ball)": "-e_r*p(ball)"}``, ... (docs/model-format.md, Events)."""
        self._add("events", name, dict(keys))
        return self

    def imports(self, file=None, **keys):
        """The components of another model file (``file=`` a path relative to the calling
        file's folder, as an import is relative to its model file), or any other import the
        reader accepts (its keys as in YAML)."""
        self._add("imports", None, {**_options(file=file), **keys})
        return self

    def component(self, name, component: Component):
        """Define a component (a :class:`Component`) under ``name`` in this model."""
        if not isinstance(component, Component):
            raise TypeError(f"a component is a bgc.builder.Component, not "
                            f"{type(component).__name__}")
        self._components.append((name, component, _caller()))
        return self

    @property
    def file(self) -> str:
        """The Python file that created the builder (relative imports start from its folder)."""
        return self._coord.file

    def to_yaml(self) -> str:
        """The model as YAML text that the reader accepts (the same model as :meth:`build`,
        but for the places). A value that is not data is a located error, as in build()."""
        self._root()
        data = dict(self._head_values)
        order = ("parameters", "inputs", "imports", "modes")
        body = self._data()
        for key in order:
            if key in body:
                data[key] = body.pop(key)
        if self._components:
            data["components"] = {n: c._as_data() for n, c, _ in self._components}
        data.setdefault("elements", {})
        data.setdefault("bonds", [])
        data.update(body)
        return yaml.safe_dump(_plain(data), sort_keys=False, default_flow_style=None, width=100,
                              allow_unicode=True)

    def build(self) -> Model:
        """The validated, frozen model: the reader's checks and messages, at the places of
        the calls that made each part. Raises a located :class:`bgc.BgcError`."""
        root = self._root()
        digest = hashlib.sha256(self.to_yaml().encode()).hexdigest()[:16]
        return parse_root(Reader(self._coord.file, ""), root, digest)

    def _root(self) -> yaml.MappingNode:
        """The model as the YAML node tree the reader would compose, each node placed at the
        call that made it."""
        c = self._coord
        head = [(_node(k, c), _node(v, c)) for k, v in self._head_values.items()]
        if self._components:
            first = self._components[0][2]
            comps = yaml.MappingNode(_MAP, [(_node(n, cc), comp._as_node())
                                            for n, comp, cc in self._components],
                                     *_marks(first))
            head.append((_node("components", first), comps))
        for section, empty in (("elements", {}), ("bonds", [])):
            if section not in self._sections:
                head.append((_node(section, c), _node(empty, c)))
        return self._nodes(head)


def _marks(coord: Coord):
    mark = yaml.Mark(coord.file, 0, coord.line - 1, coord.column - 1, None, None)
    return mark, mark


def _node(value, coord: Coord):
    """Plain Python data as the YAML node the reader would have composed, placed at coord."""
    start, end = _marks(coord)
    if isinstance(value, dict):
        return yaml.MappingNode(_MAP, [(_node(k, coord), _node(v, coord))
                                       for k, v in value.items()], start, end)
    if isinstance(value, (list, tuple)):
        return yaml.SequenceNode(_SEQ, [_node(v, coord) for v in value], start, end)
    if isinstance(value, bool):
        return yaml.ScalarNode(_BOOL, "true" if value else "false", start, end)
    if value is None:
        return yaml.ScalarNode(_NULL, "null", start, end)
    if isinstance(value, int):
        return yaml.ScalarNode(_INT, str(value), start, end)
    if isinstance(value, float):  # (numpy's float64 too: its own repr is not YAML's)
        return yaml.ScalarNode(_FLOAT, repr(float(value)), start, end)
    if isinstance(value, str):
        return yaml.ScalarNode(_STR, value, start, end)
    if hasattr(value, "tolist"):  # a numpy array or scalar: its numbers
        return _node(value.tolist(), coord)
    raise ModelError(coord, f"a value of type {type(value).__name__} cannot be part of a "
                            "model (numbers, text, lists and dicts of those)")


def _plain(value):
    """Data the YAML writer takes: tuples as lists, numpy values as numbers."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if hasattr(value, "tolist") and not isinstance(value, (str, bytes)):
        return _plain(value.tolist())
    if isinstance(value, float):
        return float(value)
    if isinstance(value, int) and not isinstance(value, bool):
        return int(value)
    return value


def as_model(src):
    """A builder's model, or ``src`` itself (bgc.api takes either)."""
    return src.build() if isinstance(src, Builder) else src
