"""bgc.format.matrices against sympy's own matrices: the same entries, in the same form.

The entries are drawn at random from what a model's laws hold (zeros, ones, integers,
rationals, floats, signed symbols, products, powers, sums, functions), so the zero-skipping,
sign and scaling paths all run; each result is compared by ``srepr`` (form, not only value).
"""
from __future__ import annotations

import random

import pytest
import sympy as sp

from bgc.format import matrices

X = sp.symbols("x0:6", real=True)


def _entry(rng: random.Random):
    x, y = rng.sample(X, 2)
    return rng.choice([
        sp.S.Zero, sp.S.Zero, sp.S.One, sp.S.NegativeOne, sp.Integer(3), sp.Rational(1, 2),
        sp.Float(0.25), x, -x, 2 * x, x * y, -x * y / 3, x ** 2, 1 / x, x + y, x - 2 * y,
        -(x + y) * y, sp.sin(x), sp.cos(x) * y, x * sp.Rational(-3, 4) + 1,
    ])


def _matrix(rng, r, c):
    return sp.ImmutableMatrix(r, c, [_entry(rng) for _ in range(r * c)])


def _same(a, b):
    assert type(a) is type(b) and a.shape == b.shape
    assert [sp.srepr(x) for x in a] == [sp.srepr(x) for x in b]


@pytest.mark.parametrize("seed", range(40))
def test_entry_by_entry_equals_sympy(seed):
    rng = random.Random(seed)
    r, k, c = rng.randint(1, 4), rng.randint(1, 4), rng.randint(1, 4)
    a, b = _matrix(rng, r, k), _matrix(rng, r, k)
    _same(matrices.add(a, b), a + b)
    _same(matrices.sub(a, b), a - b)
    _same(matrices.neg(a), -a)
    s = _entry(rng)
    _same(matrices.scale(a, s), a * s)
    _same(matrices.scale(a, s, left=True), s * a)
    m = _matrix(rng, k, c)
    _same(matrices.matmul(a, m), a * m)


def test_identity_and_zero_matrices():
    eye = sp.ImmutableMatrix(sp.eye(3))
    a = sp.ImmutableMatrix(3, 3, list(X[:3]) * 3)
    _same(matrices.matmul(eye, a), eye * a)
    _same(matrices.sub(a, eye), a - eye)
    _same(matrices.scale(eye, sp.Symbol("k")), eye * sp.Symbol("k"))
    _same(matrices.scale(a, 0), a * 0)
    _same(matrices.scale(a, 1), a * 1)


def test_zero_times_infinity_stays_undefined():
    """A zero entry against an infinite one is multiplied, as sympy does (nan, not 0)."""
    a = sp.ImmutableMatrix([[0, 1]])
    b = sp.ImmutableMatrix([[sp.oo], [2]])
    assert matrices.matmul(a, b)[0, 0] == (a * b)[0, 0]


def test_zero_times_a_product_with_an_infinite_factor():
    x = sp.Symbol("x", real=True)
    a = sp.ImmutableMatrix([[0, 1]])
    b = sp.ImmutableMatrix([[sp.Mul(sp.oo, x, evaluate=False)], [2]])
    assert sp.srepr(matrices.matmul(a, b)[0, 0]) == sp.srepr((a * b)[0, 0])


def test_entries_are_the_flat_list():
    for m in (sp.ImmutableMatrix([[1, X[0]], [X[1] ** 2, 0]]), sp.ImmutableMatrix(sp.eye(3)),
              sp.Matrix([[X[2], 2]]), sp.ImmutableMatrix(3, 1, [0, 0, 0])):
        assert matrices.entries(m) == m.flat() and type(matrices.entries(m)) is list
