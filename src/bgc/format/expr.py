"""Expressions as sympy objects, and the face of bgc.format's expression handling.

The checked syntax tree of an expression (bgc.format.whitelist: the parser and its whitelist,
re-exported here so that ``bgc.format.expr`` names everything about expressions) is turned into
sympy objects by :func:`build`, which asks a resolver for the meaning of each name, so name
resolution (parameters, states, bond variables) stays with the stage that knows them. Every
step is bounded (operations, matrix sizes, the size of numbers), and constants are evaluated in
double precision by :func:`numeric`, never by sympy's arbitrary-precision evaluation.
"""
from __future__ import annotations

import ast
import functools
import math
from typing import Callable, Protocol

from bgc.base.errors import Coord, ModelError
from bgc.base.limits import LIMITS
from bgc.format.whitelist import (
    BOND_FUNCTIONS,
    CONSTANTS,
    FUNCTIONS,
    HINTS,
    MAX_DEPTH,
    MAX_EXPONENT,
    Expr,
    check,
    dotted_path,
    int_const,
    node_coord,
    short_text,
)

__all__ = ["BOND_FUNCTIONS", "CONSTANTS", "FUNCTIONS", "HINTS", "MAX_DEPTH", "MAX_EXPONENT",
           "Expr", "Resolver", "build", "check", "dotted_path", "numeric", "shape_of"]


class _LazySympy:
    """sympy, imported on first use: parsing and checking a model or scene needs no sympy, so a
    warm `bgc simulate` (the module from the compile cache) never imports it."""

    def __getattr__(self, name):
        import sympy

        globals()["sp"] = sympy
        return getattr(sympy, name)


sp = _LazySympy()


# ---------------------------------------------------------------------------------------------
# Building sympy objects


class Resolver(Protocol):
    def value(self, path: tuple[str, ...], coord: Coord): ...

    def bond(self, func: str, path: tuple[str, ...], coord: Coord): ...


def shape_of(v) -> tuple[int, ...]:
    return tuple(v.shape) if isinstance(v, sp.MatrixBase) else ()


def _as_matrix(v):
    return v if isinstance(v, sp.MatrixBase) else sp.Matrix([[v]])


def build(expr: Expr, resolver: Resolver):
    """Turn a checked expression into a sympy scalar or an immutable sympy matrix."""
    try:
        return _Builder(expr, resolver).visit(expr.tree())
    except RecursionError:
        raise ModelError(expr.coord, "expression is nested too deeply") from None




def _finite(v, seen: set) -> bool:
    """No infinite or undefined value anywhere in ``v`` (``has(zoo, oo, -oo, nan)``, in one
    walk); ``seen``: the sub-expressions found finite before, not walked again."""
    bad = {sp.zoo, sp.oo, -sp.oo, sp.nan}
    items = _mat().entries(v) if isinstance(v, sp.MatrixBase) else (v,)
    stack = [x for x in items if isinstance(x, sp.Basic)]
    while stack:
        x = stack.pop()
        if x in seen:
            continue
        if not x.args and x in bad:
            return False
        seen.add(x)
        stack.extend(x.args)
    return True


def _too_big(v) -> bool:
    """An exact number too large to print, or a float beyond the double range."""
    limit = 10 ** MAX_EXPONENT
    items = _mat().entries(v) if isinstance(v, sp.MatrixBase) else (v,)
    for x in items:
        if isinstance(x, sp.Rational) and (abs(x.p) > limit or x.q > limit):
            return True
        if isinstance(x, sp.Float) and abs(x) > sp.Float(10) ** MAX_EXPONENT:
            return True
    return False


class _NumError(Exception):
    pass


NumError = _NumError  # what numeric() raises: "overflow", "complex" or "undefined"


_FLOAT_LIMIT = 10.0 ** MAX_EXPONENT


def _checked(x: float) -> float:
    if isinstance(x, complex):
        raise _NumError("complex")
    if x != x:
        raise _NumError("undefined")
    if not math.isfinite(x) or abs(x) > _FLOAT_LIMIT:
        raise _NumError("overflow")
    return x


def _pow(a: float, b: float) -> float:
    if a == 0 and b < 0:
        raise _NumError("undefined")
    if a < 0 and b != int(b):
        raise _NumError("complex")
    try:
        return math.pow(a, b)
    except OverflowError:
        raise _NumError("overflow") from None


@functools.lru_cache(maxsize=None)
def _tables():
    """sympy function -> its double-precision evaluation, and sympy relations -> operators
    (built on first use: importing this module must not import sympy, see __getattr__)."""
    math1 = {
        sp.exp: math.exp, sp.log: math.log, sp.sin: math.sin, sp.cos: math.cos,
        sp.tan: math.tan, sp.asin: math.asin, sp.acos: math.acos, sp.atan: math.atan,
        sp.sinh: math.sinh, sp.cosh: math.cosh, sp.tanh: math.tanh, sp.Abs: abs,
        sp.sign: lambda a: (a > 0) - (a < 0),
    }
    relations = {sp.StrictLessThan: lambda a, b: a < b, sp.LessThan: lambda a, b: a <= b,
                 sp.StrictGreaterThan: lambda a, b: a > b, sp.GreaterThan: lambda a, b: a >= b}
    return math1, relations


def numeric(v, memo: dict | None = None):
    """The value of a constant sympy expression in double precision, or None where it depends
    on a symbol (or holds a function this evaluator does not know). Raises :class:`_NumError`
    ("overflow", "complex", "undefined") where the constant is no finite real double: bounded
    work, where sympy's own evaluation of ``exp(exp(exp(100)))`` would not end."""
    memo = {} if memo is None else memo
    return _num(v, memo)


def _num(v, memo):
    try:
        return memo[v]
    except (KeyError, TypeError):
        pass
    x = _num1(v, memo)
    if x is not None:
        x = _checked(x)
    memo[v] = x
    return x


def _num1(v, memo):  # noqa: C901 - one case per sympy class
    if isinstance(v, (int, float)):
        return float(v)
    if v.is_Symbol:
        return None
    if not v.args and v in (sp.zoo, sp.nan, sp.oo, -sp.oo):  # (atoms: only they can be)
        raise _NumError("undefined" if v in (sp.zoo, sp.nan) else "overflow")
    if v is sp.I:
        raise _NumError("complex")
    if isinstance(v, sp.Rational):
        try:
            return v.p / v.q
        except OverflowError:
            raise _NumError("overflow") from None
    if isinstance(v, (sp.Float, sp.NumberSymbol)):
        return float(v)
    if isinstance(v, (sp.Add, sp.Mul, sp.Pow, sp.Min, sp.Max, sp.atan2, sp.Heaviside)) or (
            v.func in _tables()[0]):
        args = [_num(a, memo) for a in v.args]
        if any(a is None for a in args):
            return None
        try:
            if isinstance(v, sp.Add):
                return math.fsum(args)
            if isinstance(v, sp.Mul):
                out = 1.0
                for a in args:
                    out = _checked(out * a)
                return out
            if isinstance(v, sp.Pow):
                return _pow(*args)
            if isinstance(v, sp.Min):
                return min(args)
            if isinstance(v, sp.Max):
                return max(args)
            if isinstance(v, sp.atan2):
                return math.atan2(*args)
            if isinstance(v, sp.Heaviside):
                return 1.0 if args[0] > 0 else 0.0 if args[0] < 0 else args[1]
            if v.func in (sp.log,) and args[0] <= 0:
                raise _NumError("complex" if args[0] < 0 else "undefined")
            return _tables()[0][v.func](*args)
        except OverflowError:
            raise _NumError("overflow") from None
        except ValueError:  # math domain error: asin(2), acos(-3)
            raise _NumError("complex") from None
        except ZeroDivisionError:
            raise _NumError("undefined") from None
    if isinstance(v, sp.Piecewise):
        for val, cond in v.args:
            if cond is sp.true:
                return _num(val, memo)
            if type(cond) not in _tables()[1]:
                return None
            a, b = _num(cond.lhs, memo), _num(cond.rhs, memo)
            if a is None or b is None:
                return None
            if _tables()[1][type(cond)](a, b):
                return _num(val, memo)
        raise _NumError("undefined")
    return None


_NUM_MESSAGES = {
    "overflow": f"the constant is not a finite number (it overflows 10**{MAX_EXPONENT})",
    "complex": "the constant is complex, not real (a square root or logarithm of a negative "
               "number, or asin/acos beyond [-1, 1]?)",
    "undefined": "the expression is infinite or undefined (division by zero?)",
}


def _tree_size(v, limit: int) -> int:
    """The number of nodes of a sympy expression tree, counting stops past ``limit``."""
    n = 0
    stack = [v]
    while stack:
        x = stack.pop()
        n += 1
        if n > limit:
            return n
        stack.extend(x.args)
    return n


class _Builder:
    def __init__(self, expr: Expr, resolver: Resolver):
        self.expr = expr
        self.r = resolver
        self.memo: dict = {}  # constant sub-expression -> its double value (or None)
        self.finite: set = set()  # sub-expressions found free of infinities
        self.work = 0  # operations done so far (bounded by LIMITS.built_ops)

    def err(self, node, msg):
        what = getattr(self.r, "what", "")  # the resolver's name for the expression's owner
        return ModelError(node_coord(self.expr, node), f"{what}: {msg}" if what else msg)

    def _spend(self, node, amount: int) -> None:
        self.work += amount
        if self.work > LIMITS.built_ops:
            raise self.err(node, f"the expression expands into more than {LIMITS.built_ops} "
                                 "operations (the limit of symbolic work per expression)")

    def _shape_guard(self, node, v):
        if isinstance(v, sp.MatrixBase):
            r, c = v.shape
            if r > LIMITS.matrix_dim or c > LIMITS.matrix_dim or r * c > LIMITS.matrix_entries:
                raise self.err(node, f"a {r}x{c} matrix is larger than the limit of matrix size "
                                     f"({LIMITS.matrix_dim} rows or columns, "
                                     f"{LIMITS.matrix_entries} entries)")
            self._spend(node, r * c)
        return v

    def _number_guard(self, node, v):
        if not _finite(v, self.finite):
            raise self.err(node, "the expression is infinite or undefined (division by zero?)")
        if _too_big(v):
            raise self.err(node, f"a number larger than 10**{MAX_EXPONENT}")
        self._shape_guard(node, v)
        try:
            for x in (_mat().entries(v) if isinstance(v, sp.MatrixBase) else (v,)):
                numeric(x, self.memo)
        except _NumError as exc:
            raise self.err(node, _NUM_MESSAGES[str(exc)]) from None
        return v

    def visit(self, node):
        if isinstance(node, ast.Constant):
            v = node.value
            return sp.Integer(v) if type(v) is int else sp.Float(repr(v))
        if isinstance(node, (ast.Name, ast.Attribute)):
            path = dotted_path(node)
            if len(path) > 1 and path[-1] == "T":
                v = self.r.value(path[:-1], node_coord(self.expr, node))
                if not isinstance(v, sp.MatrixBase):
                    raise self.err(node, f"'{'.'.join(path[:-1])}' is a scalar: .T needs a matrix")
                return v.T
            if len(path) == 1 and path[0] in CONSTANTS:
                return CONSTANTS[path[0]]
            return self.r.value(path, node_coord(self.expr, node))
        if isinstance(node, ast.UnaryOp):
            v = self.visit(node.operand)
            if not isinstance(node.op, ast.USub):
                return v
            return _mat().neg(v) if isinstance(v, sp.MatrixBase) else -v
        if isinstance(node, ast.BinOp):
            return self._number_guard(node, self.binop(node))
        if isinstance(node, ast.List):
            return self._number_guard(node, self.listlit(node))
        if isinstance(node, ast.Subscript):
            return self.subscript(node)
        if isinstance(node, ast.Call):
            return self._number_guard(node, self.call(node))
        raise self.err(node, "not allowed")  # unreachable after check()

    def binop(self, node):
        a, b = self.visit(node.left), self.visit(node.right)
        sa, sb = shape_of(a), shape_of(b)
        op = node.op
        try:
            if isinstance(op, (ast.Add, ast.Sub)):
                if sa != sb:
                    raise self.err(node, f"shape mismatch: {_fmt(sa)} {'+' if isinstance(op, ast.Add) else '-'} {_fmt(sb)}")
                if sa:  # entry by entry (bgc.format.matrices: sympy's entries, directly)
                    return (_mat().add if isinstance(op, ast.Add) else _mat().sub)(a, b)
                return _ar().plus(a, b) if isinstance(op, ast.Add) else _ar().plus(a, -b)
            if isinstance(op, (ast.Mult, ast.MatMult)):
                if sa and sb:
                    if sa[1] != sb[0]:
                        raise self.err(node, f"shape mismatch in matrix product: {_fmt(sa)} times {_fmt(sb)}")
                    # Each entry of a is used by every column of b, each entry of b by every
                    # row of a: the product's size, paid before sympy builds it.
                    self._spend(node, sa[0] * sa[1] * sb[1])
                    self._spend(node, sb[1] * _tree_size(a, LIMITS.built_ops)
                                + sa[0] * _tree_size(b, LIMITS.built_ops))
                    return _mat().matmul(a, b)
                if isinstance(op, ast.MatMult):
                    raise self.err(node, "@ needs two matrices")
                if sa or sb:
                    return _mat().scale(a, b) if sa else _mat().scale(b, a, left=True)
                return a * b if a.is_Number and b.is_Number else _ar().times(a, b)
            if isinstance(op, ast.Div):
                if sb:
                    raise self.err(node, "division by a matrix (use inv())")
                if sa:
                    return _mat().scale(a, sp.S.One / b)
                if a.is_Number or b.is_Number or a is sp.S.One:
                    return a / b
                return _ar().times(a, sp.Pow(b, sp.S.NegativeOne))  # (sympy's a / b)
            if isinstance(op, ast.Pow):
                if sa or sb:
                    raise self.err(node, "** needs scalars")
                if isinstance(a, sp.Number) and isinstance(b, sp.Number) and a != 0 and (
                        abs(float(b)) * abs(math.log10(abs(float(a)))) > MAX_EXPONENT):
                    raise self.err(node, f"a number larger than 10**{MAX_EXPONENT}")
                if isinstance(b, sp.Number) and abs(b) > LIMITS.power_exponent:
                    raise self.err(node, f"exponent {short_text(str(b))} is larger than "
                                         f"{LIMITS.power_exponent} in magnitude (the limit of "
                                         "exponents)")
                return self._power_guard(node, a ** b)
        except ModelError:
            raise
        except Exception as exc:  # sympy shape errors
            raise self.err(node, f"invalid operation: {exc}") from None
        raise self.err(node, "operator not allowed")

    def _power_guard(self, node, v):
        """Refuse a power whose exponent sympy merged beyond the limit: ``((x**2)**2)...``
        150 deep is ``x**(2**150)``, which no double survives (and no printer can spell)."""
        for x in (v, *v.args) if isinstance(v, sp.Mul) else (v,):
            if isinstance(x, sp.Pow) and x.exp.is_Number and abs(x.exp) > LIMITS.power_exponent:
                raise self.err(node, f"a chain of powers makes the exponent "
                                     f"{short_text(str(x.exp))}, larger than "
                                     f"{LIMITS.power_exponent} in magnitude (the limit of "
                                     "exponents)")
        return v

    def listlit(self, node):
        items = [self.visit(e) for e in node.elts]
        shapes = {shape_of(i) for i in items}
        if shapes == {()}:
            return _mat().matrix(len(items), 1, items)
        if len(shapes) == 1:
            (s,) = shapes
            if len(s) == 2 and s[1] == 1:  # a list of column vectors: rows
                return sp.ImmutableMatrix([[v for v in item] for item in items])
        raise self.err(node, "a list holds scalars (a vector) or equal-length lists (a matrix)")

    def subscript(self, node):
        base = self.visit(node.value)
        if not isinstance(base, sp.MatrixBase):
            raise self.err(node, "indexing a scalar")
        idx = node.slice
        parts = idx.elts if isinstance(idx, ast.Tuple) else [idx]
        if len(parts) == 1:
            if base.shape[1] != 1 and base.shape[0] != 1:
                raise self.err(node, "a matrix needs two indices")
            flat = list(base)
            sl = self._index(parts[0], len(flat), node)
            if isinstance(sl, int):
                return flat[sl]
            return sp.ImmutableMatrix([flat[i] for i in range(len(flat))[sl]])
        r = self._index(parts[0], base.shape[0], node)
        c = self._index(parts[1], base.shape[1], node)
        if isinstance(r, int) and isinstance(c, int):
            return base[r, c]
        out = base[r, c]
        return sp.ImmutableMatrix(out) if isinstance(out, sp.MatrixBase) else sp.ImmutableMatrix([[out]])

    def _index(self, part, size, node):
        if isinstance(part, ast.Slice):
            lo = int_const(self.expr, part.lower) if part.lower is not None else None
            hi = int_const(self.expr, part.upper) if part.upper is not None else None
            return slice(lo, hi)
        i = int_const(self.expr, part)
        if not -size <= i < size:
            raise self.err(node, f"index {i} is out of range for size {size}")
        return i % size

    def call(self, node):
        name = node.func.id
        if name in BOND_FUNCTIONS:
            return self.r.bond(name, dotted_path(node.args[0]), node_coord(self.expr, node.args[0]))
        if name in ("eye", "zeros"):
            dims = [int_const(self.expr, a) for a in node.args]
            if any(d < 1 or d > LIMITS.matrix_dim for d in dims):
                raise self.err(node, f"{name}() size must be 1..{LIMITS.matrix_dim} (the limit "
                                     "of matrix size)")
            return sp.ImmutableMatrix(sp.eye(dims[0]) if name == "eye" else sp.zeros(*dims))
        if name == "where":
            cond = node.args[0]
            if not isinstance(cond, ast.Compare):
                raise self.err(node, "where(cond, a, b): the condition must be a comparison")
            lhs, rhs = self.visit(cond.left), self.visit(cond.comparators[0])
            if shape_of(lhs) or shape_of(rhs):
                raise self.err(node, "where(): the condition must compare scalars")
            op = type(cond.ops[0])
            a, b = self.visit(node.args[1]), self.visit(node.args[2])
            if shape_of(a) != shape_of(b):
                raise self.err(node, "where(): both branches must have the same shape")
            try:
                lv, rv = numeric(lhs, self.memo), numeric(rhs, self.memo)
            except _NumError as exc:
                raise self.err(cond, _NUM_MESSAGES[str(exc)]) from None
            if lv is not None and rv is not None:  # a constant condition: decided here, in
                # double precision (sympy would evaluate it to whatever precision it takes)
                holds = {ast.Lt: lv < rv, ast.LtE: lv <= rv, ast.Gt: lv > rv,
                         ast.GtE: lv >= rv}[op]
                return a if holds else b
            rel = {ast.Lt: sp.Lt, ast.LtE: sp.Le, ast.Gt: sp.Gt, ast.GtE: sp.Ge}[op]
            c = rel(lhs, rhs)
            if shape_of(a):
                return sp.ImmutableMatrix(a.shape[0], a.shape[1],
                                          [sp.Piecewise((x, c), (y, True)) for x, y in zip(a, b)])
            return sp.Piecewise((a, c), (b, True))
        args = [self.visit(a) for a in node.args]
        shapes = [shape_of(a) for a in args]
        fn = _funcs().get(name)
        if fn is not None:  # elementwise scalar functions
            if name in ("atan2", "min", "max"):
                if any(shapes):
                    raise self.err(node, f"{name}() takes scalars")
                return fn(*args)
            (a,) = args
            return a.applyfunc(fn) if shapes[0] else fn(a)
        try:
            return self.matrix_call(name, args, shapes, node)
        except ModelError:
            raise
        except Exception as exc:
            raise self.err(node, f"{name}(): {exc}") from None

    def matrix_call(self, name, args, shapes, node):
        vec3 = lambda i: shapes[i] == (3, 1)  # noqa: E731
        if name == "skew":
            if not vec3(0):
                raise self.err(node, "skew() needs a 3-vector")
            x, y, z = args[0]
            return sp.ImmutableMatrix([[0, -z, y], [z, 0, -x], [-y, x, 0]])
        if name == "cross":
            if not (vec3(0) and vec3(1)):
                raise self.err(node, "cross() needs two 3-vectors")
            return sp.ImmutableMatrix(args[0].cross(args[1]))
        if name == "dot":
            if not (shapes[0] and shapes[0] == shapes[1] and shapes[0][1] == 1):
                raise self.err(node, "dot() needs two vectors of the same length")
            return _ar().summed(_ar().times(a, b) for a, b in zip(args[0], args[1]))
        if name == "norm":  # Euclidean of a vector, Frobenius of a matrix
            if not shapes[0]:
                raise self.err(node, "norm() needs a vector or a matrix")
            return sp.sqrt(_ar().summed(a ** 2 for a in args[0]))
        if name == "transpose":
            return sp.ImmutableMatrix(_as_matrix(args[0]).T)
        if name == "diag":
            size = len(args[0]) if len(args) == 1 and shapes[0] else len(args)
            if size > LIMITS.matrix_dim:
                raise self.err(node, f"diag(): a {size}x{size} matrix is larger than the limit "
                                     f"of matrix size ({LIMITS.matrix_dim})")
            if len(args) == 1 and shapes[0] and shapes[0][1] == 1:
                return sp.ImmutableMatrix(sp.diag(*list(args[0])))
            if any(shapes):
                raise self.err(node, "diag() takes scalars or one vector")
            return sp.ImmutableMatrix(sp.diag(*args))
        if name in ("inv", "det"):
            m = args[0]
            if not shapes[0] or shapes[0][0] != shapes[0][1]:
                raise self.err(node, f"{name}() needs a square matrix")
            if shapes[0][0] > 4:
                raise self.err(node, f"{name}() is symbolic and limited to 4x4 matrices")
            self._spend(node, _tree_size(m, LIMITS.built_ops) * 24)
            if name == "det":
                return m.det(method="berkowitz")
            d = m.det(method="berkowitz")
            if d == 0:
                raise self.err(node, "inv(): the matrix is singular")
            return sp.ImmutableMatrix(m.adjugate() / d)
        if name == "heaviside":
            raise self.err(node, "heaviside() takes a scalar")
        raise self.err(node, f"unknown function {name!r}")


_FUNCS: dict[str, Callable] = {}


def _funcs() -> dict[str, Callable]:
    """The functions' sympy meanings (built on first use: sympy is imported lazily)."""
    if not _FUNCS:
        _FUNCS.update({
            "sin": sp.sin, "cos": sp.cos, "tan": sp.tan, "asin": sp.asin, "acos": sp.acos,
            "atan": sp.atan, "atan2": sp.atan2, "sinh": sp.sinh, "cosh": sp.cosh,
            "tanh": sp.tanh, "exp": sp.exp, "log": sp.log, "sqrt": sp.sqrt, "abs": sp.Abs,
            "sign": sp.sign, "min": sp.Min, "max": sp.Max,
            "heaviside": lambda a: sp.Heaviside(a, 1)})
    return _FUNCS


def _fmt(shape: tuple[int, ...]) -> str:
    return "scalar" if not shape else "x".join(map(str, shape))


def _ar():
    """bgc.format.arith (sympy's products and sums, directly), imported with sympy."""
    # lazy: it imports sympy, which parsing and checking a model never need
    from bgc.format import arith

    return arith


def _mat():
    """bgc.format.matrices (sympy's matrices entry by entry), imported with sympy on first use."""
    # lazy: it imports sympy, which parsing and checking a model never need
    from bgc.format import matrices

    return matrices
