"""Explicit methods on stiff models: simulate() stops them with StiffnessError, says why, and
leaves non-stiff models alone.

Independent answers: the stability limits are checked against one step of scipy's own solver
classes on y' = lam*y; the stiff eigenvalue of the 3R2S against a finite-difference Jacobian
of its rhs; the step count a stiff run needs against the explicit solver's actual steps; the
RC circuit and the oscillator against their closed forms.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import scipy.integrate

from bgc.backends.load import load_module
from bgc.run.driver import compile_file

EXPLICIT = ("RK23", "RK45", "DOP853")


def amplification(method, z):
    """|R(z)| for each z: one step h = 1 of scipy's solver on y' = z y (each z a real 2x2
    block of one system), with tolerances so loose that the step is accepted as proposed."""
    z = np.atleast_1d(np.asarray(z, dtype=complex))

    def fun(t, y):
        u, v = y.reshape(2, -1)
        return np.concatenate([z.real * u - z.imag * v, z.imag * u + z.real * v])

    y0 = np.concatenate([np.ones(z.size), np.zeros(z.size)])
    solver = getattr(scipy.integrate, method)(fun, 0.0, y0, 10.0, first_step=1.0,
                                              max_step=1.0, rtol=1e3, atol=1e3)
    solver.step()
    assert solver.t == 1.0
    return np.hypot(*solver.y.reshape(2, -1))


def compile_yaml(tmp_path, text, name):
    path = Path(tmp_path) / f"{name}.yaml"
    path.write_text(text)
    c = compile_file(path)
    return load_module(c.source, f"{name}_{abs(hash(str(tmp_path)))}")


# ---------------------------------------------------------------------------------------------
# The stability limits the runtime quotes


@pytest.mark.parametrize("method", EXPLICIT)
def test_stability_limits_are_the_solvers(gen, method):
    """Stable just inside each quoted limit, unstable just outside, with scipy's own steps."""
    real, imag = gen("msd")._STABILITY[method]
    assert amplification(method, complex(-0.99 * real)) <= 1.0
    assert amplification(method, complex(-1.01 * real)) > 1.0
    assert amplification(method, complex(0, 0.99 * imag)) <= 1.0
    assert amplification(method, complex(0, 1.01 * imag)) > 1.0


@pytest.mark.parametrize("method", EXPLICIT)
def test_limits_between_the_axes_are_within_a_third(gen, method):
    """Between the axes the runtime interpolates; the exact boundary (first |R| > 1 along the
    ray, scanned with scipy's steps) stays within [0.75, 1.55] of what it uses."""
    mod = gen("msd")
    for deg in (30, 60, 80, 84, 86, 88, 89, 89.5):
        d = complex(-np.cos(np.radians(deg)), np.sin(np.radians(deg)))
        h_max, _, _ = mod._stiffness(method, 0.0, 1e6, np.array([d]))  # |lambda| = 1
        rs = np.arange(0.5, 9.0, 0.005)
        exact = rs[np.argmax(amplification(method, rs * d) > 1.0)]
        assert 0.75 <= exact / h_max <= 1.55, (deg, exact, h_max)


# ---------------------------------------------------------------------------------------------
# Stiff from the start: the 3R2S (1e8 N/m joint couplings)


@pytest.fixture(scope="module")
def mech(gen):
    return gen("mech3r2s")


@pytest.mark.parametrize("method", EXPLICIT)
def test_3r2s_is_refused_before_any_step(mech, method):
    with pytest.raises(mech.StiffnessError) as exc:
        mech.simulate((0.0, 6.0), method=method)  # the circle scene's span
    err = exc.value
    assert isinstance(err, mech.SimulationError)
    assert err.t == 0.0
    assert err.stats["nfev"] == 0 and err.stats["nsteps"] == 0  # no rhs call spent
    msg = str(err)
    assert f"stiff for {method} at t = 0" in msg
    assert 'method="Radau"' in msg and 'method="BDF"' in msg
    real, _ = mech._STABILITY[method]
    assert f"h*|lambda| <= {real:g}" in msg
    # the quoted eigenvalue is the rhs's: largest |eigenvalue| of a central-difference Jacobian
    x0 = mech.initial_state()
    n = len(x0)
    J = np.empty((n, n))
    for j in range(n):
        h = 1e-7 * max(abs(x0[j]), 1e-3)
        xp, xm = x0.copy(), x0.copy()
        xp[j] += h
        xm[j] -= h
        J[:, j] = (mech.rhs(0.0, xp) - mech.rhs(0.0, xm)) / (2 * h)
    quoted = float(re.search(r"largest \|eigenvalue\| is ([0-9.e+-]+) 1/s", msg).group(1))
    assert quoted == pytest.approx(np.max(np.abs(np.linalg.eigvals(J))), rel=1e-3)
    # and the step count it quotes is the span over the stability limit for it, at least
    steps = float(re.search(r"need about ([0-9.e+-]+) steps", msg).group(1))
    assert steps >= 6.0 * quoted / real * 0.999


def test_3r2s_batch_is_refused_at_bounded_cost(mech):
    """64 instances: the eigenvalues of a sample of them, one check, no rhs call."""
    m1 = mech.PARAM_DEFAULTS["m1"] * np.linspace(0.8, 1.2, 64)
    with pytest.raises(mech.StiffnessError, match="stiff for RK45 at t = 0") as exc:
        mech.simulate((0.0, 6.0), method="RK45", p={"m1": m1})
    assert exc.value.stats["nstiff"] == 1 and exc.value.stats["nfev"] == 0


def test_3r2s_short_span_is_not_refused_up_front(mech):
    """1 ms needs a few dozen stability-limited steps (|lambda| ~ 9e4 1/s): not stiff enough
    to refuse, so RK45 integrates it (and the check costs no rhs call)."""
    res = mech.simulate((0.0, 1e-3), method="RK45")
    assert res.t[-1] == 1e-3 and res.stats["nstiff"] >= 1
    assert np.all(np.isfinite(res.x))


# ---------------------------------------------------------------------------------------------
# Stiff later: an RC circuit whose resistance drops a millionfold at t = 1 s

RC_DROP = """
bgc: 1
name: rc_drop
description: RC circuit charged through a resistance that drops a millionfold at t = 1 s
parameters:
  R0: {value: 1.0, unit: ohm}
  C: {value: 1.0, unit: F}
  V0: {value: 1.0, unit: V}
inputs:
  Rt: {default: "where(t < 1, R0, R0 * 1.0e-6)", shape: [], unit: ohm}
elements:
  source: {type: Se, effort: "V0"}
  cap: {type: C, compliance: "C"}
  res: {type: R, resistance: "Rt"}
  loop: {type: "1"}
bonds: [[source, loop], [loop, cap], [loop, res]]
outputs:
  v_C: "e(cap)"
"""


@pytest.fixture(scope="module")
def rc(tmp_path_factory):
    return compile_yaml(tmp_path_factory.mktemp("rc"), RC_DROP, "rc_drop")


def test_rc_drop_is_what_the_closed_form_says(rc):
    """Radau through the drop: v = V0 (1 - e^-t) before t = 1 (tau = R0 C = 1 s), then
    v = V0 - (V0 - v(1)) e^(-(t - 1)/1e-6): at V0 within microseconds."""
    t_eval = np.array([0.0, 0.5, 1.0, 1.0 + 2e-6, 1.5, 3.0])
    res = rc.simulate((0.0, 3.0), t_eval=t_eval, method="Radau", rtol=1e-10, atol=1e-13,
                      breakpoints=[1.0])
    v1 = 1 - np.exp(-1.0)
    after = np.maximum(t_eval - 1.0, 0.0)
    expected = np.where(t_eval <= 1.0, 1 - np.exp(-t_eval), 1 - (1 - v1) * np.exp(-after / 1e-6))
    np.testing.assert_allclose(res.y["v_C"], expected, rtol=0, atol=1e-8)


@pytest.mark.parametrize("method", EXPLICIT)
def test_stiffness_that_appears_later_is_caught_soon_after(rc, method):
    with pytest.raises(rc.StiffnessError) as exc:
        rc.simulate((0.0, 3.0), method=method, dt=0.01)
    err = exc.value
    # not at the start (the model is not stiff then), but within 1 ms of the drop: 1 ms is
    # ~300 steps at the stability limit (tau = 1e-6 s)
    assert 1.0 < err.t < 1.001
    # bounded work (measured 600-1200 rhs calls), against ~1e6 more steps without the check
    assert err.stats["nsteps"] < 1000 and err.stats["nfev"] < 3000
    msg = str(err)
    assert f"stiff for {method} at t = 1.000" in msg
    assert "held at the stability limit" in msg and 'method="Radau"' in msg


def test_quoted_step_count_matches_the_solvers_steps(rc):
    """The message's 'about N steps' for the remaining span, against RK45's actual steps over
    the 10 ms after the drop (stiff_check off), scaled to the remaining span."""
    with pytest.raises(rc.StiffnessError) as exc:
        rc.simulate((0.0, 3.0), method="RK45")
    quoted = float(re.search(r"need about ([0-9.e+-]+) steps", str(exc.value)).group(1))
    remaining = 3.0 - exc.value.t
    res = rc.simulate((1.0, 1.01), method="RK45", stiff_check=False, x0=[1 - np.exp(-1.0)])
    actual = res.stats["nsteps"] * remaining / 0.01
    assert 0.7 < actual / quoted < 1.5, (actual, quoted)


# ---------------------------------------------------------------------------------------------
# Not stiff: no alarm


def test_msd_is_not_stiff(gen):
    """The mass-spring-damper over 200 s: after its transient (~5 s) RK45's steps do sit at
    the stability limit (about a thousand of them), but that costs nothing worth refusing."""
    mod = gen("msd")
    for method in EXPLICIT:
        res = mod.simulate((0.0, 200.0), method=method)
        assert res.stats["nstiff"] >= 2  # the check ran while integrating
        assert res.y["position"][-1] == pytest.approx(10.0 / 200.0, rel=1e-4)  # F0 / k


OSCILLATOR = """
bgc: 1
name: oscillator
description: undamped mass-spring under a constant force, omega = 100 rad/s
parameters: {m: 1.0, k: 1.0e4, F0: 100.0}
elements:
  force: {type: Se, effort: "F0"}
  mass: {type: I, inertia: "m"}
  spring: {type: C, stiffness: "k"}
  v: {type: "1"}
bonds: [[force, v], [v, mass], [v, spring]]
outputs:
  position: "q(spring)"
"""


def test_undamped_oscillator_at_tight_tolerance_is_not_stiff(tmp_path):
    """omega = 100 rad/s over 30 s with DOP853 at rtol 1e-10: thousands of small steps, for
    accuracy. A test on |lambda| * span alone (3000 / 5.96 = 500 steps > max_steps = 100)
    would call it stiff; an undamped mode is not (implicit methods must resolve it too)."""
    mod = compile_yaml(tmp_path, OSCILLATOR, "oscillator")
    t_eval = np.linspace(0.0, 30.0, 301)
    # max_steps = 100 stops the run as too long (max_steps is enforced), never as stiff
    with pytest.raises(mod.SimulationError) as exc:
        mod.simulate((0.0, 30.0), t_eval=t_eval, method="DOP853", rtol=1e-10, atol=1e-14,
                     max_steps=100)
    assert not isinstance(exc.value, mod.StiffnessError) and "max_steps = 100" in str(exc.value)
    res = mod.simulate((0.0, 30.0), t_eval=t_eval, method="DOP853", rtol=1e-10, atol=1e-14)
    assert res.stats["nsteps"] > 100
    # x = F0/k (1 - cos(omega t))
    np.testing.assert_allclose(res.y["position"], 0.01 * (1 - np.cos(100.0 * t_eval)),
                               rtol=0, atol=1e-8)
