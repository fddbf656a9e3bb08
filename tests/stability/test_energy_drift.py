"""A lossless model over many periods: the frictionless pendulum (models/pendulum.yaml,
generated/pendulum.py) released at theta0 = 2 rad, at rtol = atol = 1e-8.

Nothing dissipates, so the energy E = h^2 / (2 m l^2) + m g l (1 - cos theta) is conserved
exactly; every change of the output `energy` is integration error, and for the
(non-symplectic) methods scipy offers it accumulates roughly linearly: a drift per period.
The closed forms used here (not bgc's): E0 = m g l (1 - cos theta0) and the period
T = 4 K(sin^2(theta0 / 2)) sqrt(l / g) (K: complete elliptic integral of the first kind).

* 1e4 periods on the C backend, whose DOP853, Radau and Rodas4 run the whole loop in C (the
  same run through scipy's LSODA and the numpy module took 2.1e6 Python rhs calls, 89 s):
  relative energy error below 1e-5 at every period's end and a drift below 1e-9 per period
  (measured 1.1e-6, 6.5e-7, 7.8e-7 and 1.0e-10, -6.5e-11, 7.8e-11 per period).
* Each method over a shorter run: drift per period below 1e-7, i.e. below 1e-3 over 1e4
  periods if the drift stays linear. scipy's BDF does not meet it (measured 2.6e-7 per
  period: 2.6e-3 over 1e4 periods); its test is an expected failure, so that a change is
  noticed. bgc's Rodas4 drifts 4.3e-11 per period over 10 periods (7.8e-11 over 1e4).
  bench/energy_drift.py measures every method over the full 1e4 periods (docs/stability.md
  has the table).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.special import ellipk

ROOT = Path(__file__).resolve().parents[2]

RTOL = ATOL = 1e-8


@pytest.fixture(scope="module")
def pend(gen):
    mod = gen("pendulum")
    P = mod.PARAM_DEFAULTS
    T = 4.0 * ellipk(np.sin(P["theta0"] / 2) ** 2) * np.sqrt(P["l"] / P["g"])
    E0 = P["m"] * P["g"] * P["l"] * (1.0 - np.cos(P["theta0"]))
    return mod, T, E0


def drift(mod, T, E0, method, periods):
    """Relative energy error at every period's end, and its least-squares slope per period."""
    k = np.arange(periods + 1)
    t, x, y = mod.simulate((0.0, periods * T), t_eval=k * T, method=method, rtol=RTOL,
                           atol=ATOL, max_steps=10**7)
    assert t[-1] == pytest.approx(periods * T) and np.all(np.isfinite(x))
    rel = (y["energy"] - E0) / E0
    return rel, np.polyfit(k, rel, 1)[0]


def test_closed_forms(pend):
    """The model's energy output at t = 0 and its period against the closed forms."""
    mod, T, E0 = pend
    y0 = mod.outputs(0.0, mod.X0)
    assert float(y0["energy"]) == pytest.approx(E0, rel=1e-14)
    # theta = 0 a quarter period after each release point: period right to ~1e-9 s
    te = T / 4 + T * np.arange(11)
    _, _, y = mod.simulate((0.0, te[-1]), t_eval=te, method="DOP853", rtol=1e-11, atol=1e-11)
    assert np.max(np.abs(y["theta"])) < 1e-8
    omega_max = np.sqrt(2 * E0 / (mod.PARAM_DEFAULTS["m"] * mod.PARAM_DEFAULTS["l"] ** 2))
    np.testing.assert_allclose(np.abs(y["omega"]), omega_max, rtol=1e-9)


@pytest.fixture(scope="module")
def pend_c(pend):
    from bgc.backends.c import build as cbuild
    if not cbuild.available():
        pytest.skip("no C compiler (CI installs one)")
    import bgc
    return bgc.compile(ROOT / "models" / "pendulum.yaml", target="c")


@pytest.mark.slow
@pytest.mark.parametrize("method", ["DOP853", "Radau", "Rodas4"])
def test_energy_drift_over_ten_thousand_periods(pend, pend_c, method):
    _, T, E0 = pend
    rel, per_period = drift(pend_c, T, E0, method, 10_000)
    assert np.max(np.abs(rel)) < 1e-5
    assert abs(per_period) < 1e-9


@pytest.mark.parametrize("method, periods", [
    ("RK45", 100), ("DOP853", 100), ("LSODA", 100), ("Radau", 10), ("Rodas4", 10),
    # BDF's slope is the same over 20 periods as over 100 (2.627e-7), at a fifth of the cost
    pytest.param("BDF", 20, marks=pytest.mark.xfail(
        strict=True, reason="scipy's BDF drifts 2.6e-7 per period at rtol 1e-8 "
                            "(docs/stability.md)")),
])
def test_drift_per_period(pend, method, periods):
    mod, T, E0 = pend
    rel, per_period = drift(mod, T, E0, method, periods)
    assert abs(per_period) < 1e-7, per_period
    assert np.max(np.abs(rel)) < 1e-7 * periods + 1e-8
