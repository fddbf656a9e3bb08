"""Symbols and name resolution for one bond graph, while its state equations are derived.

:class:`Context` gives every bond its effort and flow symbols, every parameter its symbol (or
its folded value), every input its symbols and default; :class:`NameResolver` tells the
expression builder (bgc.format.expr.build) what a name in a law means in its component's
scope. ``check_names`` refuses generated identifiers that would collide.
"""
from __future__ import annotations

import sympy as sp

from bgc.base.errors import Coord, ModelError
from bgc.core.causality import Causality
from bgc.core.eqtypes import (
    Assignment,
    InputVar,
    ParamVar,
    StateVar,
    T,
    flat,
    real_symbol,
    shape_name,
    symbol_array,
    symbol_vector,
)
from bgc.core.graph import BondGraph, a_kind, code_name, join
from bgc.format.arith import summed, times
from bgc.format.expr import Expr, build, shape_of
from bgc.format.parse import TWO_PORTS


class Context:
    """Symbols and name resolution for one bond graph."""

    def __init__(self, bg: BondGraph, caus: Causality, fold: dict | None = None,
                 zero: dict | None = None):
        self.bg = bg
        self.caus = caus
        self.zero = zero or {}  # removed element id -> cardinality: its variables read zero
        fold = fold or {}
        self.e = {b.id: symbol_vector("e_" + code_name(b.id), b.n) for b in bg.bonds}
        self.f = {b.id: symbol_vector("f_" + code_name(b.id), b.n) for b in bg.bonds}
        self.params: dict[str, ParamVar] = {}
        self.param_value: dict[str, object] = {}
        self.derived: dict[str, Assignment] = {}
        self.derived_order: list[str] = []
        self.building: set[str] = set()
        for fp in bg.params:
            code = code_name(fp.id)
            if isinstance(fp.value, Expr):
                continue
            if fp.id in fold:  # fixed by the scene: a number, not a parameter
                self.param_value[fp.id] = _fold_value(fold[fp.id])
                continue
            if isinstance(fp.value, tuple):
                # A list stays a matrix even with one entry ([2.0] is 1x1, not a scalar): the
                # law that uses it checks its shape.
                rows, cols = len(fp.value), len(fp.value[0])
                shape = (rows,) if cols == 1 else (rows, cols)
                val = symbol_array(code, shape)
            else:
                shape, val = (), real_symbol(code)
            self.params[fp.id] = ParamVar(fp.id, code, fp.value, tuple(flat(val)), shape,
                                          fp.unit, fp.description)
            self.param_value[fp.id] = val
        self.flat_params = {fp.id: fp for fp in bg.params}
        self.states: dict[str, object] = {}  # element/state id -> sympy symbol(s)
        self.state_vars: list[StateVar] = []
        self.inputs: dict[str, InputVar] = {}
        self.cache: dict = {}
        self.dependent: list = []  # (element id, state symbols, their dt_ symbols)
        self.constraints: list = []  # bgc.core.constraints.Constraint
        self.redundant: list = []  # (constraint source, component): dropped, reaction 0

    # -- parameters -------------------------------------------------------------------------
    def param(self, pid: str, coord: Coord):
        if pid in self.param_value:
            return self.param_value[pid]
        fp = self.flat_params[pid]
        if pid in self.building:
            raise ModelError(fp.coord, f"parameter {pid!r} is defined in terms of itself")
        self.building.add(pid)
        val = self.build(fp.value, fp.scope, f"parameter {pid!r}", params_only=True)
        self.building.discard(pid)
        code = code_name(pid)
        if shape_of(val):
            syms = symbol_array(code, shape_of(val) if val.shape[1] != 1 else (val.shape[0],))
            for s, v in zip(flat(syms), flat(val)):
                self.derived[str(s)] = Assignment(s, v, f"derived parameter {pid}")
                self.derived_order.append(str(s))
        else:
            syms = real_symbol(code)
            self.derived[code] = Assignment(syms, val, f"derived parameter {pid}")
            self.derived_order.append(code)
        self.param_value[pid] = syms
        return syms

    # -- expressions ------------------------------------------------------------------------
    def build(self, expr: Expr, scope: tuple[str, ...], what: str, local: dict | None = None,
              params_only: bool = False, allow_bonds: bool = True):
        res = NameResolver(self, scope, local or {}, params_only, allow_bonds, what)
        return build(expr, res)


class NameResolver:
    def __init__(self, ctx: Context, scope, local, params_only, allow_bonds, what):
        self.ctx, self.scope, self.local = ctx, scope, local
        self.params_only, self.allow_bonds, self.what = params_only, allow_bonds, what

    def _find(self, path, coord, scope=None):
        """Resolve a dotted path to (kind, id, scope)."""
        scope = self.scope if scope is None else scope
        sc = self.ctx.bg.scopes[scope]
        head = path[0]
        kind = sc.names.get(head)
        if kind is None:
            if scope == () and head in {i.name for i in self.ctx.bg.model.inputs}:
                kind = "input"
            else:
                where = f" in component {sc.component!r}" if sc.component else ""
                raise ModelError(coord, f"{self.what}: undefined name {'.'.join(path)!r}{where}")
        if kind == "instance":
            if len(path) == 1:
                raise ModelError(coord, f"{self.what}: {head!r} is a component instance, not a "
                                        "value" + self._elements_hint(scope + (head,)))
            return self._find(path[1:], coord, scope + (head,))
        if len(path) != 1:
            raise ModelError(coord, f"{self.what}: {head!r} is {a_kind(kind)}: it has no "
                                    f"{path[1]!r}")
        return kind, head, scope

    def _elements_hint(self, scope) -> str:
        """Inside a component instance: the elements it has (what e(), f(), p(), q() take)."""
        if not scope:
            return ""
        names = sorted(k for k, v in self.ctx.bg.scopes[scope].names.items() if v == "element")
        return (f" (the elements of {'.'.join(scope)!r}: {', '.join(names)}; `bgc library` "
                "lists a library component's)") if names else ""

    def value(self, path, coord):
        if len(path) == 1 and path[0] in self.local:
            return self.local[path[0]]
        if len(path) == 1 and path[0] == "t":
            if self.params_only:
                raise ModelError(coord, f"{self.what}: may only use parameters, not t")
            return T
        kind, name, scope = self._find(path, coord)
        if kind == "param":
            binding = self.ctx.bg.scopes[scope].bindings.get(name)
            if binding is not None and binding.kind == "expr":
                key = ("bind", scope, name)
                if key not in self.ctx.cache:
                    self.ctx.cache[key] = self.ctx.build(binding.target, binding.scope,
                                                         f"{join(scope, name)}",
                                                         params_only=self.params_only)
                return self.ctx.cache[key]
            pid = binding.target if binding is not None else join(scope, name)
            return self.ctx.param(pid, coord)
        if self.params_only:
            raise ModelError(coord, f"{self.what}: may only use parameters, and "
                                    f"{'.'.join(path)!r} is {a_kind(kind)}")
        if kind == "state":
            sid = join(scope, name)
            if sid not in self.ctx.states:
                raise ModelError(coord, f"{self.what}: state {sid!r} is removed by the scene "
                                        "(its effect is off) but is used here")
            return self.ctx.states[sid]
        if kind == "input":
            return self.ctx.inputs_value(name, coord)
        if kind == "element":
            raise ModelError(coord, f"{self.what}: {'.'.join(path)!r} is an element: use e(), "
                                    "f(), p() or q() to read its variables")
        raise ModelError(coord, f"{self.what}: {'.'.join(path)!r} is {a_kind(kind)}, "
                                "not a value")

    def bond(self, func, path, coord):
        if self.params_only or not self.allow_bonds:
            raise ModelError(coord, f"{self.what}: {func}() is not allowed here")
        kind, name, scope = self._find(path, coord)
        ident = join(scope, name)
        bg, ctx = self.ctx.bg, self.ctx
        if ident in ctx.zero:  # removed by the scene: contributes nothing
            return sp.Integer(0) if func == "power" else zero_value(ctx.zero[ident])
        if kind == "bond":
            b = bg.bond(ident)
            e, f = ctx.e[b.id], ctx.f[b.id]
            if func in ("p", "q"):
                raise ModelError(coord, f"{self.what}: {func}() takes an "
                                        f"{'I' if func == 'p' else 'C'} element, not a bond")
        elif kind == "element":
            el = bg.element(ident)
            if func in ("p", "q"):
                want = "I" if func == "p" else "C"
                if el.type != want:
                    an = lambda t: "an" if t in ("I", "R", "Se", "Sf", "MTF", "MGY") else "a"  # noqa: E731
                    raise ModelError(coord, f"{self.what}: {func}() takes {an(want)} {want} "
                                            f"element, {ident!r} is {an(el.type)} {el.type}")
                return ctx.states[ident]
            bonds = bg.bonds_of(ident)
            if el.type == "0":
                if func in ("f", "power"):
                    raise ModelError(coord, f"{self.what}: a 0-junction has one effort but no "
                                            f"single flow: use {func}() of one of its bonds")
                return ctx.e[bonds[0].id]
            if el.type == "1":
                if func in ("e", "power"):
                    raise ModelError(coord, f"{self.what}: a 1-junction has one flow but no "
                                            f"single effort: use {func}() of one of its bonds")
                return ctx.f[bonds[0].id]
            if el.type in TWO_PORTS:
                raise ModelError(coord, f"{self.what}: {ident!r} has two bonds: name the bond")
            e, f = ctx.e[bonds[0].id], ctx.f[bonds[0].id]
        else:
            raise ModelError(coord, f"{self.what}: {func}() takes a bond, element or junction; "
                                    f"{'.'.join(path)!r} is {a_kind(kind)}"
                                    + self._elements_hint(scope))
        if func == "e":
            return e
        if func == "f":
            return f
        return summed(times(a, b) for a, b in zip(flat(e), flat(f)))


def _inputs_value(self: Context, name: str, coord: Coord):
    if name not in self.inputs:
        inp = next(i for i in self.bg.model.inputs if i.name == name)
        syms = symbol_array("u_" + name, inp.shape)
        res = NameResolver(self, (), {}, False, False, f"input {name!r}")
        self.inputs[name] = None  # guard against self reference
        default = build(inp.default, res)
        _default_uses_only_params(self, name, inp, default)
        if shape_of(default) != shape_of(syms):
            raise ModelError(inp.default.coord, f"input {name!r}: default has shape "
                                                f"{shape_name(shape_of(default))}, declared "
                                                f"{shape_name(shape_of(syms))}")
        self.inputs[name] = InputVar(name, tuple(flat(syms)), inp.shape, tuple(flat(default)),
                                     getattr(inp, "table", None))
        self.cache[("input", name)] = syms
    elif self.inputs[name] is None:
        raise ModelError(coord, f"input {name!r} refers to itself")
    return self.cache[("input", name)]


def _default_uses_only_params(self: Context, name: str, inp, default) -> None:
    """An input's default is a signal of t and the parameters: a state or another input in it
    has no value where the module evaluates the inputs (before the right-hand side)."""
    used = set().union(*(d.free_symbols for d in flat(default)))
    if not used:
        return
    found = [(sid, "a state") for sid, v in self.states.items() if used & set(flat(v))]
    found += [(other, "an input") for other, iv in self.inputs.items()
              if iv is not None and used & set(iv.symbols)]
    if found:
        what, kind = found[0]
        raise ModelError(inp.default.coord, f"input {name!r}: its default may use only t and "
                                            f"parameters, and {what!r} is {kind}")


Context.inputs_value = _inputs_value


def zero_value(n):
    return sp.Integer(0) if n == 1 else sp.ImmutableMatrix(sp.zeros(n, 1))


def _fold_value(v):
    if isinstance(v, tuple):
        return sp.ImmutableMatrix([[sp.Float(c) for c in row] for row in v])
    return sp.Float(v)


def _text(s) -> str:
    """``str(s)``; a plain symbol's name read directly (sympy's printer per symbol was most of
    this check on a large model)."""
    return s.name if type(s) is sp.Symbol else str(s)


def check_names(bg: BondGraph, ctx: Context, state_vars) -> None:
    """Generated identifiers must not collide (e.g. a parameter named like a bond variable):
    the error is placed at the user's name (a parameter or input is what can be renamed)."""
    pcoord = {fp.id: fp.coord for fp in bg.params}
    icoord = {i.name: i.coord for i in getattr(bg.model, "inputs", ())}
    seen: dict[str, str] = {}
    pairs = []  # (identifier, who, coord of the declaration or None)
    for pv in ctx.params.values():
        pairs += [(_text(s), f"parameter {pv.id!r}", pcoord.get(pv.id)) for s in pv.symbols]
    for k in ctx.derived:
        pairs.append((k, "derived parameter", pcoord.get(k)))
    for sv in state_vars:
        pairs.append((_text(sv.symbol), f"state {sv.name!r}", None))
    for b in bg.bonds:
        pairs += [(_text(s), f"bond {b.id!r}", None) for s in flat(ctx.e[b.id]) + flat(ctx.f[b.id])]
    for iv in ctx.inputs.values():
        pairs += [(_text(s), f"input {iv.name!r}", icoord.get(iv.name)) for s in iv.symbols]
    where: dict[str, object] = {}
    for ident, who, coord in pairs:
        if ident in seen and seen[ident] != who:
            at = where.get(ident) or coord or bg.model.coord  # the parameter, if one
            raise ModelError(at, f"name clash in generated code: {who} and "
                                 f"{seen[ident]} both become {ident!r}; rename one")
        seen[ident] = who
        if coord is not None:
            where[ident] = coord
