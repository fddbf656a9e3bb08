"""sympy's canonical products and sums, built directly where their form is known.

``Mul`` and ``Add`` find their canonical form by collecting like factors and terms, then
sorting them; most of their cost is the general machinery around that (sympification, the
cache, the many special cases of numbers, infinities, orders and non-commutative factors).
For the operands a model's expressions are mostly made of the result is plain:

* :func:`times`: a product of finite rational or float coefficients and commutative factors
  (symbols, sums, functions, powers), the integer exponents of a base met more than once
  added (as sympy's ``Pow`` makes the power); not where sympy distributes a number over a
  sum: the coefficient (if not 1) first, then the factors in ``Mul``'s own order
  (``_mulsort``). -1 times a sum is the sum of its terms negated, as sympy distributes it.
* :func:`total`: a sum of commutative terms, at most one of them a (finite, nonzero) number,
  no two alike (the same factors but for the coefficient): the number first, then the terms
  (nested sums flattened) in ``Add``'s own order (``_addsort``).

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
_NEG = sp.S.NegativeOne
_I = sp.S.ImaginaryUnit
_INFINITE = (sp.S.ComplexInfinity, sp.S.Infinity, sp.S.NegativeInfinity)
_Symbol = sp.Symbol
_Mul, _Add, _Pow, _Integer = sp.Mul, sp.Add, sp.Pow, sp.Integer


def times(a, b):
    """``a * b``."""
    out = _times(a, b) if _mulsort is not None else None
    return a * b if out is None else out


def _times(a, b):
    if a is _NEG and b.is_Add or b is _NEG and a.is_Add:  # -1 distributed over a sum
        return total([-t for t in (b if a is _NEG else a).args])
    coeff = _ONE
    has_add = False
    exps: dict = {}  # base -> its integer exponent (None: another exponent, met once)
    first: dict = {}  # base -> the factor as given (kept where it is met once)
    merged = set()  # the bases met more than once
    for o in (a, b):
        for f in (o.args if o.is_Mul else (o,)):
            if f.is_Number:
                if not (f.is_Rational or f.is_Float) or f.is_zero:
                    return None
                coeff = coeff * f
                continue
            if type(f) is _Symbol:
                base, e = f, 1
            else:  # a power, a sum, a function: its base and exponent as Mul sees them
                if f is _I or f.is_Order or isinstance(f, sp.MatrixExpr):
                    return None
                base, e = f.as_base_exp()
                if base.is_Number:
                    return None
                e = int(e) if e.is_Integer else None
                has_add = has_add or f.is_Add
            if not base.is_commutative:
                return None
            if base in exps:
                if e is None or exps[base] is None:
                    return None
                exps[base] += e
                merged.add(base)
            else:
                exps[base] = e
                first[base] = f
    if has_add and (a.is_Rational or b.is_Rational):  # (sympy's two-argument distribution)
        return None
    factors = []
    for base, e in exps.items():
        if base not in merged:
            factors.append(first[base])
        elif e == 0:
            if (base.is_Add or base.is_Mul) and any(i in base.args for i in _INFINITE):
                return None  # (sympy: nan)
        elif e == 1:
            factors.append(base)
        else:
            p = _Pow(base, _Integer(e))
            if not (p.is_Pow and p.args[0] == base):
                return None  # (a power that evaluates to something else)
            factors.append(p)
    if not factors:
        return coeff
    if coeff is not _ONE and len(factors) == 1 and factors[0].is_Add:  # (distributed)
        return None
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


def summed(terms):
    """``sum(terms, Integer(0))``: the terms added one by one, as Python's ``sum`` does."""
    out = None
    for t in terms:
        out = t if out is None else plus(out, t)  # (0 + t is t itself)
    return sp.S.Zero if out is None else out


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
    number = None
    for t in flat:
        if t.is_Number:  # one finite nonzero number at most: it goes first
            if number is not None or not (t.is_Rational or t.is_Float) or t.is_zero:
                return None
            number = t
            continue
        if t.is_Order or not t.is_commutative or (t.is_Pow and t.args[0].is_Number) or (
                not isinstance(t, sp.Expr)) or isinstance(t, sp.MatrixExpr):
            return None
        key = (t.args[1:] if t.args[0].is_Number else t.args) if t.is_Mul else (t,)
        if key in seen:
            return None
        seen.add(key)
    if number is not None:
        flat.remove(number)
    _addsort(flat)
    return _Add._from_args(flat if number is None else [number] + flat)
