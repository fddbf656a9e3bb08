"""bgc.format.arith against sympy's constructors: the same products and sums, in form.

Operands are drawn at random from what a model's expressions hold (numbers of every kind the
builder makes, plain and signed symbols, powers, products, sums, functions), combined at
random depth, so that both the direct paths and the fall-backs to sympy run; each result is
compared with ``Mul``/``Add``'s by ``srepr``.
"""
from __future__ import annotations

import random

import pytest
import sympy as sp

from bgc.format import arith

X = sp.symbols("x0:5", real=True)
N = sp.Symbol("n", commutative=False)


def _atom(rng):
    x, y = rng.sample(X, 2)
    return rng.choice([
        sp.Integer(2), sp.S.NegativeOne, sp.S.One, sp.Rational(-3, 4), sp.Float(0.1),
        sp.Float(2.5), x, -x, x ** 2, x ** -1, y ** -2, 3 * x, -x * y, x * y ** 2 / 7,
        x + y, x - y, 2 * x + 1, sp.sin(x), sp.sqrt(x), sp.sqrt(2), sp.pi, x * (x + y),
        sp.exp(x), (x + y) ** 2, 1 / (x + y), sp.Float(2.0) * x + y, sp.cos(y) ** 2,
    ])


def _expr(rng, depth):
    if depth == 0 or rng.random() < 0.3:
        return _atom(rng)
    a, b = _expr(rng, depth - 1), _expr(rng, depth - 1)
    return rng.choice([a * b, a + b, a - b])


def _same(a, b):
    assert sp.srepr(a) == sp.srepr(b), (a, b)


@pytest.mark.parametrize("seed", range(16))
def test_products_and_sums_equal_sympy(seed):
    rng = random.Random(seed)
    for _ in range(25):
        a, b = _expr(rng, 2), _expr(rng, 2)
        _same(arith.times(a, b), sp.Mul(a, b))
        _same(arith.times(a, b), a * b)
        _same(arith.plus(a, b), a + b)
        terms = [_expr(rng, 1) for _ in range(rng.randint(0, 5))]
        _same(arith.total(terms), sp.Add(*terms))


def test_cases_that_collect():
    x, y = X[:2]
    _same(arith.times(x, x), x * x)
    _same(arith.times(x ** 2, x ** -2), x ** 2 * x ** -2)
    _same(arith.times(3 * x, x ** -1), 3 * x * x ** -1)
    _same(arith.times(sp.Rational(1, 2), x + y), sp.Rational(1, 2) * (x + y))
    _same(arith.times(x + y, x + y), (x + y) * (x + y))
    _same(arith.plus(x * y, -2 * x * y), x * y - 2 * x * y)
    _same(arith.plus(x, -x), x - x)
    _same(arith.total([x * y, y * x, x]), sp.Add(x * y, y * x, x))
    _same(arith.times(N, x), N * x)
    _same(arith.plus(N, x), N + x)


def test_bases_shared_by_powers_and_functions():
    x, y = X[:2]
    for a, b in [(x, sp.sqrt(x)), (sp.sqrt(x), x), (sp.exp(x), sp.exp(y)), (x + y, (x + y) ** 2),
                 ((x + y) ** -1, x + y), (x ** -1, sp.sqrt(x)), (sp.sin(x), sp.sin(x)),
                 (sp.S.NegativeOne, x + y + 1), (x + y, sp.S.NegativeOne), (sp.I, x),
                 (sp.Float(2.0), x + y), (sp.Rational(1, 2) * x, x + y), (3 * (x + y), y)]:
        _same(arith.times(a, b), a * b)
    _same(arith.total([x, sp.Integer(2), y]), x + 2 + y)
    _same(arith.total([x + 1, y, sp.Float(0.5)]), sp.Add(x + 1, y, sp.Float(0.5)))


def test_summed_is_pythons_sum():
    x, y, z = X[:3]
    for terms in ([], [x], [x, y * z, -x], [x * y, 2 * x * y, sp.Float(1.5)], [x + 1, sp.Integer(-1), y]):
        _same(arith.summed(iter(terms)), sum(terms, sp.Integer(0)))


def test_merged_powers_of_any_base():
    x, y = X[:2]
    s, f = x + y, sp.Float(2.0) * x + 4 * y
    for a, b in [(s, s), (y * s, s), (s ** -1, s), (s ** 2, s ** -2), (sp.sin(x), sp.sin(x)),
                 (sp.cos(y) ** 2, sp.cos(y) ** -1), (f, f), (x * f, f ** 2), (s, sp.sqrt(s)),
                 (sp.exp(x), sp.exp(x)), (x * s ** 3, y * s ** -3)]:
        _same(arith.times(a, b), a * b)
