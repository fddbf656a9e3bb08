"""Dimension variables and names for the dimensional analysis of a flat bond graph.

:class:`Checker` holds the :class:`~bgc.core.dimsys.System` of one graph, the forms of its
parameters, inputs and states (a declared unit is a fact, else an unknown), and the forms of
component parameters bound at instances; :class:`_Names` tells bgc.core.dimexpr what a name
means in a scope. The laws that use them are bgc.core.units'.
"""
from __future__ import annotations

from bgc.base.errors import Coord, ModelError
from bgc.core.dimexpr import SECOND, DimEval, is_number
from bgc.core.dimsys import Form, System
from bgc.format.units import UnitError, parse_unit
from bgc.format.whitelist import Expr, short_text


def unit_of(text: str, coord: Coord, who: str) -> Form | None:
    """The declared unit of ``who`` as a form (None when there is none); a located error when
    bgc cannot read it."""
    if not text:
        return None
    try:
        return Form.of(parse_unit(text)[1])
    except UnitError as exc:
        raise ModelError(coord, f"{who}: unit {short_text(text)}: {exc}") from None


def _join(prefix: tuple[str, ...], name: str) -> str:
    return ".".join(prefix + (name,))


class Checker:
    """The dimension variables of one bond graph and the names its expressions use."""

    def __init__(self, bg):
        self.bg = bg
        self.sys = System()
        self.params: dict[str, Form] = {}
        for fp in bg.params:
            declared = unit_of(fp.unit, fp.coord, f"parameter {fp.id!r}")
            self.params[fp.id] = declared or Form.var(("param", fp.id))
        self.inputs = {i.name: unit_of(i.unit, i.coord, f"input {i.name!r}")
                       or Form.var(("input", i.name)) for i in bg.model.inputs}
        self.states = {s.id: unit_of(s.unit, s.coord, f"state {s.id!r}")
                       or Form.var(("state", s.id)) for s in bg.states}
        self.bindings: dict = {}  # (scope, name) -> Form of the instance's expression
        self.comp_units: dict = {}  # (component, param) -> (unit text, coord)
        for comp in bg.model.components:
            for p in comp.body.params:
                if p.unit:
                    self.comp_units[(comp.name, p.name)] = (p.unit, p.coord)

    def e(self, bid: str) -> Form:
        return Form.var(("e", bid))

    def f(self, bid: str) -> Form:
        return Form.var(("f", bid))

    def eval(self, expr: Expr, scope: tuple[str, ...], what: str, local: dict | None = None):
        return DimEval(self.sys, _Names(self, scope, local or {}), expr, what).run()

    def equate(self, a, b, coord: Coord, message) -> None:
        self.sys.equate(a, b, coord, message)

    def binding(self, scope: tuple[str, ...], name: str, binding) -> Form | None:
        key = (scope, name)
        if key not in self.bindings:
            self.bindings[key] = Form.var(self.sys.new_var(_join(scope, name)))  # (a cycle)
            comp = self.bg.scopes[scope].component
            who = f"instance {'.'.join(scope)!r}: parameter {name!r}"
            got = (self.bindings[key] if is_number(binding.target.tree())  # a value: in the
                   else self.eval(binding.target, binding.scope, who))  # parameter's unit
            self.bindings[key] = got
            if (comp, name) in self.comp_units:
                text, coord = self.comp_units[(comp, name)]
                want = unit_of(text, coord, f"component {comp!r}: parameter {name!r}")
                self.equate(want, got, binding.target.coord,
                            lambda w, g: f"{who}: component {comp!r} declares {text}, "
                                         f"but {short_text(binding.target.text)} is {g}")
        return self.bindings[key]


class _Names:
    """What a name means in one scope, for dimensions: like bgc.core.context's resolver, but
    a name it cannot resolve is an unknown (the equations' stage reports it)."""

    def __init__(self, chk: Checker, scope, local):
        self.chk, self.scope, self.local = chk, scope, local

    def fresh(self, path) -> Form:
        return Form.var(self.chk.sys.new_var(".".join(path)))

    def find(self, path, scope=None):
        scope = self.scope if scope is None else scope
        sc = self.chk.bg.scopes.get(scope)
        kind = sc.names.get(path[0]) if sc is not None else None
        if kind is None and scope == () and path[0] in self.chk.inputs:
            kind = "input"
        if kind == "instance" and len(path) > 1:
            return self.find(path[1:], scope + (path[0],))
        if kind is None or len(path) != 1:
            return None
        return kind, path[0], scope

    def value(self, path) -> Form:
        if len(path) == 1 and path[0] in self.local:
            return self.local[path[0]]
        if path == ("t",):
            return SECOND
        found = self.find(path)
        if found is None:
            return self.fresh(path)
        kind, name, scope = found
        if kind == "param":
            binding = self.chk.bg.scopes[scope].bindings.get(name)
            if binding is not None and binding.kind == "expr":
                return self.chk.binding(scope, name, binding)
            pid = binding.target if binding is not None else _join(scope, name)
            return self.chk.params.get(pid) or self.fresh(path)
        if kind == "state":
            return self.chk.states.get(_join(scope, name)) or self.fresh(path)
        if kind == "input":
            return self.chk.inputs[name]
        return self.fresh(path)

    def bond(self, func, path) -> Form:
        found = self.find(path)
        if found is None or found[0] not in ("bond", "element"):
            return self.fresh(path)
        kind, name, scope = found
        ident = _join(scope, name)
        bg, chk = self.chk.bg, self.chk
        if kind == "bond":
            bid = ident
            if func in ("p", "q"):
                return self.fresh(path)
        else:
            el = bg.element(ident)
            bonds = bg.bonds_of(ident)
            if not bonds or len(bonds) > 1 and el.type not in ("0", "1"):
                return self.fresh(path)
            bid = bonds[0].id
            if func in ("p", "q"):
                if el.type != {"p": "I", "q": "C"}[func]:
                    return self.fresh(path)
                return (chk.e(bid) if func == "p" else chk.f(bid)) + SECOND
        if func == "e":
            return chk.e(bid)
        if func == "f":
            return chk.f(bid)
        return chk.e(bid) + chk.f(bid)
