"""A junction's balance (bgc.core.laws.signed_sum) is exactly sympy's own sum: the same
canonical expression, argument for argument, as ``sp.Add`` of the signed terms, for any mix
of signs, names and sizes (sympy's constructor is the reference)."""
from __future__ import annotations

import random

import sympy as sp

from bgc.core.laws import signed_sum


def test_signed_sums_are_sympys_sums():
    rng = random.Random(27)
    names = [f"{p}_{k}" for p in ("e_b", "f_b", "e_r", "f_link1__b") for k in
             (1, 2, 9, 10, 11, 100, 3000)] + ["x", "y_2", "z"]
    for _ in range(400):
        k = rng.randint(0, 6)
        real = rng.random() < 0.8
        syms = [sp.Symbol(n, real=True) if real else sp.Symbol(n) for n in rng.sample(names, k)]
        terms = [(s, rng.random() < 0.5) for s in syms]
        want = sp.Add(*[s if pos else -s for s, pos in terms])
        got = signed_sum(terms)
        assert got == want and got.args == want.args and sp.srepr(got) == sp.srepr(want)
        assert type(got) is type(want)


def test_repeated_or_non_symbol_terms_take_the_general_sum():
    x, y = sp.symbols("x y", real=True)
    assert signed_sum([(x, True), (x, False)]) == 0
    assert signed_sum([(x, True), (x, True), (y, False)]) == 2 * x - y
    assert signed_sum([(2 * x, True), (y, False)]) == 2 * x - y
    assert signed_sum([(x, False)]) == -x
    assert signed_sum([]) == 0
