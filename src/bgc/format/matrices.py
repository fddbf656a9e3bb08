"""Matrix arithmetic on sympy entries, entry by entry: the entries sympy's own matrices give.

sympy's immutable matrices add, scale and multiply through its DomainMatrix machinery (domain
unification, a sparse representation, a conversion back), which costs more than the
arithmetic for the small matrices of a model's laws (3-vectors, rotation matrices). These
functions do the same arithmetic directly on the flat list of entries, with the same scalar
operation sympy's sparse representation applies to each stored (nonzero) entry: ``x + y``,
``x * s`` (``s * x`` for a scalar on the left), ``x * -1``; a zero entry is not stored there,
so it is skipped here too, and a product with a zero factor is the zero it makes (unless the
other factor may be infinite, which is then multiplied as sympy would). The results are
equal, entry for entry and in form, to sympy's (tests/test_matrices.py holds them to it);
the matrices are built without re-checking entries that are sympy objects already, and the
entries' products and sums by bgc.format.arith (sympy's constructors' results, directly).
"""
from __future__ import annotations

import sympy as sp

from bgc.format.arith import plus, times, total

_ZERO = sp.S.Zero
_ONE = sp.S.One
_NEG = sp.S.NegativeOne
_new = sp.ImmutableMatrix._new
_Dense = sp.ImmutableDenseMatrix
_Tuple = sp.Tuple


def matrix(rows: int, cols: int, entries) -> sp.ImmutableMatrix:
    """An immutable matrix of sympy entries (row by row), without sympy's input checks."""
    return _new(rows, cols, list(entries), copy=False)


def entries(m) -> list:
    """The flat entries of a matrix, row by row (an immutable dense matrix holds them as its
    third argument, sympy objects already: read there, without converting its representation)."""
    if type(m) is _Dense:
        args = m.args
        if len(args) == 3 and type(args[2]) is _Tuple:
            return list(args[2].args)
    return m.flat()


def add(a, b) -> sp.ImmutableMatrix:
    """``a + b`` of two matrices of one shape."""
    return matrix(a.rows, a.cols, [y if x is _ZERO else x if y is _ZERO else plus(x, y)
                                   for x, y in zip(entries(a), entries(b))])


def neg(a) -> sp.ImmutableMatrix:
    """``-a``."""
    return matrix(a.rows, a.cols, [x if x is _ZERO else times(x, _NEG) for x in entries(a)])


def sub(a, b) -> sp.ImmutableMatrix:
    """``a - b`` (sympy's ``a + (-b)``)."""
    return add(a, neg(b))


def scale(a, s, left: bool = False) -> sp.ImmutableMatrix:
    """``a * s`` (``s * a`` with ``left``) for a sympy scalar ``s``."""
    s = sp.sympify(s)
    if s is _ZERO:
        return matrix(a.rows, a.cols, [_ZERO] * (a.rows * a.cols))
    if s is _ONE:
        return a
    if left:
        return matrix(a.rows, a.cols, [x if x is _ZERO else times(s, x) for x in entries(a)])
    return matrix(a.rows, a.cols, [x if x is _ZERO else times(x, s) for x in entries(a)])


def _skip(x, y) -> bool:
    """A product that is the zero it makes: a zero factor, and no factor of the other that
    may be infinite (what sympy's ``Mul(0, y)`` asks: else it is nan)."""
    if x is _ZERO:
        return not any(c.is_finite is False for c in (y.args if y.is_Mul else (y,)))
    return y is _ZERO and _skip(y, x)


def matmul(a, b) -> sp.ImmutableMatrix:
    """The matrix product as sums of products, entry by entry (sympy's own canonical sums),
    the products with a zero factor left out."""
    n, k = a.shape
    m = b.shape[1]
    fa, fb = entries(a), entries(b)
    out = []
    for i in range(n):
        row = fa[i * k:(i + 1) * k]
        for j in range(m):
            terms = [times(x, y) for x, y in zip(row, fb[j::m]) if not _skip(x, y)]
            out.append(total(terms) if len(terms) != 1 else terms[0])
    return matrix(n, m, out)
