"""sympy's canonical products and sums, built directly where their form is known.

``Mul`` and ``Add`` find their canonical form by collecting like factors and terms, then
sorting them; most of their cost is the general machinery around that (sympification, the
cache, the many special cases of numbers, infinities, orders and non-commutative factors).
For the operands a model's expressions are mostly made of the result is plain:

* :func:`times`: a product of finite rational or float coefficients, commutative plain
  symbols raised to integer powers, and sums (only without any numeric coefficient, where no
  distribution happens), each base at most once except a symbol's powers, whose exponents
  add: the coefficient (if not 1) first, then the factors in ``Mul``'s own order
  (``_mulsort``).
* :func:`total`: a sum of commutative terms, none of them a number, no two alike (the same
  factors but for the coefficient): the terms (nested sums flattened) in ``Add``'s own order
  (``_addsort``).

Anything else goes to sympy's constructors, so the result is always exactly theirs
(tests/test_arith.py holds both to them, in form). bgc.core.canon does the same for the plain
sums and products of a large linear network's equations.
"""
from __future__ import annotations

import sympy as sp

try:  # the constructors' own sorts
    from sympy.core.add import _addsort
    from sympy.core.mul import _mulsort
except ImportError:  # pragma: no cover - a sympy without them: always the constructors
    _addsort = _mulsort = None

_ONE = sp.S.One
_Symbol = sp.Symbol
_Mul, _Add, _Pow, _Integer = sp.Mul, sp.Add, sp.Pow, sp.Integer


def times(a, b):
    """``a * b``."""
    out = _times(a, b) if _mulsort is not None else None
    return a * b if out is None else out


def _times(a, b):  # noqa: C901 - one case per kind of factor
    coeff = _ONE
    numbers = has_add = False
    exps: dict = {}  # base -> integer exponent (a sum's: 1)
    first: dict = {}  # base -> the factor as given (kept where its exponent is unchanged)
    for o in (a, b):
        for f in (o.args if o.is_Mul else (o,)):
            if f.is_Number:
                if not (f.is_Rational or f.is_Float) or f.is_zero:
                    return None
                coeff = coeff * f
                numbers = True
                continue
            if type(f) is _Symbol:
                base, e = f, 1
            elif f.is_Pow and type(f.args[0]) is _Symbol and f.args[1].is_Integer:
                base, e = f.args[0], int(f.args[1])
            elif f.is_Add:
                base, e = f, 1
                has_add = True
            else:
                return None
            if not base.is_commutative:
                return None
            if base in exps:
                if base.is_Add:
                    return None
                exps[base] += e
            else:
                exps[base] = e
                first[base] = f
    if has_add and numbers:  # (sympy distributes a number over a sum)
        return None
    factors = []
    for base, e in exps.items():
        f = first[base]
        if e == 0:
            continue
        if f is base or not f.is_Pow:
            factors.append(base if e == 1 else _Pow(base, _Integer(e)))
        else:
            factors.append(f if f.args[1] == e else base if e == 1 else _Pow(base, _Integer(e)))
    if not factors:
        return coeff
    if len(factors) == 1 and coeff is _ONE:
        return factors[0]
    _mulsort(factors)
    return _Mul._from_args([coeff] + factors if coeff is not _ONE else factors)


def total(terms):
    """``Add(*terms)``."""
    out = _total(terms) if _addsort is not None else None
    return _Add(*terms) if out is None else out


def plus(a, b):
    """``a + b``."""
    out = _total((a, b)) if _addsort is not None else None
    return a + b if out is None else out


def _total(terms):
    flat = []
    for t in terms:
        if t.is_Add:
            flat.extend(t.args)
        else:
            flat.append(t)
    if len(flat) < 2:
        return None
    seen = set()
    for t in flat:
        if t.is_Number or t.is_Order or not t.is_commutative or (
                t.is_Pow and t.args[0].is_Number) or not isinstance(t, sp.Expr) or (
                isinstance(t, sp.MatrixExpr)):
            return None
        key = (t.args[1:] if t.args[0].is_Number else t.args) if t.is_Mul else (t,)
        if key in seen:
            return None
        seen.add(key)
    _addsort(flat)
    return _Add._from_args(flat)
