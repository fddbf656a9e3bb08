"""Classic stiff problems written as bond graphs, against published or closed-form answers.

Van der Pol (models/van_der_pol.yaml): an LC circuit with a cubic nonlinear resistor. With
L = 1 H, g = 1 S, V0 = 1 V it is, state for state, problem VDPOL of the stiff test sets
(y1 = v, y2 = dv/dt, eps = 1/mu^2, y(0) = (2, 0)):
* at mu = 1e3 (eps = 1e-6) the published reference solution at t = 2 of the Test Set for IVP
  Solvers (F. Mazzia, C. Magherini et al., University of Bari, problem "vdpol", computed
  with RADAU at rtol = atol = 1.1e-18): y1 = 1.706167732170483, y2 = -0.8928097010247975;
* at mu = 1e3, 1e4 and 1e6, the period of the limit cycle against Dorodnitsyn's asymptotic
  formula (A. A. Dorodnitsyn, Prikl. Mat. Mekh. 11, 1947; in the scaled time):
  T = (3 - 2 ln 2) + 3 a mu^(-4/3) - (2/3) ln(mu) mu^(-2) + O(mu^-2), a = 2.338107410...
  (the first zero of the Airy function Ai is -a). The O(mu^-2) remainder is bounded here by
  2 mu^-2 (measured: -1.32 mu^-2, Dorodnitsyn's next constant).

Stiff two-mass chain (models/two_mass_chain.yaml): a soft wall spring (7 rad/s mode) and a
stiff link (1.4e4 rad/s, damped) under a force step, against the exact solution of the linear
system (matrix exponential of the hand-written state matrix), and bgc's analytic Jacobian
against that matrix.
"""
from __future__ import annotations

import numpy as np
import pytest
from stability_helpers import CHAIN_STATES, chain_exact, chain_matrix

VDPOL_T2 = (1.706167732170483, -0.8928097010247975)  # Bari test set, vdpol, eps = 1e-6
AIRY_A = 2.338107410459767  # -(first zero of Ai)


# ---------------------------------------------------------------------------------------
# Van der Pol
# ---------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def vdp(gen):
    return gen("van_der_pol")


def vdp_hand(x, mu, L=1.0, g=1.0, V0=1.0):
    """The circuit's equations written out by hand: x = (q_C, flux_L) -> (dq/dt, dflux/dt)."""
    C = L * g * g / mu**2
    v = x[0] / C
    iL = x[1] / L
    iR = g * (v**3 / (3 * V0**2) - v)
    return np.array([-iL - iR, v])


def test_vdp_equations_and_jacobian_match_the_circuit(vdp):
    """rhs and Jacobian against the hand-written circuit, away from the default scales
    (V0 != 1 exercises every division by V0^2 in the generated code)."""
    rng = np.random.default_rng(7)
    for mu, L, g, V0 in [(1e3, 1.0, 1.0, 1.0), (50.0, 0.3, 2.0, 0.5), (1e5, 2.0, 0.7, 3.0)]:
        p = {"mu": mu, "L": L, "g": g, "V0": V0}
        C = L * g * g / mu**2
        for _ in range(5):
            x = np.array([C * V0 * rng.uniform(-3, 3), L * g * V0 * rng.uniform(-3, 3)])
            want = vdp_hand(x, mu, L, g, V0)
            np.testing.assert_allclose(vdp.rhs(0.0, x, p), want, rtol=1e-12, atol=0)
            h = 1e-6 * np.abs(x)
            J_fd = np.column_stack([(vdp_hand(x + e, mu, L, g, V0) - vdp_hand(x - e, mu, L, g, V0))
                                    / (2 * e[i]) for i, e in enumerate(np.diag(h))])
            np.testing.assert_allclose(vdp.jacobian(0.0, x, p), J_fd, rtol=1e-6, atol=0)


@pytest.mark.parametrize("method", ["Radau", "BDF", "LSODA", "Rodas4"])
@pytest.mark.parametrize("V0", [1.0, 0.5])
def test_vdp_mu_1e3_against_published_reference(vdp, method, V0):
    """At mu = 1e3, t = 2 against the Bari test set (with V0 != 1 the solution is V0 times
    the test set's). rtol 1e-8; atol per state, scaled to the state (q_C = C v is ~1e-6).
    y2 = dv/dt = (-i_L - i_R(v)) / C amplifies the error of i_L by 1/C = 1e6 at the knee,
    hence its looser bound. Measured: |dy1| <= 1.4e-7, |dy2| <= 3.8e-6."""
    C = 1e-6
    rtol = 1e-8
    t, x, y = vdp.simulate((0.0, 2.0), t_eval=[0.0, 2.0], method=method, rtol=rtol,
                           atol=[rtol * C * V0, rtol * V0], p={"V0": V0, "v0": 2 * V0})
    assert np.all(np.isfinite(x))
    assert y["v"][0] == pytest.approx(2 * V0, rel=1e-14) and abs(y["dv_dt"][0]) < 1e-9
    assert abs(y["v"][-1] / V0 - VDPOL_T2[0]) < 1e-6
    assert abs(y["dv_dt"][-1] / V0 - VDPOL_T2[1]) < 1e-4


def downward_crossings(t, v, level):
    i = np.nonzero((v[:-1] > level) & (v[1:] <= level))[0]
    return t[i] + (v[i] - level) / (v[i] - v[i + 1]) * (t[i + 1] - t[i])


@pytest.mark.parametrize("mu", [1e3, 1e4, 1e6])
def test_vdp_period_against_dorodnitsyn(vdp, mu):
    """One period of the limit cycle: between two downward crossings of v = 1.5 on the slow
    branch (where v' = O(1), so a 1e-4 s output grid and linear interpolation resolve the
    crossing to ~1e-9 s). Measured |T - formula| = 1.3e-6, 1.3e-8, <1e-9 (rtol 1e-9).
    From v = 2 the first crossing comes at about (2 - ln 2) - (9/8 - ln 1.5) = 0.59 and the
    second a period (1.61) later, 2.20: the run stops at 2.4, before the third (3.8)."""
    C = 1.0 / mu**2
    rtol = 1e-9
    te = np.arange(0.0, 2.4, 1e-4)
    t, x, y = vdp.simulate((0.0, 2.4), t_eval=te, method="Radau", rtol=rtol,
                           atol=[rtol * C, rtol], p={"mu": mu})
    assert np.all(np.isfinite(x))
    # bounded by the limit cycle: |v| <= 2 + O(mu^-4/3)
    assert np.max(np.abs(y["v"])) < 2.001
    c = downward_crossings(t, y["v"], 1.5)
    assert len(c) == 2
    period = c[1] - c[0]
    formula = 3 - 2 * np.log(2) + 3 * AIRY_A * mu ** (-4 / 3) - (2 / 3) * np.log(mu) / mu**2
    assert abs(period - formula) < 2.0 / mu**2 + 5e-9


# ---------------------------------------------------------------------------------------
# Stiff two-mass chain
# ---------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def chain(gen):
    return gen("two_mass_chain")


def test_chain_jacobian_is_the_state_matrix(chain):
    P = chain.PARAM_DEFAULTS
    A, _ = chain_matrix(P)
    assert chain.STATE_NAMES == CHAIN_STATES
    x = np.array([0.3, -0.2, 0.01, 1e-7])
    np.testing.assert_allclose(chain.jacobian(0.0, x), A, rtol=1e-14, atol=0)
    # stiff: the fast and slow modes 2e3 apart
    lam = np.abs(np.linalg.eigvals(A))
    assert lam.max() / lam.min() > 1e3


@pytest.mark.parametrize("method", ["Radau", "BDF", "LSODA", "Rodas4"])
def test_chain_force_step_against_exact_solution(chain, method):
    P = chain.PARAM_DEFAULTS
    te = np.linspace(0.0, 2.0, 201)
    t, x, y = chain.simulate((0.0, 2.0), t_eval=te, method=method, rtol=1e-8,
                             atol=[1e-10, 1e-10, 1e-10, 1e-15])
    ex = chain_exact(P, te)
    scale = np.max(np.abs(ex), axis=1)
    err = np.max(np.abs(x - ex), axis=1) / scale
    assert np.all(err < 1e-5), err
    # the static deflection x1 = F0/k1 is approached, the stretch is F0/k2 (1e-7 m) at most
    assert np.max(np.abs(y["x2"] - y["x1"])) < 2.5 * P["F0"] / P["k2"]
