"""Issue 27, printing: bgc.backends.fastprint prints every expression as sympy's own printers do.

The reference is sympy's code path itself: the same printer classes with fastprint's methods
taken out (``doprint``, the dispatch, ``parenthesize``, sums, products and symbols go back to
sympy's CodePrinter, StrPrinter and Printer), plus the one fix bgc made to sympy's product
text before (a lone denominator b**-2, printed b*b, in parentheses). Random expressions of
every shape the printers meet (negative coefficients and powers, rationals, floats, nested
sums and products, functions, Piecewise, relations, min/max) must come out character for
character the same."""
from __future__ import annotations

import random

import pytest
import sympy as sp
from sympy.printing.c import C99CodePrinter
from sympy.printing.numpy import NumPyPrinter

from bgc.backends.c.cexpr import CPrinter
from bgc.backends.numpy.printer import BgcPrinter

X = sp.symbols("x0:6", real=True)
NAMED = [sp.Symbol("lambda", real=True), sp.Symbol("main", real=True)]  # reserved in a target


def _stock(cls, base):
    """``cls`` with fastprint's methods replaced by sympy's own (those of ``base``'s MRO)."""

    def _print_Mul(self, expr):
        s = base._print_Mul(self, expr)
        den = [f for f in sp.Mul.make_args(expr) if f.is_commutative and f.is_Pow
               and f.exp.is_Rational and f.exp.is_negative]
        if len(den) == 1 and -den[0].exp in cls.product_powers:
            d = self._print(sp.Pow(den[0].base, -den[0].exp, evaluate=False))
            if s.endswith("/" + d):
                s = f"{s[:-len(d)]}({d})"
        return s

    names = {"doprint": base.doprint, "_print": base._print, "parenthesize": base.parenthesize,
             "_print_Add": base._print_Add, "_print_Mul": _print_Mul}
    if "_print_Symbol" not in cls.__dict__:
        names["_print_Symbol"] = base._print_Symbol
    return type("Stock" + cls.__name__, (cls,), names)


def _expr(rng: random.Random, depth: int):
    leaves = list(X) + NAMED + [sp.Integer(rng.randint(-3, 3)), sp.Rational(rng.randint(-5, 5), 3),
                                sp.Float(rng.choice([0.5, -2.25, 1e-3, 3.0])), sp.pi]
    if depth == 0 or rng.random() < 0.2:
        return rng.choice(leaves)
    sub = [_expr(rng, depth - 1) for _ in range(3)]
    kind = rng.randrange(9)
    if kind == 0:
        return sp.Add(*sub)
    if kind == 1:
        return sp.Mul(*sub)
    if kind == 2:
        return -sp.Mul(*sub)
    if kind == 3:
        return sp.Pow(sub[0], rng.choice([-1, -2, -3, 2, 3, 5, sp.Rational(1, 2),
                                          -sp.Rational(1, 2), sp.Rational(3, 2), -4]))
    if kind == 4:
        return sub[0] / (sub[1] * sub[-1])
    if kind == 5:
        return rng.choice([sp.sin, sp.cos, sp.exp, sp.atan, sp.tanh])(sub[0])
    if kind == 6:
        return sp.Piecewise((sub[0], sub[1] > 0), (sub[2], True))
    if kind == 7:
        return rng.choice([sp.Min, sp.Max])(sub[0], sub[1])
    return sp.atan2(sub[0], sub[1]) + sp.Abs(sub[1]) * sp.sign(sub[0])


@pytest.mark.parametrize("fast, base", [(BgcPrinter, NumPyPrinter), (CPrinter, C99CodePrinter)])
def test_fast_printing_is_sympys_text(fast, base):
    stock = _stock(fast, base)
    rng = random.Random(27)
    one_fast, one_stock = fast(), stock()  # one printer for many expressions, as the backends
    checked = 0
    for _ in range(600):
        try:
            e = _expr(rng, rng.randint(1, 4))
        except (TypeError, ValueError):  # zoo > 0, Max(zoo, x): sympy refuses them
            continue
        if e.has(sp.zoo, sp.nan, sp.oo):  # a division by zero: nothing bgc prints
            continue
        try:
            want = stock().doprint(e)
        except (ValueError, TypeError, NotImplementedError):
            with pytest.raises((ValueError, TypeError, NotImplementedError)):
                fast().doprint(e)
            continue
        assert fast().doprint(e) == want, e
        assert one_fast.doprint(e) == one_stock.doprint(e) == want, e
        checked += 1
    assert checked > 400  # most random expressions are printable


def test_the_lone_denominator_keeps_its_parentheses():
    # x/b**2 printed with b**2 as b*b: without the parentheses it would mean x/b*b = x
    x, b = X[0], X[1]
    assert BgcPrinter().doprint(x / b**2) == "x0/(x1*x1)"
    assert CPrinter().doprint(x / b**3) == "x0/(x1*x1*x1)"
    assert eval(BgcPrinter().doprint(x / (b + 1)**2), {"x0": 3.0, "x1": 1.0}) == 0.75


def test_renamed_prints_what_the_replaced_expression_means():
    """FastPrinting.renamed (the re-rolled numpy functions' slots and gathers): the text of
    ``e`` with symbols renamed evaluates to ``e`` at the values the new names hold, nested
    renamings restore what was there before, and afterwards every name is its own again."""
    import math

    import numpy as np

    rng = random.Random(5)
    d = sp.Dummy("r")
    w = np.array([0.7, -1.3, 2.1, 0.4])
    fast = BgcPrinter()
    env = {"xp": np, "_w": w, "_g0": 1.9, "x5": -0.6, **{str(s): 0.3 + k for k, s in
                                                             enumerate(X[:5])}}
    checked = 0
    for _ in range(200):
        try:
            e = _expr(rng, rng.randint(1, 3)).subs(X[4], d)
        except (TypeError, ValueError):
            continue
        if e.has(sp.zoo, sp.nan, sp.oo) or e.has(*NAMED) or e.has(sp.Piecewise):
            continue
        values = {X[0]: sp.Float(w[2]), X[1]: sp.Float(w[0]), d: sp.Float(1.9),
                  X[2]: sp.Float(0.3 + 2), X[3]: sp.Float(0.3 + 3), X[5]: sp.Float(-0.6)}
        try:
            want = complex(e.xreplace(values).evalf())
        except (TypeError, ValueError):
            continue
        if not math.isfinite(abs(want)) or want.imag:
            continue
        with fast.renamed({X[0]: "_w[2]", X[1]: "_w[9]"}):
            with fast.renamed({X[1]: "_w[0]", d: "_g0"}):  # inner names win, then undone
                text = fast.doprint(e)
            assert fast.doprint(X[1]) == "_w[9]"
        assert fast.doprint(X[0] + X[1]) == BgcPrinter().doprint(X[0] + X[1])
        with np.errstate(all="ignore"):
            got = eval(text, env)
        assert np.isclose(got, want.real, rtol=1e-12, atol=1e-12), (e, text)
        checked += 1
    assert checked > 60
    with pytest.raises(TypeError), fast.renamed({sp.sin(X[0]): "s"}):
        pass
