"""Newton on an exponential law from far off (issue 23, item 1): the half-wave rectifier's
diode loop, i = Is (exp((Vs - v_C - Rs i) / n Vt) - 1), at capacitor voltages across +-100 V
(the exponent at i = 0 reaches thousands: exp() overflows without the loop's guard) on both
backends, against scipy's brentq on the same loop equation written here from the model's
parameters (models/rectifier.yaml)."""
from __future__ import annotations

import math

import numpy as np
import pytest
import sympy as sp
from scipy.optimize import brentq

from bgc.backends.c import build as cbuild
from bgc.format.parse import parse_file
from bgc.lower.newton import EXP_CAP, LimExp, SlopeExp, guarded
from bgc.run.driver import build

P = dict(V0=10.0, f0=50.0, Is=1e-12, nVt=0.02585, Rs=1.0, RL=1000.0, C1=1e-3)
MODEL = "models/rectifier.yaml"


def _dq(t, vC):
    """dq/dt of the capacitor: the loop current (brentq) less the load's."""
    V = P["V0"] * math.sin(2 * math.pi * P["f0"] * t) - vC

    def f(i):  # increasing in i; with np.expm1 an overflow is inf, the right sign
        with np.errstate(over="ignore"):
            return i - P["Is"] * np.expm1((V - P["Rs"] * i) / P["nVt"])

    i = brentq(f, -2 * P["Is"], abs(V) / P["Rs"] + 1.0, xtol=1e-15, rtol=1e-15,
               maxiter=500)
    return i - vC / P["RL"]


def _module(backend):
    if backend == "c" and not (cbuild.available() and cbuild.runtime_sources()):
        pytest.skip("no C compiler")
    b = build(model=parse_file(MODEL), backend=backend)
    assert b.backend == backend
    return b.module


@pytest.mark.parametrize("backend", ["numpy", "c"])
@pytest.mark.parametrize("cold", [False, True])
def test_the_diode_loop_converges_from_tens_of_volts_off(backend, cold):
    m = _module(backend)
    rng = np.random.default_rng(23)
    for _ in range(120):
        vC, t = rng.uniform(-100, 100), rng.uniform(0, 0.04)
        if cold and backend == "numpy":
            m._NEWTON_WARM.clear()  # from zero, not from the last point's solution
        got = float(np.asarray(m.rhs(t, np.array([P["C1"] * vC]))).reshape(-1)[0])
        want = _dq(t, vC)
        assert got == pytest.approx(want, rel=1e-9, abs=1e-12), (vC, t)


def test_a_batch_of_far_states_converges_on_numpy():
    m = _module("numpy")
    rng = np.random.default_rng(7)
    vC = rng.uniform(-100, 100, 64)
    got = np.asarray(m.rhs(0.013, P["C1"] * vC[None, :])).reshape(-1)
    want = np.array([_dq(0.013, v) for v in vC])
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)


def test_the_guard_keeps_exp_below_its_cap_and_continues_it_beyond():
    """LimExp is exp up to the cap and its tangent line beyond; the printers' text of it, in
    the numpy module, agrees."""
    m = _module("numpy")
    a = np.array([-5.0, 0.0, 30.0, EXP_CAP, EXP_CAP + 10.0, 1e4])
    lex, sex = m._bgc_lexp(a), m._bgc_sexp(a)
    np.testing.assert_allclose(lex[:4], np.exp(a[:4]), rtol=1e-15)
    np.testing.assert_allclose(lex[4:], math.exp(EXP_CAP) * (1 + a[4:] - EXP_CAP), rtol=1e-15)
    np.testing.assert_allclose(sex, np.exp(np.minimum(a, EXP_CAP)), rtol=1e-15)
    assert np.all(np.isfinite(lex))
    nl = build(model=parse_file(MODEL), backend="numpy", use_cache=False
               ).compiled.equations.newton[0]
    g = guarded(nl)
    assert len(g["exponents"]) == 1 and "nVt" in str(g["exponents"][0])
    # the loop's values take the guarded exp, its derivative coefficients (_nc*) the slope
    vals = [e for s, e in g["body"] if not str(s).startswith("_nc")]
    coeffs = [e for s, e in g["body"] if str(s).startswith("_nc")]
    assert any(e.has(LimExp) for e in vals) and not any(e.has(SlopeExp) for e in vals)
    assert any(e.has(SlopeExp) for e in coeffs) and not any(e.has(LimExp) for e in coeffs)
    assert not any(e.has(sp.exp) for _, e in g["body"])


def test_a_step_is_limited_logarithmically():
    m = _module("numpy")
    # an exponent from 0 to 1000 in one full step: the limited step reaches log(1001)
    lam = m._bgc_exp_limit((np.array(0.0),), (np.array(1000.0),), ())
    assert float(lam) * 1000.0 == pytest.approx(math.log1p(1000.0))
    # small growth, or a falling exponent, is not limited
    assert float(m._bgc_exp_limit((np.array(30.0),), (np.array(31.5),), ())) == 1.0
    assert float(m._bgc_exp_limit((np.array(300.0),), (np.array(-50.0),), ())) == 1.0
