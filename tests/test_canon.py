"""bgc.core.canon builds sympy's canonical sums and products directly: every result must be
what sympy's own constructors (Add, Mul, xreplace) give, argument for argument."""
import random

import sympy as sp

from bgc.core import canon

SYMS = [sp.Symbol(n, real=True) for n in ("e_b2", "e_b10", "f_b3", "R", "C", "q_c0", "_d1",
                                          "_d12", "u_V", "x")]
ATOMS = SYMS + [sp.Integer(0), sp.Integer(2), sp.Rational(1, 3), sp.Float(0.5), sp.pi]


def _same(a, b):
    return a == b and sp.srepr(a) == sp.srepr(b) and a.args == b.args and str(a) == str(b)


def _operand(rng, pool):
    s = rng.choice(pool)
    k = rng.random()
    if k < 0.25:
        return -s
    if k < 0.4:
        return sp.Pow(s, rng.choice([-1, -2, 2, 3]))
    return s


def test_add_and_mul_of_match_the_constructors():
    rng = random.Random(7)
    hits = {"add": 0, "mul": 0}
    for _ in range(3000):
        pool = SYMS if rng.random() < 0.8 else ATOMS
        args = [_operand(rng, pool) for _ in range(rng.randint(1, 5))]
        if rng.random() < 0.2:
            args.insert(rng.randint(0, len(args)), sp.S.NegativeOne)
        a = canon.add_of(args)
        if a is not None:
            hits["add"] += 1
            assert _same(a, sp.Add(*args)), args
        m = canon.mul_of(args)
        if m is not None:
            hits["mul"] += 1
            assert _same(m, sp.Mul(*args)), args
    assert hits["add"] > 300 and hits["mul"] > 300  # the fast paths were exercised


def test_quotient_matches_division():
    for num in SYMS[:4] + [-SYMS[0], 2 * SYMS[1], SYMS[0] + SYMS[1], sp.Integer(1), SYMS[3]]:
        for den in (SYMS[3], SYMS[4], 2 * SYMS[4], sp.Integer(3)):
            assert _same(canon.quotient(num, den), num / den), (num, den)


def test_replaced_matches_xreplace():
    rng = random.Random(11)
    x, y = SYMS[0], SYMS[1]
    extra = [sp.sin(x) * y, sp.Piecewise((x, y > 0), (-x, True)), sp.exp(-x / y),
             sp.Function("g")(x, y)]
    for _ in range(1500):
        terms = []
        for _ in range(rng.randint(1, 4)):
            fac = [_operand(rng, SYMS) for _ in range(rng.randint(1, 3))]
            terms.append(sp.Mul(*fac))
        e = sp.Add(*terms)
        if rng.random() < 0.3:
            e = e / rng.choice(SYMS) + rng.choice(extra)
        rule = {}
        for s in rng.sample(SYMS, 3):
            rule[s] = rng.choice([rng.choice(SYMS), -rng.choice(SYMS), sp.Integer(0),
                                  sp.Integer(2), rng.choice(SYMS) + rng.choice(SYMS)])
        assert _same(canon.replaced(e, rule), e.xreplace(rule)), (e, rule)
