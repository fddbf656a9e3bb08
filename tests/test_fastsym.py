"""symengine (bgc.core.fastsym) differentiates and eliminates common subexpressions; sympy's own
diff and cse are the independent answer. Every example model compiled both ways must give the
same rhs and Jacobian at random points, and the bridge must keep sympy symbols' identity."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import sympy as sp

from bgc.backends.load import load_module
from bgc.core import fastsym
from bgc.format.parse import parse_file
from bgc.run.driver import compile_model

ROOT = Path(__file__).resolve().parent.parent
MODELS = sorted(p.name for p in (ROOT / "models").glob("*.yaml"))

pytestmark = pytest.mark.skipif(not fastsym.available(), reason="symengine not installed")


def _points(mod, rng, k=4):
    x0 = np.asarray(mod.X0, dtype=float)
    scale = np.maximum(np.abs(x0), 0.1)
    return [x0 + 0.05 * scale * rng.standard_normal(x0.shape) for _ in range(k)]


SLOW = {"3r2s.yaml", "3r2s_rigid.yaml"}  # sympy's own diff and cse of these take tens of seconds


@pytest.mark.parametrize("model", [pytest.param(m, marks=pytest.mark.slow) if m in SLOW else m
                                   for m in MODELS])
def test_symengine_equals_sympy(model, monkeypatch, compiled_model):
    # the symengine compile is the one the model's golden and C-backend tests share
    fast = load_module(compiled_model(model[:-5]).source, f"fast_{model[:-5]}")
    monkeypatch.setattr(fastsym, "se", None)
    # (only rhs and jacobian are compared: sympy's module is printed without the
    # linearisation's B, C, D, which leaves those two functions as they are)
    slow = load_module(compile_model(parse_file(ROOT / "models" / model), linear=False).source,
                       f"slow_{model[:-5]}")
    rng = np.random.default_rng(7)
    for x in _points(fast, rng):
        t = float(rng.uniform(0.0, 1.0))
        r1, r2 = fast.rhs(t, x), slow.rhs(t, x)
        np.testing.assert_allclose(r1, r2, rtol=1e-12, atol=1e-12 * (1 + np.abs(r2).max()))
        j1, j2 = fast.jacobian(t, x), slow.jacobian(t, x)
        np.testing.assert_allclose(j1, j2, rtol=1e-12, atol=1e-12 * (1 + np.abs(j2).max()))


def test_bridge_keeps_symbols_and_refuses_what_it_cannot_read():
    x, y = sp.symbols("x y", real=True)
    b = fastsym.Bridge()
    e = sp.sin(x) * y ** 2 + sp.exp(x / y) - sp.Rational(3, 7) * sp.log(y) + sp.Float(0.25)
    back = b.from_se(b.to_se(e))
    assert back.free_symbols == {x, y}  # the very symbols, assumptions included
    pt = {x: 0.3, y: 1.7}
    assert abs(float(back.subs(pt)) - float(e.subs(pt))) < 1e-14
    d = fastsym.partials(b, e, [x, y])
    for s in (x, y):
        ref = float(sp.diff(e, s).subs(pt))
        assert abs(float(b.from_se(d[s]).subs(pt)) - ref) < 1e-13
    for bad in (sp.sign(x), sp.Piecewise((x, x > 0), (y, True)), sp.Max(x, y), sp.atan2(x, y)):
        assert b.to_se(bad * y) is None  # the caller differentiates these with sympy


def test_cse_passes_atan2_through_as_an_opaque_function():
    # an output angle atan2(y, x) beside other outputs that share y and x: symengine's CSE
    # takes the whole body (atan2 crosses as a function of no meaning there) and still finds
    # the common terms inside its arguments; substituting the temporaries back gives the very
    # values sympy computes from the original expressions
    x, y, z = sp.symbols("x y z", real=True)
    r = sp.sqrt(x ** 2 + y ** 2)
    exprs = [sp.atan2(y * z + x, r), (y * z + x) * r, sp.atan2(sp.sin(z), x) + sp.sin(z)]
    k = iter(range(100))
    out = fastsym.cse(exprs, lambda: sp.Symbol(f"_c{next(k)}", real=True))
    assert out is not None  # (without the opaque crossing: None, and sympy's cse)
    repl, reduced = out
    assert any(e.has(sp.atan2) for e in reduced) or any(e.has(sp.atan2) for _, e in repl)
    assert any(v in (y * z + x, r) for _, v in repl)  # a term shared through atan2's argument
    back = {}
    for s, e in repl:
        back[s] = e.xreplace(back)
    pt = {x: 0.3, y: -1.7, z: 0.9}
    for orig, red in zip(exprs, reduced):
        ref = float(orig.subs(pt).evalf(30))
        assert abs(float(red.xreplace(back).subs(pt).evalf(30)) - ref) < 1e-14 * (1 + abs(ref))
    assert fastsym.Bridge().to_se(sp.atan2(y, x)) is None  # never so for differentiation


def test_free_symbols_by_one_walk_are_sympys():
    # the one-walk free symbols (forward sweep, lowering) against sympy's own, on the kinds of
    # node bgc's expressions hold, and on classes with bound variables, which keep their rule
    x, y, z, t = sp.symbols("x y z t", real=True)
    f = sp.Function("f")
    exprs = [x, sp.Integer(3), sp.pi, x * y + sp.sin(z) ** 2, sp.atan2(y, x) * sp.exp(-t),
             sp.Piecewise((x, y > 0), (z, True)), sp.Max(x, sp.Abs(y)) + sp.sign(z),
             f(x, y) + t, sp.Derivative(f(x, z), x), sp.Integral(x * y, (x, 0, z)),
             sp.Lambda(x, x + y)(z), (x + y) * (x + y) ** 2 + sp.sqrt(x + y)]
    for e in exprs:
        assert fastsym.free_symbols(e) == e.free_symbols, e
