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
from bgc.run.driver import compile_file

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
    slow = load_module(compile_file(ROOT / "models" / model).source, f"slow_{model[:-5]}")
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
