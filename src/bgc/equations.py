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

import networkx as nx
import sympy as sp

from .causality import Causality
from . import fastsym
from .errors import Coord, ModelError
from .expr import Expr, build, shape_of
from .graph import BondGraph, FlatElement, code_name, join
from .parse import TWO_PORTS

T = sp.Symbol("t", real=True)


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
                rows, cols = len(fp.value), len(fp.value[0])
                shape = (rows,) if cols == 1 else (rows, cols)
                if cols == 1 and rows == 1:
                    shape = ()
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
            raise ModelError(coord, f"{self.what}: {head!r} is a {kind}: it has no "
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
                                    f"{'.'.join(path)!r} is a {kind}")
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
        raise ModelError(coord, f"{self.what}: {'.'.join(path)!r} is a {kind}, not a value")

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
                    raise ModelError(coord, f"{self.what}: {func}() takes an {want} element, "
                                            f"{ident!r} is a {el.type}")
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
                                    f"{'.'.join(path)!r} is a {kind}")
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
        if shape_of(default) != shape_of(syms):
            raise ModelError(inp.default.coord, f"input {name!r}: default has shape "
                                                f"{_shape_name(shape_of(default))}, declared "
                                                f"{_shape_name(shape_of(syms))}")
        self.inputs[name] = InputVar(name, tuple(flat(syms)), inp.shape, tuple(flat(default)))
        self.cache[("input", name)] = syms
    elif self.inputs[name] is None:
        raise ModelError(coord, f"input {name!r} refers to itself")
    return self.cache[("input", name)]


_Ctx.inputs_value = _inputs_value


# ---------------------------------------------------------------------------------------------


def _zeros(n):
    return sp.Integer(0) if n == 1 else sp.ImmutableMatrix(sp.zeros(n, 1))


def _fold_value(v):
    if isinstance(v, tuple):
        if len(v) == 1 and len(v[0]) == 1:
            return sp.Float(v[0][0])
        return sp.ImmutableMatrix([[sp.Float(c) for c in row] for row in v])
    return sp.Float(v)


def derive(bg: BondGraph, caus: Causality, progress=None, fold: dict | None = None,
           zero: dict | None = None) -> Equations:
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
        if shape_of(var) != shape_of(value):
            raise ModelError(el.coord, f"{el.type} {el.id!r}: cardinality mismatch: its law "
                                       f"gives {_shape_name(shape_of(value))}, its bond "
                                       f"carries {_shape_name(shape_of(var))}")
        for s, v in zip(flat(var), flat(value)):
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

    if progress:
        progress("ordering assignments")
    order, loops = _causal_order(bg, defs, owner)
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
    jac, jac_assign = _jacobian(kept, state_vars, derivatives)
    _check_names(bg, ctx, state_vars)
    return Equations(bg.model.name, tuple(state_vars), tuple(ctx.params.values()),
                     tuple(ctx_derived), tuple(ctx.inputs[i.name] for i in bg.model.inputs),
                     tuple(kept), derivatives, outputs, jac, tuple(jac_assign), tuple(loops))


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
            raise ModelError(el.coord, f"{what} is in derivative causality")
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


def _causal_order(bg: BondGraph, defs: dict, owner: dict):
    """Assignments in causal order; algebraic loops solved where linear."""
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
        els = sorted({owner[s] for s in comp})
        desc = ", ".join(_kind(bg.element(e)) for e in els)
        eqs = [s - defs[s].expr for s in comp]
        try:
            A, rhs = sp.linear_eq_to_matrix(eqs, comp)
        except (sp.polys.polyerrors.PolynomialError, ValueError, TypeError):
            A = None
        if A is None or any(A.has(s) for s in comp):
            raise ModelError(bg.element(els[0]).coord,
                             f"algebraic loop through {desc} is nonlinear in its unknowns "
                             f"({', '.join(map(str, comp[:6]))}); bgc solves linear loops only: "
                             "add a storage element (e.g. a small C or I) to break it")
        if len(comp) > 60:
            raise ModelError(bg.element(els[0]).coord, f"algebraic loop through {desc} has "
                                                       f"{len(comp)} unknowns (limit 60)")
        sol = A.LUsolve(rhs)
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


def _jacobian(kept: list[Assignment], state_vars, derivatives):
    """Forward-mode Jacobian along the causal assignments.

    D[v] maps a state index j to dv/dx_j. Non-trivial entries become new intermediates
    (``_d<k>``), so every emitted expression stays as small as one assignment's.
    """
    D: dict[sp.Symbol, dict[int, object]] = {}
    for j, sv in enumerate(state_vars):
        D[sv.symbol] = {j: sp.Integer(1)}
    jac_assign: list[Assignment] = []
    counter = itertools.count()

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

    for a in kept:
        g = grad(a.expr)
        if not g:
            continue
        dv = {}
        for j, v in sorted(g.items()):
            if _trivial(v):
                dv[j] = v
            else:
                s = _sym(f"_d{next(counter)}")
                jac_assign.append(Assignment(s, v, ""))
                dv[j] = s
        D[a.symbol] = dv
    jac = {}
    for i, expr in enumerate(derivatives):
        for j, v in grad(expr).items():
            jac[(i, j)] = v
    return jac, jac_assign


def _check_names(bg: BondGraph, ctx: _Ctx, state_vars) -> None:
    """Generated identifiers must not collide (e.g. a parameter named like a bond variable)."""
    seen: dict[str, str] = {}
    pairs = []
    for pv in ctx.params.values():
        pairs += [(str(s), f"parameter {pv.id!r}") for s in pv.symbols]
    for k in ctx.derived:
        pairs.append((k, "derived parameter"))
    for sv in state_vars:
        pairs.append((str(sv.symbol), f"state {sv.name!r}"))
    for b in bg.bonds:
        pairs += [(str(s), f"bond {b.id!r}") for s in flat(ctx.e[b.id]) + flat(ctx.f[b.id])]
    for iv in ctx.inputs.values():
        pairs += [(str(s), f"input {iv.name!r}") for s in iv.symbols]
    for ident, who in pairs:
        if ident in seen and seen[ident] != who:
            raise ModelError(bg.model.coord, f"name clash in generated code: {who} and "
                                             f"{seen[ident]} both become {ident!r}; rename one")
        seen[ident] = who
