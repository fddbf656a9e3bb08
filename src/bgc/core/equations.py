"""Stage 4: causal bond graph -> state equations with sympy.

Every bond carries an effort and a flow symbol per component (``e_b3``, ``f_link1__b7_2``). The
element that causality makes responsible for a variable defines it by one assignment; the
assignments are sorted into causal order (algebraic loops, found as strongly connected
components, are solved symbolically when linear). Plain copies across junctions are inlined,
everything else stays an assignment, so expressions never swell. The Jacobian is derived in
forward mode along the same assignments (chain rule), never by differentiating an expanded
right-hand side. No ``simplify`` anywhere.
"""
from __future__ import annotations

import heapq
import itertools
from dataclasses import dataclass, field
from dataclasses import replace as dc_replace

import networkx as nx
import sympy as sp

from bgc.base.errors import Coord, ModelError
from bgc.core import fastsym
from bgc.core.causality import Causality
from bgc.core.graph import BondGraph, FlatElement, a_kind, code_name, join
from bgc.format.expr import Expr, build, shape_of
from bgc.format.parse import TWO_PORTS

T = sp.Symbol("t", real=True)
# Linear systems from derivative causality up to this size are solved symbolically (Cramer-like
# LU on symbols for the matrix entries); larger ones by a numeric solve in the generated code.
SYMBOLIC_MAX = 4


def _sym(name: str) -> sp.Symbol:
    return sp.Symbol(name, real=True)


def _vec(prefix: str, n: int):
    if n == 1:
        return _sym(prefix)
    return sp.ImmutableMatrix(n, 1, [_sym(f"{prefix}_{i}") for i in range(n)])


def _mat_syms(prefix: str, shape: tuple[int, ...]):
    if not shape:
        return _sym(prefix)
    if len(shape) == 1:
        return sp.ImmutableMatrix(shape[0], 1, [_sym(f"{prefix}_{i}") for i in range(shape[0])])
    r, c = shape
    return sp.ImmutableMatrix(r, c, [_sym(f"{prefix}_{i}_{j}") for i in range(r) for j in range(c)])


def flat(v) -> list:
    return list(v) if isinstance(v, sp.MatrixBase) else [v]


def _shape_name(shape):
    return "scalar" if not shape else "x".join(map(str, shape))


@dataclass(frozen=True)
class StateVar:
    name: str  # as shown in STATE_NAMES
    symbol: sp.Symbol
    owner: str  # element or state id
    initial: object  # sympy expression of parameters


@dataclass(frozen=True)
class ParamVar:
    id: str  # dotted name (PARAM_DEFAULTS key)
    code: str
    value: object  # float or tuple of tuples
    symbols: tuple  # flat symbols (matrix entries)
    shape: tuple[int, ...]
    unit: str = ""
    description: str = ""


@dataclass(frozen=True)
class InputVar:
    name: str
    symbols: tuple
    shape: tuple[int, ...]
    default: tuple  # flat sympy expressions of t and parameters
    table: object = None  # a bgc.format.tables.Table: the input is data (emit evaluates it)


@dataclass(frozen=True)
class Assignment:
    symbol: sp.Symbol
    expr: object
    why: str  # a comment for the generated code


@dataclass(frozen=True)
class Equations:
    name: str
    states: tuple[StateVar, ...]
    params: tuple[ParamVar, ...]
    derived: tuple[Assignment, ...]  # derived parameters, in dependency order
    inputs: tuple[InputVar, ...]
    assignments: tuple[Assignment, ...]  # intermediate efforts and flows, causal order
    derivatives: tuple  # one expression per state
    outputs: tuple[tuple[str, tuple[int, ...], tuple], ...]  # name, shape, flat exprs
    jacobian: dict  # (i, j) -> expression (nonzero entries only)
    jac_assignments: tuple[Assignment, ...]  # forward-mode derivative intermediates
    loops: tuple[str, ...]  # descriptions of the algebraic loops solved
    notes: tuple[str, ...] = field(default=())
    # storage elements in derivative causality: (element id, the state names it follows from)
    dependent: tuple = field(default=())
    newton: tuple = field(default=())  # NewtonLoop: nonlinear algebraic loops
    #: causality's warnings that the equations leave standing: SCAP's arbitrary choice of an R's
    #: form is no longer a "possible algebraic loop" once the equations are derived (any loop
    #: was found and solved, and is listed in ``loops``; or there was none)
    warnings: tuple[str, ...] = field(default=())


class _Ctx:
    """Symbols and name resolution for one bond graph."""

    def __init__(self, bg: BondGraph, caus: Causality, fold: dict | None = None,
                 zero: dict | None = None):
        self.bg = bg
        self.caus = caus
        self.zero = zero or {}  # removed element id -> cardinality: its variables read zero
        fold = fold or {}
        self.e = {b.id: _vec("e_" + code_name(b.id), b.n) for b in bg.bonds}
        self.f = {b.id: _vec("f_" + code_name(b.id), b.n) for b in bg.bonds}
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
                val = _mat_syms(code, shape)
            else:
                shape, val = (), _sym(code)
            self.params[fp.id] = ParamVar(fp.id, code, fp.value, tuple(flat(val)), shape,
                                          fp.unit, fp.description)
            self.param_value[fp.id] = val
        self.flat_params = {fp.id: fp for fp in bg.params}
        self.states: dict[str, object] = {}  # element/state id -> sympy symbol(s)
        self.state_vars: list[StateVar] = []
        self.inputs: dict[str, InputVar] = {}
        self.cache: dict = {}
        self.dependent: list = []  # (element id, state symbols, their dt_ symbols)

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
            syms = _mat_syms(code, shape_of(val) if val.shape[1] != 1 else (val.shape[0],))
            for s, v in zip(flat(syms), flat(val)):
                self.derived[str(s)] = Assignment(s, v, f"derived parameter {pid}")
                self.derived_order.append(str(s))
        else:
            syms = _sym(code)
            self.derived[code] = Assignment(syms, val, f"derived parameter {pid}")
            self.derived_order.append(code)
        self.param_value[pid] = syms
        return syms

    # -- expressions ------------------------------------------------------------------------
    def build(self, expr: Expr, scope: tuple[str, ...], what: str, local: dict | None = None,
              params_only: bool = False, allow_bonds: bool = True):
        res = _Resolver(self, scope, local or {}, params_only, allow_bonds, what)
        return build(expr, res)


class _Resolver:
    def __init__(self, ctx: _Ctx, scope, local, params_only, allow_bonds, what):
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
                                        "value")
            return self._find(path[1:], coord, scope + (head,))
        if len(path) != 1:
            raise ModelError(coord, f"{self.what}: {head!r} is {a_kind(kind)}: it has no "
                                    f"{path[1]!r}")
        return kind, head, scope

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
            return sp.Integer(0) if func == "power" else _zeros(ctx.zero[ident])
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
                                    f"{'.'.join(path)!r} is {a_kind(kind)}")
        if func == "e":
            return e
        if func == "f":
            return f
        return sum((a * b for a, b in zip(flat(e), flat(f))), sp.Integer(0))


def _inputs_value(self: _Ctx, name: str, coord: Coord):
    if name not in self.inputs:
        inp = next(i for i in self.bg.model.inputs if i.name == name)
        syms = _mat_syms("u_" + name, inp.shape)
        res = _Resolver(self, (), {}, False, False, f"input {name!r}")
        self.inputs[name] = None  # guard against self reference
        default = build(inp.default, res)
        _default_uses_only_params(self, name, inp, default)
        if shape_of(default) != shape_of(syms):
            raise ModelError(inp.default.coord, f"input {name!r}: default has shape "
                                                f"{_shape_name(shape_of(default))}, declared "
                                                f"{_shape_name(shape_of(syms))}")
        self.inputs[name] = InputVar(name, tuple(flat(syms)), inp.shape, tuple(flat(default)),
                                     getattr(inp, "table", None))
        self.cache[("input", name)] = syms
    elif self.inputs[name] is None:
        raise ModelError(coord, f"input {name!r} refers to itself")
    return self.cache[("input", name)]


def _default_uses_only_params(self: _Ctx, name: str, inp, default) -> None:
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


_Ctx.inputs_value = _inputs_value


# ---------------------------------------------------------------------------------------------


def _zeros(n):
    return sp.Integer(0) if n == 1 else sp.ImmutableMatrix(sp.zeros(n, 1))


def _fold_value(v):
    if isinstance(v, tuple):
        return sp.ImmutableMatrix([[sp.Float(c) for c in row] for row in v])
    return sp.Float(v)


def derive(bg: BondGraph, caus: Causality, progress=None, fold: dict | None = None,
           zero: dict | None = None, symbolic_max: int = SYMBOLIC_MAX,
           newton: bool = True) -> Equations:
    """State equations of a causal bond graph.

    ``fold``: parameter id -> value, turned into numbers; ``zero``: removed element id ->
    cardinality, whose variables read as zero (both from scene specialisation)."""
    ctx = _Ctx(bg, caus, fold, zero)
    # States of storage elements, then auxiliary states, in declaration order.
    for el in bg.elements:
        if el.type in ("I", "C") and el.id not in caus.derivative:
            n = bg.bonds_of(el.id)[0].n
            letter = "p" if el.type == "I" else "q"
            sym = _vec(f"{letter}_{code_name(el.id)}", n)
            ctx.states[el.id] = sym
    for st in bg.states:
        ctx.states[st.id] = _mat_syms("s_" + code_name(st.id), st.shape)
    for inp in bg.model.inputs:
        ctx.inputs_value(inp.name, inp.coord)

    defs: dict[sp.Symbol, Assignment] = {}
    owner: dict[sp.Symbol, str] = {}
    derivs: dict[sp.Symbol, object] = {}
    state_vars: list[StateVar] = []

    def define(var, value, el: FlatElement, why: str):
        if not shape_of(var) and shape_of(value) == (1, 1):  # e.g. M^T e2 of an n2 x 1 modulus
            value = value[0, 0]
        if shape_of(var) != shape_of(value):
            raise ModelError(el.coord, f"{el.type} {el.id!r}: cardinality mismatch: its law "
                                       f"gives {_shape_name(shape_of(value))}, its bond "
                                       f"carries {_shape_name(shape_of(var))}")
        targets = set(flat(var))
        for s, v in zip(flat(var), flat(value)):
            _check_value(v, el, targets)
            defs[s] = Assignment(s, v, why)
            owner[s] = el.id

    for el in bg.elements:
        _element_equations(ctx, el, define, derivs, state_vars)
    for st in bg.states:
        val = ctx.build(st.derivative, st.scope, f"state {st.id!r} derivative")
        sym = ctx.states[st.id]
        if shape_of(val) != shape_of(sym):
            raise ModelError(st.derivative.coord, f"state {st.id!r}: derivative has shape "
                                                  f"{_shape_name(shape_of(val))}, the state "
                                                  f"{_shape_name(shape_of(sym))}")
        init = ctx.build(st.initial, st.scope, f"state {st.id!r} initial", params_only=True)
        if shape_of(init) != shape_of(sym) and not (init == 0 or init == sp.Integer(0)):
            raise ModelError(st.initial.coord, f"state {st.id!r}: initial value has shape "
                                               f"{_shape_name(shape_of(init))}, the state "
                                               f"{_shape_name(shape_of(sym))}")
        inits = flat(init) if shape_of(init) else [init] * len(flat(sym))
        for k, (s, v, i0) in enumerate(zip(flat(sym), flat(val), inits)):
            derivs[s] = v
            state_vars.append(StateVar(_state_label(st.id, st.shape, k), s, st.id, i0))

    outputs = []
    for out in bg.model.body.outputs:
        val = ctx.build(out.expr, (), f"output {out.name!r}")
        shp = shape_of(val)
        if shp and shp[1] == 1:
            shp = (shp[0],)
        outputs.append((out.name, shp, tuple(flat(val))))

    tear_sets = ()
    dependent = []
    if ctx.dependent:
        names = {sv.symbol: sv.name for sv in state_vars}
        for eid, syms, _ in ctx.dependent:
            seen, stack, on = set(), list(syms), set()
            while stack:
                v = stack.pop()
                if v in seen:
                    continue
                seen.add(v)
                if v in names:
                    on.add(v)
                elif v in defs:
                    stack.extend(defs[v].expr.free_symbols)
            dependent.append((eid, tuple(sv.name for sv in state_vars if sv.symbol in on)))
        if progress:
            progress("differentiating along the causal paths of dependent storage elements")
        tear_sets = _time_derivatives(ctx, defs, owner, derivs, state_vars)
    if progress:
        progress("ordering assignments")
    nloops: list = [] if newton else None
    order, loops = _causal_order(bg, defs, owner, tear_sets, symbolic_max, nloops)
    # Inline plain copies (junction equalities, sign flips, constants): they are not work.
    subs: dict = {}
    kept: list[Assignment] = []
    for s in order:
        a = defs[s]
        v = a.expr.xreplace(subs) if subs else a.expr
        if _trivial(v):
            subs[s] = v
        else:
            kept.append(Assignment(s, v, a.why))
    derivatives = tuple((derivs[sv.symbol].xreplace(subs) if subs else derivs[sv.symbol])
                        for sv in state_vars)
    outputs = tuple((n, shp, tuple(e.xreplace(subs) for e in vals)) for n, shp, vals in outputs)
    ctx_derived = [ctx.derived[k] for k in ctx.derived_order]

    # Every free symbol must be declared: a state, a parameter, an input, t, or an assignment.
    known = {sv.symbol for sv in state_vars} | {T}
    for pv in ctx.params.values():
        known.update(pv.symbols)
    for a in ctx_derived:
        known.add(a.symbol)
    for iv in ctx.inputs.values():
        known.update(iv.symbols)
    known.update(a.symbol for a in kept)
    for expr in itertools.chain((a.expr for a in kept), derivatives,
                                (e for _, _, v in outputs for e in v)):
        stray = expr.free_symbols - known
        if stray:
            names = ", ".join(sorted(map(str, stray)))
            raise ModelError(bg.model.coord, f"internal: undeclared symbols {names} "
                                             "(a derivative-causality element referenced?)")

    if progress:
        progress("deriving the Jacobian")
    nloops = [dc_replace(nl, g=tuple(e.xreplace(subs) for e in nl.g)) for nl in nloops or ()]
    jac, jac_assign = _jacobian(kept, state_vars, derivatives, nloops)
    _check_names(bg, ctx, state_vars)
    standing = tuple(w for w in caus.warnings if not w.startswith("R elements with causality"))
    return Equations(bg.model.name, tuple(state_vars), tuple(ctx.params.values()),
                     tuple(ctx_derived), tuple(ctx.inputs[i.name] for i in bg.model.inputs),
                     tuple(kept), derivatives, outputs, jac, tuple(jac_assign), tuple(loops),
                     warnings=standing, dependent=tuple(dependent), newton=tuple(nloops))


_BAD_VALUES = (sp.zoo, sp.oo, -sp.oo, sp.nan, sp.I)


def _check_value(v, el: FlatElement, targets: set) -> None:
    """An element's equation must be finite and real, and must not read what it defines."""
    if v.has(*_BAD_VALUES):
        bad = "complex" if v.has(sp.I) else "infinite or undefined"
        hint = {"I": " (a zero inertia?)", "C": " (a zero compliance?)",
                "R": " (a zero resistance in conductance form?)"}.get(el.type, "")
        raise ModelError(el.coord, f"{el.type} {el.id!r}: its equation is {bad}: it divides by "
                                   f"zero or takes the root or logarithm of a negative "
                                   f"constant{hint}")
    own = v.free_symbols & targets
    if own:
        name = sorted(map(str, own))[0]
        var = "effort" if name.startswith("e_") else "flow" if name.startswith("f_") else name
        raise ModelError(el.coord, f"{el.type} {el.id!r}: its law reads its own {var}, the "
                                   "variable the law defines (write it in terms of the "
                                   f"element's {'state' if el.type in ('I', 'C') else 'other variable'})")


def _state_label(oid: str, shape, k: int) -> str:
    if not shape:
        return oid
    if len(shape) == 1:
        return f"{oid}[{k}]"
    return f"{oid}[{k // shape[1]},{k % shape[1]}]"


def _trivial(v) -> bool:
    if v.is_Symbol or v.is_Number:
        return True
    if isinstance(v, sp.Mul) and len(v.args) == 2 and v.args[0] == -1 and v.args[1].is_Symbol:
        return True
    return False


def _element_equations(ctx: _Ctx, el: FlatElement, define, derivs, state_vars):
    bg, caus = ctx.bg, ctx.caus
    bonds = bg.bonds_of(el.id)
    t = el.type
    what = f"{t} {el.id!r}"
    if t in ("0", "1"):
        _junction(ctx, el, bonds, define)
        return
    if t in TWO_PORTS:
        _two_port(ctx, el, bonds, define)
        return
    (b,) = bonds
    n = b.n
    e, f = ctx.e[b.id], ctx.f[b.id]
    sgn = 1 if b.dst == el.id else -1  # +1 when the bond points at the element
    sets_effort = caus.effort_by[b.id] == el.id
    key, law = el.law
    if t == "Se":
        define(e, _card(ctx.build(law, el.scope, what), n, el, key), el, f"{el.id} (Se): effort")
        return
    if t == "Sf":
        define(f, _card(ctx.build(law, el.scope, what), n, el, key), el, f"{el.id} (Sf): flow")
        return
    if t in ("I", "C"):
        letter = "p" if t == "I" else "q"
        state = ctx.states.get(el.id)
        if state is None:
            _dependent_storage(ctx, el, b, sgn, define)
            return
        if t == "I":
            if key == "inertia":
                m = _card(ctx.build(law, el.scope, what), n, el, key, square=True)
                val = _solve(m, state, el, key)
            else:
                val = _card(ctx.build(law, el.scope, what, local={"p": state}), n, el, key)
            define(f, val, el, f"{el.id} (I, integral): flow from momentum")
            rate = e * sgn
        else:
            if key == "stiffness":
                k = _card(ctx.build(law, el.scope, what), n, el, key, square=True)
                val = k * state
            elif key == "compliance":
                c = _card(ctx.build(law, el.scope, what), n, el, key, square=True)
                val = _solve(c, state, el, key)
            else:
                val = _card(ctx.build(law, el.scope, what, local={"q": state}), n, el, key)
            define(e, val * sgn, el, f"{el.id} (C, integral): effort from displacement")
            rate = f
        init = (ctx.build(el.initial, el.scope, f"{what} initial", params_only=True)
                if el.initial is not None else sp.Integer(0))
        if shape_of(init) not in ((), shape_of(state)) or (not shape_of(init) and n > 1
                                                             and init != 0):
            raise ModelError(el.initial.coord if el.initial else el.coord,
                             f"{what}: initial value shape does not match its bond (n={n})")
        inits = flat(init) if shape_of(init) else [init] * n
        for k, (s, r, i0) in enumerate(zip(flat(state), flat(rate), inits)):
            derivs[s] = r
            label = f"{el.id}.{letter}" + (f"[{k}]" if n > 1 else "")
            state_vars.append(StateVar(label, s, el.id, i0))
        return
    if t == "R":
        fe, ff = e * sgn, f  # the element's own effort and flow
        if key == "resistance":
            r = _card(ctx.build(law, el.scope, what), n, el, key, square=True)
            if sets_effort:
                define(e, (r * ff) * sgn, el, f"{el.id} (R): effort = r f")
            else:
                define(f, _solve(r, fe, el, key), el, f"{el.id} (R): flow = e / r")
        elif key == "effort":
            val = _card(ctx.build(law, el.scope, what, local={"f": ff}), n, el, key)
            define(e, val * sgn, el, f"{el.id} (R): effort law")
        else:
            val = _card(ctx.build(law, el.scope, what, local={"e": fe}), n, el, key)
            define(f, val, el, f"{el.id} (R): flow law")
        return
    raise ModelError(el.coord, f"unsupported element type {t}")  # pragma: no cover


def _dependent_storage(ctx: _Ctx, el: FlatElement, b, sgn: int, define):
    """A storage element in derivative causality: its state is a function of the others'.

    An I receives its flow f: its momentum p = M f is an assignment and its effort is dp/dt;
    a C receives its effort e: q = K^-1 e (or c e) and its flow is dq/dt. The time derivative
    is a placeholder symbol ``dt_<p or q>`` that ``_time_derivatives`` defines by the chain
    rule along the causal assignments (with the state derivatives as unknowns where needed).
    """
    t, n = el.type, b.n
    key, law = el.law
    what = f"{t} {el.id!r}"
    e, f = ctx.e[b.id], ctx.f[b.id]
    letter = "p" if t == "I" else "q"
    if t == "I":
        if key != "inertia":
            raise ModelError(el.coord, f"{what} is in derivative causality (its flow follows from "
                                       "the other states), which needs its momentum as a function "
                                       "of its flow: give it an `inertia:` law, not `flow:`")
        m = _card(ctx.build(law, el.scope, what), n, el, key, square=True)
        val = m * f
    else:
        if key == "stiffness":
            k = _card(ctx.build(law, el.scope, what), n, el, key, square=True)
            val = _solve(k, e * sgn, el, key)
        elif key == "compliance":
            val = _card(ctx.build(law, el.scope, what), n, el, key, square=True) * (e * sgn)
        else:
            raise ModelError(el.coord, f"{what} is in derivative causality (its effort follows "
                                       "from the other states), which needs its displacement as "
                                       "a function of its effort: give it a `stiffness:` or "
                                       "`compliance:` law, not `effort:`")
    state = _vec(f"{letter}_{code_name(el.id)}", n)
    dot = _vec(f"_dt_{letter}_{code_name(el.id)}", n)
    define(state, val, el, f"{el.id} ({t}, derivative): {'momentum from flow' if t == 'I' else 'displacement from effort'}")
    if t == "I":
        define(e, dot * sgn, el, f"{el.id} (I, derivative): effort = dp/dt")
    else:
        define(f, dot, el, f"{el.id} (C, derivative): flow = dq/dt")
    ctx.states[el.id] = state  # p() / q() read the dependent state
    ctx.dependent.append((el.id, tuple(flat(state)), tuple(flat(dot))))


def _card(val, n, el, key, square=False):
    """Check a law's shape against the bond's cardinality n."""
    s = shape_of(val)
    if n == 1:
        if s in ((), (1, 1)):
            return val[0] if s else val
    elif square:
        if s == ():
            return sp.ImmutableMatrix(val * sp.eye(n))
        if s == (n, n):
            return val
    elif s == (n, 1):
        return val
    want = "scalar" if n == 1 else (f"a scalar or a {n}x{n} matrix" if square else f"a {n}-vector")
    raise ModelError(el.coord, f"{el.type} {el.id!r}: cardinality mismatch: {key} is "
                               f"{_shape_name(s)}, the bond (n={n}) needs {want}")


def _solve(m, rhs, el, key):
    """m^-1 rhs for a scalar or a small matrix (adjugate over determinant)."""
    if not shape_of(m):
        if m == 0:
            raise ModelError(el.coord, f"{el.type} {el.id!r}: its {key} is zero and must be "
                                       "inverted here (a division by zero)")
        return rhs / m
    if m.shape[0] > 4:
        raise ModelError(el.coord, f"{el.type} {el.id!r}: inverting a {m.shape[0]}x"
                                   f"{m.shape[0]} {key} symbolically is not supported; give the "
                                   "law in the other form (e.g. flow: expression of p)")
    if m.is_diagonal():
        return sp.ImmutableMatrix(m.shape[0], 1, [r / m[i, i] for i, r in enumerate(rhs)])
    d = m.det(method="berkowitz")
    if d == 0:
        raise ModelError(el.coord, f"{el.type} {el.id!r}: {key} matrix is singular")
    return sp.ImmutableMatrix(m.adjugate() * rhs / d)


def _junction(ctx: _Ctx, el: FlatElement, bonds, define):
    caus = ctx.caus
    if el.type == "0":
        src = next(b for b in bonds if caus.effort_by[b.id] != el.id)
        for b in bonds:
            if b is not src:
                define(ctx.e[b.id], ctx.e[src.id], el, f"0-junction {el.id}: common effort")
        # flows: sum in = sum out, solved for the imposing bond's flow
        total = _zeros(src.n)
        for b in bonds:
            if b is src:
                continue
            total = total + (ctx.f[b.id] if b.src == el.id else -ctx.f[b.id])
        val = total if src.dst == el.id else -total
        define(ctx.f[src.id], val, el, f"0-junction {el.id}: flow balance")
    else:
        src = next(b for b in bonds if caus.effort_by[b.id] == el.id)
        for b in bonds:
            if b is not src:
                define(ctx.f[b.id], ctx.f[src.id], el, f"1-junction {el.id}: common flow")
        total = _zeros(src.n)
        for b in bonds:
            if b is src:
                continue
            total = total + (ctx.e[b.id] if b.src == el.id else -ctx.e[b.id])
        val = total if src.dst == el.id else -total
        define(ctx.e[src.id], val, el, f"1-junction {el.id}: effort balance")


def _two_port(ctx: _Ctx, el: FlatElement, bonds, define):
    b1 = next(b for b in bonds if b.dst == el.id)
    b2 = next(b for b in bonds if b.src == el.id)
    key, law = el.law
    what = f"{el.type} {el.id!r}"
    m = ctx.build(law, el.scope, what, params_only=el.type in ("TF", "GY"))
    s = shape_of(m)
    n1, n2 = b1.n, b2.n
    if s == ():
        if n1 != n2:
            raise ModelError(el.coord, f"{what}: cardinality mismatch: a scalar {key} needs equal "
                                       f"cardinalities, its bonds have {n1} and {n2}")
        if n1 > 1:
            m = sp.ImmutableMatrix(m * sp.eye(n1))
    elif s != (n2, n1):
        raise ModelError(el.coord, f"{what}: cardinality mismatch: {key} is {_shape_name(s)}, "
                                   f"its bonds need {n2}x{n1} (out x in)")
    mt = m.T if shape_of(m) else m
    e1, f1, e2, f2 = ctx.e[b1.id], ctx.f[b1.id], ctx.e[b2.id], ctx.f[b2.id]
    forward = ctx.caus.effort_by[b1.id] == el.id
    if el.type in ("TF", "MTF"):
        if forward:
            define(f2, m * f1, el, f"{el.id} ({el.type}): f2 = M f1")
            define(e1, mt * e2, el, f"{el.id} ({el.type}): e1 = M^T e2")
        else:
            if n1 != n2:
                raise ModelError(el.coord, f"{what}: causality needs its {key} inverted, but it "
                                           f"is not square ({n2}x{n1})")
            define(f1, _solve(m, f2, el, key), el, f"{el.id} ({el.type}): f1 = M^-1 f2")
            define(e2, _solve(mt, e1, el, key), el, f"{el.id} ({el.type}): e2 = M^-T e1")
    else:
        if forward:  # the gyrator sets both efforts
            define(e2, m * f1, el, f"{el.id} ({el.type}): e2 = M f1")
            define(e1, mt * f2, el, f"{el.id} ({el.type}): e1 = M^T f2")
        else:
            if n1 != n2:
                raise ModelError(el.coord, f"{what}: causality needs its {key} inverted, but it "
                                           f"is not square ({n2}x{n1})")
            define(f1, _solve(m, e2, el, key), el, f"{el.id} ({el.type}): f1 = M^-1 e2")
            define(f2, _solve(mt, e1, el, key), el, f"{el.id} ({el.type}): f2 = M^-T e1")


def _time_derivatives(ctx: _Ctx, defs: dict, owner: dict, derivs: dict, state_vars) -> tuple:
    """Define the ``dt_`` symbols of the dependent storage elements by the chain rule.

    Forward mode in time along the causal assignments: for every assignment v = g(...) that a
    dependent state depends on, ``_dt_v = sum(dg/ds * _dt_s) + dg/dt``; a state's time
    derivative is the symbol ``_dx_<state>``, itself assigned the state's derivative. The
    loop this closes (state derivatives -> dependent efforts -> junctions -> state
    derivatives) is linear in its unknowns and solved by ``_tear_solve``.
    Returns the tear candidates: (the _dx_ symbols, the dependent dt_ symbols)."""
    bg = ctx.bg
    state_syms = {sv.symbol: sv for sv in state_vars}
    input_syms = {s: iv.name for iv in ctx.inputs.values() for s in iv.symbols}
    dt_syms = {d: eid for eid, _, dots in ctx.dependent for d in dots}
    dep_of: dict = {}  # state symbol of a dependent element -> its dt_ symbol
    for eid, states, dots in ctx.dependent:
        dep_of.update(zip(states, dots))
    # closure of the assignments the dependent states depend on
    need, stack = set(), [s for s in dep_of]
    while stack:
        s = stack.pop()
        if s in need or s not in defs:
            continue
        need.add(s)
        stack.extend(d for d in defs[s].expr.free_symbols if d in defs)
    dot: dict = {}
    dx: dict = {}
    for s in sorted(need, key=str):
        dot[s] = dep_of.get(s) or _sym(f"_dt_{s}")
    for s in sorted({d for v in need for d in defs[v].expr.free_symbols if d in state_syms},
                    key=str):
        dot[s] = _sym(f"_dx_{s}")
        dx[dot[s]] = s
    for s in sorted(need, key=str):
        a = defs[s]
        expr = a.expr
        free = expr.free_symbols
        for d in free:
            if d in input_syms:
                who = owner[s]
                deps = sorted({e for e, st, _ in ctx.dependent})
                raise ModelError(bg.element(who).coord,
                                 f"derivative causality of {', '.join(map(repr, deps))}: its "
                                 f"state follows from input {input_syms[d]!r} through "
                                 f"{_kind(bg.element(who))}, whose time derivative bgc would "
                                 "need; drive it through a compliant coupling, or make the "
                                 "signal an expression of t")
            if d in dt_syms:
                raise ModelError(bg.element(dt_syms[d]).coord,
                                 f"derivative causality of {dt_syms[d]!r} feeds another "
                                 f"dependent element through {_kind(bg.element(owner[s]))}: "
                                 "a second derivative would be needed (index > 2); add a "
                                 "compliant coupling")
        terms = [_clean(sp.diff(expr, d)) * dot[d] for d in sorted(free, key=str) if d in dot]
        terms.append(_clean(sp.diff(expr, T)))
        val = sp.Add(*terms)
        defs[dot[s]] = Assignment(dot[s], val, f"d/dt of {s} ({a.why})" if s not in dep_of
                                  else f"{owner[s]}: d/dt of its state (chain rule)")
        owner[dot[s]] = owner[s]
    for d, s in dx.items():
        defs[d] = Assignment(d, derivs[s], f"derivative of state {state_syms[s].name}")
        owner[d] = state_syms[s].owner
    return (frozenset(dx), frozenset(dt_syms))


def _tear_solve(bg, g, defs, owner, comp, index, tear_sets, symbolic_max):
    """Solve an algebraic loop that is linear in its unknowns by tearing.

    With the tear variables known, the rest of the loop is acyclic; every value in it is
    affine in the tear variables, with coefficients found by forward-mode differentiation
    along the loop (new assignments, free of loop variables: otherwise the loop is
    nonlinear). The loop evaluated at tear = 0 gives the constant part. That leaves
    (I - A) tear = b, solved symbolically on symbols standing for the entries while small,
    else numerically in the generated code. Returns (description or None)."""
    cset = set(comp)
    best = None
    cands = [sorted(cset & ts, key=index.get) for ts in tear_sets]
    cands = [c for c in cands if c]
    if len(cands) > 1:
        cands.append(sorted(set(cands[0]) | set(cands[1]), key=index.get))
    for cand in sorted(cands, key=len):
        rest = [s for s in comp if s not in set(cand)]
        if nx.is_directed_acyclic_graph(g.subgraph(rest)):
            best = cand
            break
    if best is None:
        return None
    tear = best
    tset = set(tear)
    rest_g = g.subgraph([s for s in comp if s not in tset]).copy()
    rest = schedule(rest_g, index)
    els = sorted({owner[s] for s in comp if owner.get(s)})
    where = _coord(bg, els[0])
    counter = itertools.count(len(index))
    new: list = []

    def add(sym, expr, why, own):
        defs[sym] = Assignment(sym, expr, why)
        owner[sym] = own
        index[sym] = next(counter)
        new.append(sym)

    C: dict = {t: {k: sp.Integer(1)} for k, t in enumerate(tear)}
    tag = str(tear[0]).lstrip("_")
    nco = itertools.count()

    def coeffs(s):
        expr = defs[s].expr
        acc: dict = {}
        for d in expr.free_symbols & cset:
            part = _clean(sp.diff(expr, d))
            if part == 0:
                continue
            bad = part.free_symbols & cset
            if bad:
                raise ModelError(where, "algebraic loop through " + ", ".join(
                    _who(bg, e) for e in els) + f" is nonlinear in its unknowns "
                    f"({', '.join(sorted(map(str, bad))[:6])}): bgc solves linear loops only")
            for k, c in C.get(d, {}).items():
                acc[k] = acc[k] + part * c if k in acc else part * c
        out = {}
        for k, v in sorted(acc.items()):
            if v == 0:
                continue
            if _trivial(v):
                out[k] = v
            else:
                sym = _sym(f"_l{next(nco)}_{tag}")
                add(sym, v, "", owner[s])
                out[k] = sym
        return out

    for s in rest:
        C[s] = coeffs(s)
    a_rows = [coeffs(t) for t in tear]
    zero = {t: sp.Integer(0) for t in tear}
    for s in rest:
        z = _sym(f"_z_{s}".replace("__z_", "_z_"))
        add(z, defs[s].expr.xreplace(zero), defs[s].why + " (loop at zero)", owner[s])
        zero[s] = z
    n = len(tear)
    bsyms, A = [], sp.zeros(n, n)
    for i, t in enumerate(tear):
        bexpr = defs[t].expr.xreplace(zero)
        if _trivial(bexpr):
            bsyms.append(bexpr)
        else:
            b = _sym(f"_b{i}_{tag}")
            add(b, bexpr, f"linear system for {', '.join(map(str, tear))}: right-hand side",
                owner[t])
            bsyms.append(b)
        for k in range(n):
            v = (1 if i == k else 0) - a_rows[i].get(k, 0)
            if v == 0 or v.is_Number:
                A[i, k] = v
            else:
                a = _sym(f"_A{i}_{k}_{tag}")
                add(a, v, "linear system: matrix" if (i, k) == (0, 0) else "", owner[t])
                A[i, k] = a
    if n <= symbolic_max:
        sol = list(A.LUsolve(sp.Matrix(bsyms)))
        how = "symbolically"
    else:
        X = _sym(f"_X_{tag}")
        add(X, LinSolve(n, *list(A), *bsyms), f"numeric linear solve ({n} unknowns)", owner[tear[0]])
        sol = [LinSolveEntry(X, i) for i in range(n)]
        how = "numerically (np.linalg.solve)"
    for t, v in zip(tear, sol):
        defs[t] = Assignment(t, v, defs[t].why + " (linear system solved)")
    # rebuild the dependency edges of everything touched
    for s in list(comp) + new:
        g.add_node(s)
        for dep in list(g.predecessors(s)):
            g.remove_edge(dep, s)
        for dep in _deps(defs[s].expr):
            if dep in defs:
                g.add_edge(dep, s)
    desc = ", ".join(_who(bg, e) for e in els)
    return (f"derivative causality: linear system in {n} unknown(s) "
            f"({', '.join(str(t).lstrip('_') for t in tear)}) solved {how}, through {desc}")


class LinSolve(sp.Function):
    """x = A^-1 b for LinSolve(n, A entries row-major, b entries): printed as a batched solve."""

    @classmethod
    def eval(cls, *args):
        return None

    def _eval_derivative(self, s):  # the Jacobian goes through _linsolve_grad instead
        raise ModelError(None, "internal: LinSolve differentiated symbolically")


class LinSolveEntry(sp.Function):
    """Component i of a LinSolve result (a symbol)."""

    @classmethod
    def eval(cls, *args):
        return None


@dataclass(frozen=True)
class NewtonLoop:
    """A nonlinear algebraic loop solved by Newton's method in the generated code."""

    name: str  # the generated function
    tear: tuple  # its unknowns (symbols)
    args: tuple  # the symbols from outside the loop it reads
    body: tuple  # (symbol, expr): the loop's other variables and the derivative coefficients
    residual: tuple  # tear_i - g_i(...), zero at the solution
    jac: tuple  # d residual / d tear, row-major
    g: tuple  # g_i: the tear variables' own definitions (for the system Jacobian)
    rest: tuple  # the loop's other variables, in order
    where: str  # for the error message: "file:line:col: algebraic loop through ..."


class NewtonSolve(sp.Function):
    """The tear variables of Newton loop k: NewtonSolve(k, *outside symbols)."""

    @classmethod
    def eval(cls, *args):
        return None


def _cut_set(g: nx.DiGraph, comp: list, index: dict) -> list:
    """Tear variables that leave the loop acyclic: greedily the node with the most
    in x out edges inside what is still cyclic (ties: the first in causal priority)."""
    tear: list = []
    rest = set(comp)
    while True:
        sub = g.subgraph(rest)
        cyc = [c for c in nx.strongly_connected_components(sub)
               if len(c) > 1 or any(sub.has_edge(v, v) for v in c)]
        if not cyc:
            return tear
        cand = max((v for c in cyc for v in c),
                   key=lambda v: (sub.in_degree(v) * sub.out_degree(v), -index[v]))
        tear.append(cand)
        rest.discard(cand)


def _newton_loop(bg, g, defs, owner, comp, index, newton: list) -> str:
    k = len(newton)
    tear = sorted(_cut_set(g, comp, index), key=index.get)
    tset = set(tear)
    rest = schedule(g.subgraph([s for s in comp if s not in tset]).copy(), index)
    cset = set(comp)
    els = sorted({owner[s] for s in comp})
    desc = ", ".join(_who(bg, e) for e in els)
    body: list = []
    C: dict = {t: {i: sp.Integer(1)} for i, t in enumerate(tear)}
    nco = itertools.count()

    def coeffs(expr):
        acc: dict = {}
        for d in expr.free_symbols & cset:
            part = _clean(sp.diff(expr, d))
            if part == 0:
                continue
            for i, c in C.get(d, {}).items():
                acc[i] = acc[i] + part * c if i in acc else part * c
        out = {}
        for i, v in sorted(acc.items()):
            if v == 0:
                continue
            if _trivial(v):
                out[i] = v
            else:
                sym = _sym(f"_nc{next(nco)}")
                body.append((sym, v))
                out[i] = sym
        return out

    for s in rest:
        body.append((s, defs[s].expr))
        C[s] = coeffs(defs[s].expr)
    G = [defs[t].expr for t in tear]
    n = len(tear)
    a_rows = [coeffs(gi) for gi in G]
    residual = tuple(t - gi for t, gi in zip(tear, G))
    jac = tuple((1 if i == j else 0) - a_rows[i].get(j, 0) for i in range(n) for j in range(n))
    inner = {sym for sym, _ in body} | tset
    outside = set()
    for e in [e for _, e in body] + list(residual) + list(jac):
        outside |= sp.sympify(e).free_symbols - inner
    args = tuple(sorted(outside, key=str))
    c = _coord(bg, els[0])
    where = f"{c}: " if c else ""
    X = _sym(f"_nl{k}")
    newton.append(NewtonLoop(f"_newton_{k}", tuple(tear), args, tuple(body), residual, jac,
                             tuple(G), tuple(rest),
                             f"{where}algebraic loop through {desc} (unknowns "
                             f"{', '.join(map(str, tear))})"))
    defs[X] = Assignment(X, NewtonSolve(k, *args), f"nonlinear algebraic loop through {desc}: "
                                                   "Newton's method")
    owner[X] = els[0]
    index[X] = len(index)
    for i, t in enumerate(tear):
        defs[t] = Assignment(t, LinSolveEntry(X, i), defs[t].why + " (Newton)")
    for v in list(comp) + [X]:
        g.add_node(v)
        for dep in list(g.predecessors(v)):
            g.remove_edge(dep, v)
        for dep in defs[v].expr.free_symbols:
            if dep in defs:
                g.add_edge(dep, v)
    return (f"nonlinear algebraic loop solved by Newton's method in {n} unknown(s) "
            f"({', '.join(map(str, tear))}), through {desc}")


def _deps(expr):
    return expr.free_symbols


def _causal_order(bg: BondGraph, defs: dict, owner: dict, tear_sets=(),
                  symbolic_max: int = SYMBOLIC_MAX, newton: list | None = None):
    """Assignments in causal order; algebraic loops solved where linear (symbolically), and
    nonlinear ones by Newton's method in the generated code when ``newton`` (a list that
    receives the loops) is given."""
    g = nx.DiGraph()
    index = {s: i for i, s in enumerate(defs)}
    for s, a in defs.items():
        g.add_node(s)
        for dep in a.expr.free_symbols:
            if dep in defs:
                g.add_edge(dep, s)
    loops = []
    for comp in list(nx.strongly_connected_components(g)):
        if len(comp) == 1:
            (s,) = comp
            if not g.has_edge(s, s):
                continue
        comp = sorted(comp, key=index.get)
        if any(cset_t & set(comp) for cset_t in tear_sets):
            done = _tear_solve(bg, g, defs, owner, comp, index, tear_sets, symbolic_max)
            if done is None:
                els = sorted({owner[s] for s in comp})
                raise ModelError(_coord(bg, els[0]), "derivative causality: the loop "
                                 "through " + ", ".join(_who(bg, e) for e in els)
                                 + " cannot be torn at the state derivatives")
            loops.append(done)
            continue
        els = sorted({owner[s] for s in comp})
        desc = ", ".join(_kind(bg.element(e)) for e in els)
        eqs = [s - defs[s].expr for s in comp]
        try:
            A, rhs = sp.linear_eq_to_matrix(eqs, comp)
        except (sp.polys.polyerrors.PolynomialError, ValueError, TypeError):
            A = None
        if (A is None or any(A.has(s) for s in comp)) and newton is not None:
            loops.append(_newton_loop(bg, g, defs, owner, comp, index, newton))
            continue
        if A is None or any(A.has(s) for s in comp):
            raise ModelError(bg.element(els[0]).coord,
                             f"algebraic loop through {desc} is nonlinear in its unknowns "
                             f"({', '.join(map(str, comp[:6]))}); bgc solves linear loops only: "
                             "add a storage element (e.g. a small C or I) to break it")
        if len(comp) > 60:
            raise ModelError(bg.element(els[0]).coord, f"algebraic loop through {desc} has "
                                                       f"{len(comp)} unknowns (limit 60)")
        try:
            sol = A.LUsolve(rhs)
        except (ValueError, ZeroDivisionError, sp.matrices.exceptions.NonInvertibleMatrixError):
            raise ModelError(bg.element(els[0]).coord,
                             f"algebraic loop through {desc} is singular: its equations do not "
                             "determine its unknowns (a law that reads the variable it "
                             "defines?)") from None
        loops.append(f"linear algebraic loop solved through {desc}")
        for s, v in zip(comp, sol):
            defs[s] = Assignment(s, v, defs[s].why + " (algebraic loop, solved)")
        for s in comp:
            for dep in list(g.predecessors(s)):
                g.remove_edge(dep, s)
            for dep in defs[s].expr.free_symbols:
                if dep in defs:
                    g.add_edge(dep, s)
    order = schedule(g, index)
    return order, loops


def _who(bg: BondGraph, oid: str) -> str:
    """An element (by kind) or an auxiliary state, for messages."""
    if oid in bg._el:
        return _kind(bg.element(oid))
    return f"state {oid!r}"


def _coord(bg: BondGraph, oid: str):
    if oid in bg._el:
        return bg.element(oid).coord
    return next((st.coord for st in bg.states if st.id == oid), None)


def _kind(el: FlatElement) -> str:
    """'R 'load'', '0-junction 'node''."""
    return f"{el.type}-junction {el.id!r}" if el.type in ("0", "1") else f"{el.type} {el.id!r}"


def schedule(g: nx.DiGraph, index: dict) -> list:
    """Topological order that keeps the given priority wherever dependencies allow."""
    indeg = {n: g.in_degree(n) for n in g.nodes}
    heap = [(index[n], n.name if hasattr(n, "name") else str(n), n)
            for n, d in indeg.items() if d == 0]
    heapq.heapify(heap)
    out = []
    while heap:
        _, _, n = heapq.heappop(heap)
        out.append(n)
        for m in g.successors(n):
            indeg[m] -= 1
            if indeg[m] == 0:
                heapq.heappush(heap, (index[m], m.name if hasattr(m, "name") else str(m), m))
    if len(out) != len(indeg):
        raise ModelError(None, "internal: cycle left after solving algebraic loops")
    return out


def _clean(d):
    """Derivatives of step-like functions (sign, Heaviside) are zero almost everywhere."""
    if d.has(sp.DiracDelta):
        d = d.replace(lambda a: isinstance(a, sp.DiracDelta), lambda a: sp.Integer(0))
    if d.has(sp.Derivative):
        d = d.replace(lambda a: isinstance(a, sp.Derivative)
                      and isinstance(a.expr, (sp.sign, sp.Heaviside)),
                      lambda a: sp.Integer(0))
    if d.has(sp.Derivative):
        raise ModelError(None, f"cannot differentiate {d}")
    return d


def prune(results: list, assigns: list[Assignment], also=None) -> list[Assignment]:
    """The assignments (in their order) that ``results`` depend on, directly or through each
    other; ``also(a)`` names further symbols an assignment needs (beyond its expression's)."""
    need: set = set()
    for r in results:
        need |= r.free_symbols
    keep = []
    for a in reversed(assigns):
        if a.symbol in need:
            keep.append(a)
            need |= a.expr.free_symbols
            if also is not None:
                need.update(also(a))
    keep.reverse()
    return keep


def _jacobian(kept: list[Assignment], state_vars, derivatives, nloops=()):
    """Forward-mode Jacobian d(derivatives)/dx along the causal assignments."""
    return forward_mode(kept, {sv.symbol: j for j, sv in enumerate(state_vars)},
                        list(derivatives), "_d", nloops)


def forward_mode(kept: list[Assignment], seeds: dict, finals: list, prefix: str = "_d",
                 nloops=()):
    """Forward-mode derivatives of ``finals`` with respect to the seed symbols (symbol ->
    column) along the causal assignments ``kept``: the state Jacobian (seeds: the states) and
    the linearisation's B, C, D (seeds: inputs or states; finals: derivatives or outputs).

    D[v] maps a column j to dv/d(seed j). Non-trivial entries become new intermediates
    (``<prefix><k>``), so every emitted expression stays as small as one assignment's; linear
    solves and Newton loops are differentiated through (one more solve per column). Only the
    assignments the finals depend on are visited (linear in model size).
    """
    D: dict[sp.Symbol, dict[int, object]] = {s: {j: sp.Integer(1)} for s, j in seeds.items()}
    jac_assign: list[Assignment] = []
    counter = itertools.count()
    used = prune(finals, kept, lambda a: (  # a Newton loop's own assignments feed it
        nloops[int(a.expr.args[0])].rest if isinstance(a.expr, NewtonSolve) else ()))

    bridge = fastsym.Bridge() if fastsym.available() else None

    def grad(expr) -> dict[int, object]:
        syms = sorted((s for s in expr.free_symbols if D.get(s)), key=str)  # deterministic
        if not syms:
            return {}
        parts = fastsym.partials(bridge, expr, syms) if bridge is not None else None
        if parts is not None:  # symengine: same algebra, a hundred times faster
            acc_se: dict[int, object] = {}
            for s, partial in parts.items():
                for j, dj in D[s].items():
                    term = partial * bridge.to_se(dj)
                    acc_se[j] = acc_se[j] + term if j in acc_se else term
            return {j: bridge.from_se(v) for j, v in acc_se.items() if v != 0}
        acc: dict[int, object] = {}
        for s in syms:
            partial = _clean(sp.diff(expr, s))
            if partial == 0:
                continue
            for j, dj in D[s].items():
                term = partial * dj
                acc[j] = acc[j] + term if j in acc else term
        return {j: v for j, v in acc.items() if v != 0}

    solves: dict = {}  # LinSolve result symbol -> {state index: symbol of its derivative}
    kept_map = {a.symbol: a for a in kept}

    def local(seed: dict, exprs_of, order, outer: bool):
        """Forward mode over the loop's variables with the tear variables seeded."""
        Dl = dict(seed)
        for s in order:
            a = kept_map.get(s)
            if a is None:
                continue
            acc: dict = {}
            for d in a.expr.free_symbols:
                ds = Dl.get(d) if d in Dl else (D.get(d) if outer else None)
                if not ds:
                    continue
                part = _clean(sp.diff(a.expr, d))
                if part == 0:
                    continue
                for j, dj in ds.items():
                    acc[j] = acc[j] + part * dj if j in acc else part * dj
            dv = {}
            for j, v in sorted(acc.items()):
                if v == 0:
                    continue
                if _trivial(v):
                    dv[j] = v
                else:
                    sym = _sym(f"{prefix}{next(counter)}")
                    jac_assign.append(Assignment(sym, v, ""))
                    dv[j] = sym
            Dl[s] = dv
        out = []
        for e in exprs_of:
            acc = {}
            for d in e.free_symbols:
                ds = Dl.get(d) if d in Dl else (D.get(d) if outer else None)
                if not ds:
                    continue
                part = _clean(sp.diff(e, d))
                for j, dj in ds.items():
                    acc[j] = acc[j] + part * dj if j in acc else part * dj
            out.append({j: v for j, v in acc.items() if v != 0})
        return out

    for a in used:
        if isinstance(a.expr, NewtonSolve):
            # implicit function theorem at the solution: (I - dg/dz) dz = dg/dx (z held)
            nl = nloops[int(a.expr.args[0])]
            n = len(nl.tear)
            gx = local({t: {} for t in nl.tear}, nl.g, nl.rest, True)
            gz = local({t: {i: sp.Integer(1)} for i, t in enumerate(nl.tear)}, nl.g, nl.rest,
                       False)
            A = [(1 if i == k else 0) - gz[i].get(k, 0) for i in range(n) for k in range(n)]
            solves[a.symbol] = {}
            for j in sorted(set().union(*gx)):
                s = _sym(f"{prefix}{next(counter)}")
                jac_assign.append(Assignment(s, LinSolve(n, *A, *[gx[i].get(j, 0)
                                                                  for i in range(n)]), ""))
                solves[a.symbol][j] = s
            continue
        if isinstance(a.expr, LinSolve):
            # d(A^-1 b) = A^-1 (db - dA x): one more solve with the same matrix per column
            n = int(a.expr.args[0])
            A, b = a.expr.args[1:1 + n * n], a.expr.args[1 + n * n:]
            x = [LinSolveEntry(a.symbol, i) for i in range(n)]
            gA, gb = [grad(v) for v in A], [grad(v) for v in b]
            cols = sorted(set().union(*gA, *gb))
            solves[a.symbol] = {}
            for j in cols:
                r = [gb[i].get(j, 0) - sum((gA[i * n + k].get(j, 0) * x[k] for k in range(n)),
                                           sp.Integer(0)) for i in range(n)]
                s = _sym(f"{prefix}{next(counter)}")
                jac_assign.append(Assignment(s, LinSolve(n, *A, *r), ""))
                solves[a.symbol][j] = s
            continue
        if isinstance(a.expr, LinSolveEntry):
            X, i = a.expr.args
            dv = {}
            for j, s in solves.get(X, {}).items():
                d = _sym(f"{prefix}{next(counter)}")
                jac_assign.append(Assignment(d, LinSolveEntry(s, i), ""))
                dv[j] = d
            if dv:
                D[a.symbol] = dv
            continue
        g = grad(a.expr)
        if not g:
            continue
        dv = {}
        for j, v in sorted(g.items()):
            if _trivial(v):
                dv[j] = v
            else:
                s = _sym(f"{prefix}{next(counter)}")
                jac_assign.append(Assignment(s, v, ""))
                dv[j] = s
        D[a.symbol] = dv
    out = {}
    for i, expr in enumerate(finals):
        for j, v in grad(expr).items():
            out[(i, j)] = v
    return out, jac_assign


def _check_names(bg: BondGraph, ctx: _Ctx, state_vars) -> None:
    """Generated identifiers must not collide (e.g. a parameter named like a bond variable):
    the error is placed at the user's name (a parameter or input is what can be renamed)."""
    pcoord = {fp.id: fp.coord for fp in bg.params}
    icoord = {i.name: i.coord for i in getattr(bg.model, "inputs", ())}
    seen: dict[str, str] = {}
    pairs = []  # (identifier, who, coord of the declaration or None)
    for pv in ctx.params.values():
        pairs += [(str(s), f"parameter {pv.id!r}", pcoord.get(pv.id)) for s in pv.symbols]
    for k in ctx.derived:
        pairs.append((k, "derived parameter", pcoord.get(k)))
    for sv in state_vars:
        pairs.append((str(sv.symbol), f"state {sv.name!r}", None))
    for b in bg.bonds:
        pairs += [(str(s), f"bond {b.id!r}", None) for s in flat(ctx.e[b.id]) + flat(ctx.f[b.id])]
    for iv in ctx.inputs.values():
        pairs += [(str(s), f"input {iv.name!r}", icoord.get(iv.name)) for s in iv.symbols]
    where: dict[str, object] = {}
    for ident, who, coord in pairs:
        if ident in seen and seen[ident] != who:
            at = where.get(ident) or coord or bg.model.coord  # the parameter, if one
            raise ModelError(at, f"name clash in generated code: {who} and "
                                 f"{seen[ident]} both become {ident!r}; rename one")
        seen[ident] = who
        if coord is not None:
            where[ident] = coord


# ---------------------------------------------------------------------------------------------
# Linearisation: the derivatives of rhs with respect to the inputs (B) and of the outputs with
# respect to the states and the inputs (C, D), in forward mode along the same assignments as
# the state Jacobian. Computed on demand (emit asks for them), so derive() is unchanged.


@dataclass(frozen=True)
class LinearParts:
    """Nonzero entries of B = d(rhs)/du, C = d(y)/dx, D = d(y)/du, keyed (row, column), with
    the forward-mode intermediates each needs. Inputs are flattened in INPUT_NAMES order (a
    vector input contributes its components in order), outputs in OUTPUT_NAMES order (each
    output's components in row-major order)."""

    B: dict
    B_assignments: tuple[Assignment, ...]
    C: dict
    D: dict
    CD_assignments: tuple[Assignment, ...]
    input_labels: tuple[str, ...]
    output_labels: tuple[str, ...]


def _label(name: str, shape, k: int) -> str:
    if not shape:
        return name
    if len(shape) == 1:
        return f"{name}[{k}]"
    return f"{name}[{k // shape[1]},{k % shape[1]}]"


def linear_parts(eq: Equations) -> LinearParts:
    """B, C and D of the linearisation (A is ``eq.jacobian``)."""
    useeds = {}
    ilabels = []
    for iv in eq.inputs:
        for k, s in enumerate(iv.symbols):
            useeds[s] = len(ilabels)
            ilabels.append(_label(iv.name, iv.shape, k))
    xseeds = {sv.symbol: j for j, sv in enumerate(eq.states)}
    youts, olabels = [], []
    for name, shp, vals in eq.outputs:
        for k, v in enumerate(vals):
            youts.append(v)
            olabels.append(_label(name, shp, k))
    kept = list(eq.assignments)
    nloops = tuple(getattr(eq, "newton", ()))
    B, b_assign = forward_mode(kept, useeds, list(eq.derivatives), "_du", nloops)
    C, c_assign = forward_mode(kept, xseeds, youts, "_dx", nloops)
    D, d_assign = forward_mode(kept, useeds, youts, "_du", nloops)
    # B's and D's intermediates share a prefix: they live in different generated functions
    # except D's, which sits beside C's (prefix _dx): no clash inside one function.
    return LinearParts(B, tuple(b_assign), C, D, tuple(c_assign) + tuple(d_assign),
                       tuple(ilabels), tuple(olabels))
