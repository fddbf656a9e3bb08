"""Each element's equations: the constitutive laws of sources, storage and resistors, the
junctions' balances and the two-ports' transformations, in the form causality gives them.

``element_equations`` defines, through the ``define`` callback of the derivation, the variables
causality makes the element responsible for; a storage element in derivative causality gets
its state as an assignment and a placeholder for its time derivative (bgc.core.loops defines
it). Shapes are checked against the bonds' cardinalities here, with messages at the element.
"""
from __future__ import annotations

import sympy as sp

from bgc.base.errors import ModelError
from bgc.core.canon import quotient
from bgc.core.constraints import constraint_source
from bgc.core.context import Context
from bgc.core.eqtypes import StateVar, flat, shape_name, symbol_vector
from bgc.core.graph import FlatElement, code_name
from bgc.format.arith import times
from bgc.format.expr import shape_of
from bgc.format.matrices import matmul, matrix, neg, scale
from bgc.format.parse import TWO_PORTS

_BAD_VALUES = (sp.zoo, sp.oo, -sp.oo, sp.nan, sp.I)

try:  # Add's canonical order of its terms (sympy's own sort; signed_sum below)
    from sympy.core.add import _addsort
except ImportError:  # pragma: no cover - a sympy without it: the general constructor
    _addsort = None


_BAD_SET = frozenset(_BAD_VALUES)
#: The nodes whose free symbols are their symbols' and whose bad values are their atoms: an
#: expression made only of these is checked in one walk (below).
_PLAIN = (sp.Add, sp.Mul, sp.Pow)


def _plain_walk(v, targets: set):
    """(any bad value, any target read) of an expression of sums, products, powers, symbols
    and numbers, in one walk; None for anything else (a function, a matrix...), which the
    general check handles. The same answers as ``has`` and ``free_symbols``, for the junction
    balances and constitutive laws that are most of a large model's equations."""
    bad = own = False
    stack = [v]
    while stack:
        x = stack.pop()
        if x.is_Symbol:
            own = own or x in targets
        elif x.is_Atom:
            bad = bad or x in _BAD_SET
        elif isinstance(x, _PLAIN):
            stack.extend(x.args)
        else:
            return None
    return bad, own


def check_value(v, el: FlatElement, targets: set) -> None:
    """An element's equation must be finite and real, and must not read what it defines."""
    quick = _plain_walk(v, targets)
    if quick == (False, False):
        return
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


def element_equations(ctx: Context, el: FlatElement, define, derivs, state_vars):
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
        val = _card(ctx.build(law, el.scope, what), n, el, key)
        if el.id in caus.constraints:
            closure = (_card(ctx.build(el.closure, el.scope, f"{what} (closure)"), n, el,
                             "closure") if el.closure is not None else None)
            constraint_source(ctx, el, b, val, define, closure)
            return
        if el.closure is not None:
            raise ModelError(el.closure.coord, f"{what}: a closure (position residual) is given, "
                             "but the source closes no kinematic loop: it is an ordinary flow "
                             "source; remove the closure")
        define(f, val, el, f"{el.id} (Sf): flow")
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
            rate = _signed(e, sgn)
        else:
            if key == "stiffness":
                k = _card(ctx.build(law, el.scope, what), n, el, key, square=True)
                val = _times(k, state)
            elif key == "compliance":
                c = _card(ctx.build(law, el.scope, what), n, el, key, square=True)
                val = _solve(c, state, el, key)
            else:
                val = _card(ctx.build(law, el.scope, what, local={"q": state}), n, el, key)
            define(e, _signed(val, sgn), el, f"{el.id} (C, integral): effort from displacement")
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
        fe, ff = _signed(e, sgn), f  # the element's own effort and flow
        if key == "resistance":
            r = _card(ctx.build(law, el.scope, what), n, el, key, square=True)
            if sets_effort:
                define(e, _signed(_times(r, ff), sgn), el, f"{el.id} (R): effort = r f")
            else:
                define(f, _solve(r, fe, el, key), el, f"{el.id} (R): flow = e / r")
        elif key == "effort":
            val = _card(ctx.build(law, el.scope, what, local={"f": ff}), n, el, key)
            define(e, _signed(val, sgn), el, f"{el.id} (R): effort law")
        else:
            val = _card(ctx.build(law, el.scope, what, local={"e": fe}), n, el, key)
            define(f, val, el, f"{el.id} (R): flow law")
        return
    raise ModelError(el.coord, f"unsupported element type {t}")  # pragma: no cover


def _dependent_storage(ctx: Context, el: FlatElement, b, sgn: int, define):
    """A storage element in derivative causality: its state is a function of the others'.

    An I receives its flow f: its momentum p = M f is an assignment and its effort is dp/dt;
    a C receives its effort e: q = K^-1 e (or c e) and its flow is dq/dt. The time derivative
    is a placeholder symbol ``dt_<p or q>`` that ``time_derivatives`` defines by the chain
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
        val = _times(m, f)
    else:
        if key == "stiffness":
            k = _card(ctx.build(law, el.scope, what), n, el, key, square=True)
            val = _solve(k, _signed(e, sgn), el, key)
        elif key == "compliance":
            val = _times(_card(ctx.build(law, el.scope, what), n, el, key, square=True),
                         _signed(e, sgn))
        else:
            raise ModelError(el.coord, f"{what} is in derivative causality (its effort follows "
                                       "from the other states), which needs its displacement as "
                                       "a function of its effort: give it a `stiffness:` or "
                                       "`compliance:` law, not `effort:`")
    state = symbol_vector(f"{letter}_{code_name(el.id)}", n)
    dot = symbol_vector(f"_dt_{letter}_{code_name(el.id)}", n)
    define(state, val, el, f"{el.id} ({t}, derivative): {'momentum from flow' if t == 'I' else 'displacement from effort'}")
    if t == "I":
        define(e, _signed(dot, sgn), el, f"{el.id} (I, derivative): effort = dp/dt")
    else:
        define(f, dot, el, f"{el.id} (C, derivative): flow = dq/dt")
    ctx.states[el.id] = state  # p() / q() read the dependent state
    ctx.dependent.append((el.id, tuple(flat(state)), tuple(flat(dot))))


def _signed(v, sgn: int):
    """``v * sgn`` for a sign +1 or -1 (a matrix entry by entry, as sympy's matrices)."""
    if sgn == 1:
        return v
    return neg(v) if shape_of(v) else times(v, sp.S.NegativeOne)


def _times(a, b):
    """``a * b``: a matrix product (bgc.format.matrices.matmul: sympy's entries), a scalar
    times a matrix, or a product of scalars."""
    if shape_of(a):
        return matmul(a, b) if shape_of(b) else scale(a, b)
    return scale(b, a, left=True) if shape_of(b) else times(a, b)


def _eye_times(val, n: int):
    """``val * eye(n)`` of a scalar ``val``: ``val`` on the diagonal (sympy's entries)."""
    if val == 0 or val == 1:  # (sympy's scaling gives zeros, or the identity, for these)
        val = sp.S.Zero if val == 0 else sp.S.One
    return matrix(n, n, [val if i == j else sp.S.Zero for i in range(n) for j in range(n)])


def _card(val, n, el, key, square=False):
    """Check a law's shape against the bond's cardinality n."""
    s = shape_of(val)
    if n == 1:
        if s in ((), (1, 1)):
            return val[0] if s else val
    elif square:
        if s == ():
            return _eye_times(val, n)
        if s == (n, n):
            return val
    elif s == (n, 1):
        return val
    want = "scalar" if n == 1 else (f"a scalar or a {n}x{n} matrix" if square else f"a {n}-vector")
    raise ModelError(el.coord, f"{el.type} {el.id!r}: cardinality mismatch: {key} is "
                               f"{shape_name(s)}, the bond (n={n}) needs {want}")


def _solve(m, rhs, el, key):
    """m^-1 rhs for a scalar or a small matrix (adjugate over determinant)."""
    if not shape_of(m):
        if m == 0:
            raise ModelError(el.coord, f"{el.type} {el.id!r}: its {key} is zero and must be "
                                       "inverted here (a division by zero)")
        return quotient(rhs, m)
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


def _junction(ctx: Context, el: FlatElement, bonds, define):
    caus = ctx.caus
    if el.type == "0":
        src = next(b for b in bonds if caus.effort_by[b.id] != el.id)
        for b in bonds:
            if b is not src:
                define(ctx.e[b.id], ctx.e[src.id], el, f"0-junction {el.id}: common effort")
        # flows: sum in = sum out, solved for the imposing bond's flow
        define(ctx.f[src.id], _balance(ctx.f, el, bonds, src), el,
               f"0-junction {el.id}: flow balance")
    else:
        src = next(b for b in bonds if caus.effort_by[b.id] == el.id)
        for b in bonds:
            if b is not src:
                define(ctx.f[b.id], ctx.f[src.id], el, f"1-junction {el.id}: common flow")
        define(ctx.e[src.id], _balance(ctx.e, el, bonds, src), el,
               f"1-junction {el.id}: effort balance")


def _balance(var: dict, el, bonds, src):
    """A junction's balance solved for the imposing bond ``src``'s variable: the sum of the
    others' (``var``: bond id -> effort or flow), each signed by its direction. Scalar bonds
    build the sum as one Add of the signed terms (the same canonical expression as adding them
    one by one and negating the total, in one constructor call instead of one per bond: the
    per-bond sums and the negated total were most of a large ladder's junctions)."""
    out = src.dst == el.id  # the others' sum as it stands (else negated)
    terms = [(var[b.id], (b.src == el.id) == out) for b in bonds if b is not src]
    if src.n == 1:
        return signed_sum(terms)
    # a multibond's balance, component by component: the entries of the matrices' sum
    return matrix(src.n, 1, [signed_sum([(v[i], pos) for v, pos in terms])
                             for i in range(src.n)])


def signed_sum(terms) -> sp.Expr:
    """The sum of ``(value, positive)`` terms, exactly ``sp.Add(*[v or -v])``. Distinct plain
    symbols (a junction's bond variables) skip Add's and Mul's canonicalisation: their
    canonical sum is its terms (``-s`` as sympy writes it, -1 first) in Add's own order, which
    is built here directly (tests/test_junction_sums.py holds it to sympy's constructor)."""
    syms = [v for v, _ in terms]
    if (_addsort is None or len(terms) < 2 or any(type(v) is not sp.Symbol for v in syms)
            or len(set(syms)) != len(syms)):
        return sp.Add(*[v if pos else -v for v, pos in terms])
    args = [v if pos else sp.Mul._from_args((sp.S.NegativeOne, v)) for v, pos in terms]
    _addsort(args)
    return sp.Add._from_args(args)


def _two_port(ctx: Context, el: FlatElement, bonds, define):
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
            m = _eye_times(m, n1)
    elif s != (n2, n1):
        raise ModelError(el.coord, f"{what}: cardinality mismatch: {key} is {shape_name(s)}, "
                                   f"its bonds need {n2}x{n1} (out x in)")
    mt = m.T if shape_of(m) else m
    e1, f1, e2, f2 = ctx.e[b1.id], ctx.f[b1.id], ctx.e[b2.id], ctx.f[b2.id]
    forward = ctx.caus.effort_by[b1.id] == el.id
    if el.type in ("TF", "MTF"):
        if forward:
            define(f2, _times(m, f1), el, f"{el.id} ({el.type}): f2 = M f1")
            define(e1, _times(mt, e2), el, f"{el.id} ({el.type}): e1 = M^T e2")
        else:
            if n1 != n2:
                raise ModelError(el.coord, f"{what}: causality needs its {key} inverted, but it "
                                           f"is not square ({n2}x{n1})")
            define(f1, _solve(m, f2, el, key), el, f"{el.id} ({el.type}): f1 = M^-1 f2")
            define(e2, _solve(mt, e1, el, key), el, f"{el.id} ({el.type}): e2 = M^-T e1")
    else:
        if forward:  # the gyrator sets both efforts
            define(e2, _times(m, f1), el, f"{el.id} ({el.type}): e2 = M f1")
            define(e1, _times(mt, f2), el, f"{el.id} ({el.type}): e1 = M^T f2")
        else:
            if n1 != n2:
                raise ModelError(el.coord, f"{what}: causality needs its {key} inverted, but it "
                                           f"is not square ({n2}x{n1})")
            define(f1, _solve(m, e2, el, key), el, f"{el.id} ({el.type}): f1 = M^-1 e2")
            define(f2, _solve(mt, e1, el, key), el, f"{el.id} ({el.type}): f2 = M^-T e1")
