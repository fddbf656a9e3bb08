"""Rodas4, the Rosenbrock method every generated module provides (simulate(method="Rodas4")).

Its coefficients are a table of numbers: a mistyped one shows as a lower order, so the
tests measure orders. References come from scipy's DOP853 at rtol 1e-13 (an independent
implementation) or from closed forms; the solver is driven with fixed steps (first_step =
max_step = h and tolerances it always meets) so that the error is the method's alone.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp


def fixed_steps(mod, t_end, n, x0, time_dependent, u=None, **kw):
    """n steps of h = t_end / n of the module's Rodas4 class, through scipy's solve_ivp."""
    h = t_end / n
    return solve_ivp(lambda t, y: mod.rhs(t, y, None, u), (0.0, t_end), x0,
                     method=mod._rodas_class(), jac=lambda t, y: mod.jacobian(t, y, None, u),
                     first_step=h, max_step=h, rtol=1e3, atol=1e3,
                     time_dependent=time_dependent, **kw)


def observed_orders(errors):
    """log2 of successive error ratios (the step halves each time)."""
    e = np.asarray(errors)
    return np.log2(e[:-1] / e[1:])


def dop853(mod, t_end, x0, u=None):
    return solve_ivp(lambda t, y: mod.rhs(t, y, None, u), (0.0, t_end), x0, method="DOP853",
                     rtol=1e-13, atol=1e-15, dense_output=True)


@pytest.fixture(scope="module")
def pendulum(gen):
    return gen("pendulum")


@pytest.fixture(scope="module")
def msd(gen):
    return gen("msd")


def test_global_order_is_four_on_a_nonlinear_model(pendulum):
    """The pendulum released at 2 rad (the nonlinear C law m g l sin q), 2 s. Measured
    errors 1.4e-3, 2.7e-5, 7.2e-7, 2.6e-8 for 10..80 steps: orders 5.7, 5.2, 4.8 (above 4
    while the steps are large)."""
    x0 = pendulum.initial_state()
    ref = dop853(pendulum, 2.0, x0)
    errors = []
    for n in (10, 20, 40, 80):
        sol = fixed_steps(pendulum, 2.0, n, x0, time_dependent=False)
        assert sol.success and len(sol.t) - 1 in (n, n + 1)  # n + 1: a last step of ~1 ulp
        errors.append(np.max(np.abs(sol.y[:, -1] - ref.y[:, -1])))
    orders = observed_orders(errors)
    assert np.all(orders > 3.7), (errors, orders)


def test_dense_output_has_order_three(pendulum):
    """One step from the release, read at 1/4, 1/2 and 3/4 of it, against DOP853: an
    interpolant of order 3 has a local error O(h^4) (measured: O(h^5), ratios ~32)."""
    x0 = pendulum.initial_state()
    f = lambda t, y: pendulum.rhs(t, y)  # noqa: E731
    Rodas4 = pendulum._rodas_class()
    errors = []
    for h in (0.2, 0.1, 0.05, 0.025):
        s = Rodas4(f, 0.0, x0, 1.0, jac=lambda t, y: pendulum.jacobian(t, y), first_step=h,
                   max_step=h, rtol=1e3, atol=1e3, time_dependent=False)
        assert s.step() is None and s.t == h
        d = s.dense_output()
        np.testing.assert_array_equal(d(0.0), x0)  # exact at both ends
        np.testing.assert_array_equal(d(h), s.y)
        th = np.array([0.25, 0.5, 0.75]) * h
        ref = solve_ivp(f, (0.0, h), x0, method="DOP853", rtol=1e-13, atol=1e-15,
                        t_eval=th).y
        errors.append(np.max(np.abs(d(th) - ref)))
    assert np.all(observed_orders(errors) > 3.7), errors


def test_time_derivative_term_keeps_order_four_with_inputs(msd):
    """msd under F(t) = 10 sin(3 t) (a non-autonomous rhs): with the df/dt term (forward
    difference) the order stays 4; without it (time_dependent=False, as if the model had no
    inputs) it falls below 3 (measured 2.7, 2.7, then erratic), which shows the term is there
    and right. Measured with it: 3.98, 4.00, 4.00."""
    u = {"F": lambda t: 10.0 * np.sin(3.0 * t)}
    x0 = np.zeros(2)
    ref = dop853(msd, 2.0, x0, u)
    orders = {}
    for td in (True, False):
        errors = [np.max(np.abs(fixed_steps(msd, 2.0, n, x0, td, u).y[:, -1] - ref.y[:, -1]))
                  for n in (20, 40, 80, 160)]
        orders[td] = observed_orders(errors)
    assert np.all(orders[True] > 3.5), orders
    assert np.min(orders[False]) < 3.0, orders


def test_stiff_error_is_damped_within_a_step(gen):
    """L-stability (R(inf) = 0): the two-mass chain released with its stiff spring stretched
    has a fast, lightly damped mode (lambda = -1e3 +- 1.41e4 i, like the 3R2S's joints) next
    to a slow one (-0.025 +- 7.07 i). Steps of 0.05 s (h |lambda| ~ 700) cannot follow the
    fast transient: the first step misses its impulse (measured: an error 25x the solution's
    size). The next step must wipe that error out instead of carrying it along (an A-stable
    method that is not L-stable, such as the trapezoidal rule, keeps it ringing at |R| ~ 1),
    after which only the slow mode's truncation error remains. Exact solution: the matrix
    exponential of the Jacobian (the model is linear). Measured: 25, 0.063, 3.8e-3, 2.2e-5,
    then the slow mode's global error, <= 1.4e-4 of max|x| over the 2 s."""
    chain = gen("two_mass_chain")
    from scipy.linalg import expm

    u = {"F": lambda t: 0.0 * t}
    x0 = np.array([0.0, 0.0, 0.0, 1e-7])  # link_spring.q stretched
    J = chain.jacobian(0.0, x0, None, u)
    lam = np.linalg.eigvals(J)
    assert np.max(np.abs(lam)) * 0.05 > 500
    sol = fixed_steps(chain, 2.0, 40, x0, time_dependent=True, u=u)
    exact = np.stack([expm(J * t) @ x0 for t in sol.t], axis=1)
    assert np.all(np.isfinite(sol.y))
    err = np.max(np.abs(sol.y - exact), axis=0) / np.max(np.abs(exact))
    assert err[2] < 1e-2 * err[1] and err[3] < 1e-1 * err[2], err[:5]
    assert np.all(err[4:] < 1e-3), err


def test_backward_integration_matches_closed_form(msd):
    """From the step response's state at t = 3 back to t = 1, rtol 1e-9."""
    from test_simulate import msd_step

    x3, v3 = msd_step(3.0)
    x0 = np.array([2.0 * v3, x3])  # states (mass.p = m v, spring.q = x)
    te = np.linspace(3.0, 1.0, 21)
    res = msd.simulate((3.0, 1.0), t_eval=te, x0=x0, method="Rodas4", rtol=1e-9,
                       atol=1e-12, u={"F": lambda t: 10.0 + 0.0 * t})
    x, v = msd_step(te)
    np.testing.assert_array_equal(res.t, te)
    np.testing.assert_allclose(res.y["position"], x, rtol=0, atol=1e-8 * np.max(np.abs(x)))
    np.testing.assert_allclose(res.y["velocity"], v, rtol=0, atol=1e-8 * np.max(np.abs(v)))


def test_error_control_tracks_rtol(msd):
    """Adaptive steps: the step response's error against the closed form scales with rtol
    (within 0.05..20 rtol over four decades; measured 0.27 to 0.28)."""
    from test_simulate import msd_step

    te = np.linspace(0.0, 5.0, 251)
    x, _ = msd_step(te)
    for rtol in (1e-4, 1e-6, 1e-8, 1e-10):
        res = msd.simulate((0.0, 5.0), t_eval=te, method="Rodas4", rtol=rtol,
                           atol=rtol * 1e-3)
        rel = np.max(np.abs(res.y["position"] - x)) / np.max(np.abs(x))
        assert 0.05 * rtol < rel < 20 * rtol, (rtol, rel)
        # one Jacobian per accepted step, at least one LU each, 6 rhs calls and a
        # df/dt difference per attempt
        s = res.stats
        assert s["njev"] == s["nsteps"] and s["nlu"] >= s["nsteps"]


def test_needs_the_analytic_jacobian(msd):
    with pytest.raises(ValueError, match="analytic Jacobian"):
        msd.simulate((0.0, 1.0), method="Rodas4", jac=False)


FORCED = """\
bgc: 1
name: forced_msd
parameters: {m: 1.0, k: 9.0, c: 0.4, F0: 10.0, w: 3.0}
elements:
  drive: {type: Se, effort: "F0 * sin(w * t)"}
  v: {type: "1"}
  mass: {type: I, inertia: "m"}
  spring: {type: C, stiffness: "k"}
  damper: {type: R, resistance: "c"}
bonds: [[drive, v], [v, mass], [v, spring], [v, damper]]
"""


def test_a_law_in_t_without_inputs_takes_the_time_derivative(tmp_path):
    """A law that names t (no input declared): the module says its rhs reads t, and Rodas4
    takes df/dt, so it keeps its order and its step count: against the hand-written ODE
    m x'' + c x' + k x = F0 sin(w t) (DOP853 at rtol 1e-13). Before RHS_USES_T the term was
    skipped for such models (taken from INPUT_NAMES alone): the order fell below 3."""
    from bgc.backends.load import load_module
    from bgc.format.parse import parse_file
    from bgc.run.driver import compile_model

    path = tmp_path / "forced.yaml"
    path.write_text(FORCED)
    mod = load_module(compile_model(parse_file(path)).source, "forced_msd_rodas")
    assert mod.INPUT_NAMES == () and mod.RHS_USES_T is True
    m, k, c, F0, w = 1.0, 9.0, 0.4, 10.0, 3.0

    def hand(t, y):  # states: p = m v, q = x
        p, q = y
        return [F0 * np.sin(w * t) - k * q - c * p / m, p / m]

    order = [mod.STATE_NAMES.index(s) for s in ("mass.p", "spring.q")]
    ref = solve_ivp(hand, (0.0, 2.0), [0.0, 0.0], method="DOP853", rtol=1e-13, atol=1e-15)
    errors = []
    for n in (20, 40, 80, 160):
        h = 2.0 / n
        r = solve_ivp(lambda t, y: mod.rhs(t, y), (0.0, 2.0), np.zeros(2),
                      method=mod._rodas_class(), jac=lambda t, y: mod.jacobian(t, y),
                      first_step=h, max_step=h, rtol=1e3, atol=1e3, time_dependent=True)
        errors.append(np.max(np.abs(r.y[order, -1] - ref.y[:, -1])))
    assert np.all(observed_orders(errors) > 3.5), observed_orders(errors)
    run = mod.simulate((0.0, 2.0), method="Rodas4", rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(run.x[order, -1], ref.y[:, -1], atol=1e-6)
    mod.RHS_USES_T = False  # as before: the term skipped, the error control pays for it:
    # it needs more than 3x the steps (run to the end it took about 61,000, 90 s of the suite;
    # within the 3x budget it stops near t = 0.002)
    with pytest.raises(RuntimeError, match=r"Rodas4 stopped at t = .*max_steps = "):
        mod.simulate((0.0, 2.0), method="Rodas4", rtol=1e-8, atol=1e-10,
                     max_steps=3 * run.stats["nsteps"])
    plain = load_module(compile_model(parse_file(
        Path(__file__).resolve().parents[1] / "models" / "pendulum.yaml")).source,
        "pendulum_rodas_t")
    assert plain.RHS_USES_T is False  # autonomous and input-free: no df/dt
