"""sympy's canonical sums and products of plain operands, built without its constructors.

A large linear network's equations are mostly sums of signed bond variables and quotients of
two symbols (``e_b4 - e_b8``, ``e_b2/R``). sympy's ``Add`` and ``Mul`` constructors find their
canonical form by collecting like terms and powers, then sorting: for operands that are
distinct plain symbols (signed, or raised to an integer power) nothing collects, and the
canonical form is the operands in sympy's own order (``_addsort`` / ``_mulsort``, the sorts
the constructors end with), a numeric -1 first. :func:`add_of` and :func:`mul_of` build that
form directly and answer ``None`` for anything else, where the caller uses the constructor;
:func:`replaced` is ``expr.xreplace(rule)`` with them. tests/test_canon.py holds every result
to sympy's constructors, argument for argument.
"""
from __future__ import annotations

import sympy as sp

try:  # the constructors' own sorts
    from sympy.core.add import _addsort
    from sympy.core.mul import _mulsort
except ImportError:  # pragma: no cover - a sympy without them: always the constructors
    _addsort = _mulsort = None

_NEG = sp.S.NegativeOne
_Symbol = sp.Symbol


def _plain(x) -> bool:
    return type(x) is _Symbol and x.is_commutative


def add_of(args):
    """``sp.Add(*args)`` where every term is ``s`` or ``-s`` of distinct plain symbols (at
    least two terms); else None."""
    if _addsort is None or len(args) < 2:
        return None
    seen = set()
    for a in args:
        s = a if _plain(a) else (a.args[1] if a.is_Mul and len(a.args) == 2
                                 and a.args[0] is _NEG and _plain(a.args[1]) else None)
        if s is None or s in seen:
            return None
        seen.add(s)
    terms = list(args)
    _addsort(terms)
    return sp.Add._from_args(terms)


def mul_of(args):
    """``sp.Mul(*args)`` where the factors are -1, ``s``, ``-s`` or ``s**k`` (k an integer)
    of distinct plain symbols (at least one symbol); else None."""
    if _mulsort is None:
        return None
    neg = False
    factors = []
    bases = set()
    for a in args:
        if a is _NEG:
            neg = not neg
            continue
        if a.is_Mul and len(a.args) == 2 and a.args[0] is _NEG:
            neg = not neg
            a = a.args[1]
        if _plain(a):
            b = a
        elif a.is_Pow and _plain(a.args[0]) and a.args[1].is_Integer:
            b = a.args[0]
        else:
            return None
        if b in bases:
            return None
        bases.add(b)
        factors.append(a)
    if not factors:
        return None
    if len(factors) == 1 and not neg:
        return factors[0]
    _mulsort(factors)
    return sp.Mul._from_args([_NEG] + factors if neg else factors)


def quotient(num, den):
    """``num / den`` (sympy's ``Mul(num, Pow(den, -1))``), directly for plain operands."""
    if _plain(den):
        out = mul_of((num, sp.Pow(den, _NEG)))
        if out is not None:
            return out
    return num / den


def replaced(expr, rule: dict):
    """``expr.xreplace(rule)``: the same expression, its rebuilt sums and products made by
    :func:`add_of` and :func:`mul_of` where they apply."""
    if not rule:
        return expr
    return _replaced(expr, rule)[0]


_BASIC_XREPLACE = sp.Basic._xreplace


def _replaced(e, rule):
    if e in rule:
        return rule[e], True
    if not e.args:
        return e, False
    if type(e)._xreplace is not _BASIC_XREPLACE:  # a class with its own replacement
        return e._xreplace(rule)
    args = []
    changed = False
    for a in e.args:
        if isinstance(a, sp.Basic):
            a, c = _replaced(a, rule)
            changed = changed or c
        args.append(a)
    if not changed:
        return e, False
    t = type(e)
    out = add_of(args) if t is sp.Add else mul_of(args) if t is sp.Mul else None
    return (e.func(*args) if out is None else out), True
