"""The generated runtime, simulate(): scipy's OdeSolver classes stepped by hand.

Expected values come from closed forms (derived in the comments) or from scipy's own driver,
solve_ivp, run on the module's rhs with the same solver settings; none from a bgc run.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

METHODS = ("RK23", "RK45", "DOP853", "Radau", "BDF", "LSODA", "Rodas4")
IMPLICIT = ("Radau", "BDF", "LSODA", "Rodas4")

# models/msd.yaml: m x'' + c x' + k x = F, x(0) = x'(0) = 0; states (mass.p, spring.q)
M, K, C, F0 = 2.0, 200.0, 4.0, 10.0


def msd_step(t, m=M, c=C, k=K, F=F0):
    """Underdamped step response (zeta < 1), wn = sqrt(k/m), wd = wn sqrt(1 - zeta^2):
    x = F/k [1 - e^(-zeta wn t)(cos wd t + zeta/sqrt(1 - zeta^2) sin wd t)],
    v = F/k wn/sqrt(1 - zeta^2) e^(-zeta wn t) sin wd t."""
    t = np.asarray(t, dtype=float)
    wn = np.sqrt(k / m)
    z = c / (2 * np.sqrt(k * m))
    assert z < 1
    r = np.sqrt(1 - z * z)
    ex = np.exp(-z * wn * t)
    x = F / k * (1 - ex * (np.cos(wn * r * t) + z / r * np.sin(wn * r * t)))
    return x, F / k * wn / r * ex * np.sin(wn * r * t)


def step_at(t_on, F=F0):
    """The input override F(t) = 0 before t_on, F after (right-continuous)."""
    return {"F": lambda t: np.where(np.asarray(t) < t_on, 0.0, F)}


def assert_close(actual, expected, rel):
    """|actual - expected| <= rel * max|expected|, elementwise."""
    expected = np.asarray(expected, dtype=float)
    scale = float(np.max(np.abs(expected)))
    np.testing.assert_allclose(actual, expected, rtol=0, atol=rel * scale)


@pytest.fixture(scope="module")
def msd(gen):
    mod = gen("msd")
    assert mod.STATE_NAMES == ("mass.p", "spring.q")
    return mod


# ---------------------------------------------------------------------------------------------
# Against closed forms and against solve_ivp


@pytest.mark.parametrize("method", METHODS)
def test_step_response_matches_closed_form(msd, method):
    t_eval = np.linspace(0.0, 5.0, 251)
    rtol = 1e-6 if method == "RK23" else 1e-9  # RK23 (order 3) at 1e-9 takes ~1e5 steps
    res = msd.simulate((0.0, 5.0), t_eval=t_eval, method=method, rtol=rtol, atol=rtol * 1e-3)
    x, v = msd_step(t_eval)
    np.testing.assert_array_equal(res.t, t_eval)
    assert res.x.shape == (2, len(t_eval))
    # global error of a few hundred rtol at most (measured: <= 60 rtol)
    assert_close(res.y["position"], x, 1000 * rtol)
    assert_close(res.y["velocity"], v, 1000 * rtol)


def _scipy_reference(mod, method, t_span, x0, **kw):
    """scipy's own driver on the module's rhs (and analytic Jacobian), same settings.
    Rodas4 (bgc's own OdeSolver) is handed to solve_ivp as a class."""
    if method in IMPLICIT:
        kw["jac"] = lambda t, y: mod.jacobian(t, y)
    if method == "Rodas4":
        method = mod._rodas_class()
        kw["time_dependent"] = bool(mod.INPUT_NAMES)
    return solve_ivp(lambda t, y: mod.rhs(t, y), t_span, x0, method=method, **kw)


@pytest.mark.parametrize("method", METHODS)
def test_same_steps_and_values_as_solve_ivp(gen, method):
    """Without breakpoints the loop drives the same solver as solve_ivp: the same accepted
    steps, the same dense output at t_eval, the same counts."""
    mod = gen("point_mass_3d")
    x0 = np.linspace(-0.1, 0.1, 6)
    kw = dict(rtol=1e-7, atol=1e-10)
    t_eval = np.linspace(0.0, 3.0, 97)
    every = mod.simulate((0.0, 3.0), method=method, x0=x0, **kw)
    ref = _scipy_reference(mod, method, (0.0, 3.0), x0, **kw)
    assert ref.success
    np.testing.assert_array_equal(every.t, ref.t)
    np.testing.assert_allclose(every.x, ref.y, rtol=1e-13, atol=1e-15)
    assert every.stats["nsteps"] == len(ref.t) - 1
    assert every.stats["nfev"] == ref.nfev
    assert (every.stats["njev"], every.stats["nlu"]) == (ref.njev, ref.nlu)
    dense = mod.simulate((0.0, 3.0), t_eval=t_eval, method=method, x0=x0, **kw)
    ref = _scipy_reference(mod, method, (0.0, 3.0), x0, t_eval=t_eval, **kw)
    np.testing.assert_array_equal(dense.t, t_eval)
    np.testing.assert_allclose(dense.x, ref.y, rtol=1e-12, atol=1e-15)


def test_backward_integration_matches_solve_ivp(gen):
    mod = gen("point_mass_3d")
    x0 = np.linspace(-0.1, 0.1, 6)
    t_eval = np.linspace(2.0, 0.0, 41)
    res = mod.simulate((2.0, 0.0), t_eval=t_eval, method="DOP853", x0=x0, rtol=1e-9,
                       atol=1e-12)
    ref = _scipy_reference(mod, "DOP853", (2.0, 0.0), x0, t_eval=t_eval, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(res.t, t_eval)  # in the direction of integration
    np.testing.assert_allclose(res.x, ref.y, rtol=1e-12, atol=1e-15)


# ---------------------------------------------------------------------------------------------
# Statistics


@pytest.mark.parametrize("method", METHODS)
def test_stats_are_present_and_consistent(msd, method):
    res = msd.simulate((0.0, 2.0), dt=0.1, method=method, rtol=1e-6)
    s = res.stats
    assert {"nfev", "njev", "nlu", "nsteps"} <= set(s)
    assert s["nsteps"] > 0 and s["nfev"] >= s["nsteps"]
    if method in IMPLICIT:
        assert s["njev"] >= 1 and s["nlu"] >= 1
    else:
        assert s["njev"] == 0 and s["nlu"] == 0
        # an explicit Runge-Kutta step costs a fixed number of stages (FSAL: one saved)
        stages = {"RK23": 3, "RK45": 6, "DOP853": 12}[method]
        assert s["nfev"] >= stages * s["nsteps"]


@pytest.mark.parametrize("method", ["DOP853", "Radau"])
def test_stats_and_states_sum_over_segments(msd, method):
    """Two breakpoints = three solvers: one call equals three calls chained by hand."""
    kw = dict(method=method, rtol=1e-8, atol=1e-11)
    whole = msd.simulate((0.0, 3.0), breakpoints=[1.0, 2.0], **kw)
    x, stats = None, {}
    for a, c in ((0.0, 1.0), (1.0, 2.0), (2.0, 3.0)):
        part = msd.simulate((a, c), x0=x, **kw)
        x = part.x[:, -1]
        for key in ("nfev", "njev", "nlu", "nsteps"):
            stats[key] = stats.get(key, 0) + part.stats[key]
    assert {k: whole.stats[k] for k in stats} == stats
    np.testing.assert_array_equal(whole.x[:, -1], x)
    assert list(whole.t).count(1.0) == 1 and list(whole.t).count(2.0) == 1


# ---------------------------------------------------------------------------------------------
# Output times


def test_dt_gives_a_uniform_grid_including_both_ends(msd):
    res = msd.simulate((0.0, 2.0), dt=0.05, method="RK45", rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(res.t, np.linspace(0.0, 2.0, 41))
    assert_close(res.y["position"], msd_step(res.t)[0], 1e-6)


def test_t_eval_sorted_deduplicated_and_clipped_to_the_span(msd):
    res = msd.simulate((0.0, 2.0), t_eval=[1.5, -1.0, 0.25, 1.5, 3.0, 2.0, 0.0],
                       method="DOP853", rtol=1e-10, atol=1e-13)
    np.testing.assert_array_equal(res.t, [0.0, 0.25, 1.5, 2.0])
    assert res.x.shape == (2, 4)
    np.testing.assert_array_equal(res.x[:, 0], [0.0, 0.0])  # x0 exactly at t0
    assert_close(res.y["position"], msd_step(res.t)[0], 1e-7)


def test_without_t_eval_every_step_and_every_segment_end(msd):
    res = msd.simulate((0.0, 3.0), breakpoints=[0.7, 2.5, 7.0], method="RK45")
    assert res.t[0] == 0.0 and res.t[-1] == 3.0
    assert np.all(np.diff(res.t) > 0)
    assert len(res.t) == res.stats["nsteps"] + 1
    assert 0.7 in res.t and 2.5 in res.t and 7.0 not in res.t  # 7 lies outside the span


@pytest.mark.parametrize("method", ["RK45", "Radau", "LSODA", "Rodas4"])
def test_output_times_at_and_around_breakpoints(msd, method):
    """The output at a breakpoint is the state reached there (continuous across the jump);
    times just either side come from the dense output of the two segments."""
    eps = 1e-9
    t_eval = np.array([0.0, 0.5, 1.0 - eps, 1.0, 1.0 + eps, 1.5, 2.0])
    res = msd.simulate((0.0, 2.0), t_eval=t_eval, method=method, rtol=1e-10, atol=1e-13,
                       u=step_at(1.0), breakpoints=[1.0])
    np.testing.assert_array_equal(res.t, t_eval)
    # before the step nothing moves; after it, the step response delayed by 1 s
    expected = np.where(t_eval < 1.0, 0.0, msd_step(np.maximum(t_eval - 1.0, 0.0))[0])
    assert_close(res.y["position"], expected, 1e-7)
    np.testing.assert_array_equal(res.x[:, :4], 0.0)  # exactly at rest up to t = 1


# ---------------------------------------------------------------------------------------------
# One-sided inputs at breakpoints


def test_step_input_at_a_breakpoint_at_tight_tolerance(msd):
    """Radau at rtol 1e-12 through a force step at t = 1 (a breakpoint). Radau evaluates its
    last stage at the segment's end: with the input's jumped value there (the solve_ivp
    runtime) it failed ("Required step size is less than spacing between numbers")."""
    t_eval = np.linspace(0.0, 2.5, 251)
    res = msd.simulate((0.0, 2.5), t_eval=t_eval, method="Radau", rtol=1e-12, atol=1e-15,
                       u=step_at(1.0), breakpoints=[1.0])
    before, after = t_eval < 1.0, t_eval >= 1.0
    np.testing.assert_array_equal(res.y["position"][before], 0.0)
    np.testing.assert_array_equal(res.y["velocity"][before], 0.0)
    x, v = msd_step(t_eval[after] - 1.0)
    assert_close(res.y["position"][after], x, 1e-10)
    assert_close(res.y["velocity"][after], v, 1e-10)


def test_the_model_sees_t_one_sided_inside_each_segment(msd):
    """Every rhs/Jacobian call of the first segment sees t < 1 (the last stage at t = 1 is
    moved one ulp left), every call of the second t >= 1."""
    seen = []

    def force(t):
        if np.ndim(t) == 0:  # the solvers' calls (outputs() takes all times at once)
            seen.append(float(t))
        return np.where(np.asarray(t) < 1.0, 0.0, F0)

    msd.simulate((0.0, 2.0), method="Radau", rtol=1e-8, atol=1e-11, u={"F": force},
                 breakpoints=[1.0])
    seen = np.array(seen)
    first = np.arange(len(seen)) < np.argmax(seen >= 1.0)
    assert np.all(seen[first] < 1.0) and np.all(seen[~first] >= 1.0)
    assert np.nextafter(1.0, 0.0) in seen  # Radau's last stage, held inside the segment
    assert seen.max() <= 2.0


# ---------------------------------------------------------------------------------------------
# Tolerances, wall time, methods


def test_per_state_atol(msd):
    kw = dict(t_eval=np.linspace(0, 2, 21), method="RK45", rtol=1e-6)
    scalar = msd.simulate((0.0, 2.0), atol=1e-9, **kw)
    same = msd.simulate((0.0, 2.0), atol=[1e-9, 1e-9], **kw)
    np.testing.assert_array_equal(scalar.x, same.x)
    assert scalar.stats == same.stats
    # a per-state atol reaches the solver as given (scipy's solve_ivp with the same array)
    atol = np.array([1e-4, 1e-12])
    res = msd.simulate((0.0, 2.0), atol=atol, method="RK45", rtol=1e-6)
    ref = solve_ivp(lambda t, y: msd.rhs(t, y), (0.0, 2.0), [0.0, 0.0], method="RK45",
                    rtol=1e-6, atol=atol)
    np.testing.assert_array_equal(res.t, ref.t)
    assert res.stats["nfev"] == ref.nfev
    # over a batch it applies per state to every instance: two identical instances have the
    # same error norm as one, hence the same steps (atol [a, b] tiled instead of repeated
    # over the flat state would pair the wrong values)
    pair = msd.simulate((0.0, 2.0), atol=atol, method="RK45", rtol=1e-6, p={"m": [M, M]})
    assert pair.stats["nsteps"] == res.stats["nsteps"]
    np.testing.assert_allclose(pair.x[:, 1, -1], res.x[:, -1], rtol=1e-12)
    with pytest.raises(ValueError, match="atol"):
        msd.simulate((0.0, 1.0), atol=[1e-9, 1e-9, 1e-9])


def test_max_wall_stops_the_run(msd):
    with pytest.raises(msd.SimulationError, match="max_wall") as exc:
        msd.simulate((0.0, 1e4), method="DOP853", rtol=1e-12, atol=1e-15, max_wall=0.0)
    err = exc.value
    assert not isinstance(err, msd.StiffnessError)
    assert err.stats["nsteps"] == 1 and 0.0 < err.t < 1e4  # stopped after its first step
    # a run that takes seconds (~2e4 steps) stops too
    with pytest.raises(msd.SimulationError, match="max_wall") as exc:
        msd.simulate((0.0, 1e4), method="DOP853", rtol=1e-12, atol=1e-15, max_wall=0.2)
    assert exc.value.t < 1e4 and exc.value.stats["nsteps"] >= 1


def test_solver_failure_is_a_simulation_error_with_counts(msd):
    """A force that turns NaN at t = 0.5: the first rhs call past 0.5 stops RK45 with a
    NonFiniteError (a SimulationError) naming the state the force drives, mass.p (the force
    enters only the momentum balance), within the step that crossed t = 0.5."""
    with pytest.raises(msd.SimulationError, match="RK45 failed at t = 0.5") as exc:
        msd.simulate((0.0, 1.0), method="RK45",
                     u={"F": lambda t: np.where(np.asarray(t) < 0.5, F0, np.nan)})
    err = exc.value
    assert not isinstance(err, msd.StiffnessError) and isinstance(err, msd.NonFiniteError)
    assert 0.5 <= err.t < 0.52 and err.stats["nfev"] > 0
    assert err.where == "rhs" and msd.STATE_NAMES[err.index] == "mass.p"
    assert "dmass.p/dt is nan" in str(err) and "element 'mass'" in str(err)


def test_unknown_method(msd):
    with pytest.raises(ValueError, match="Euler"):
        msd.simulate((0.0, 1.0), method="Euler")


# ---------------------------------------------------------------------------------------------
# Batches and Jacobians


BATCH_C = np.array([2.0, 4.0, 8.0, 12.0])


@pytest.mark.parametrize("method,jac", [("Radau", True), ("Radau", False), ("BDF", True),
                                        ("BDF", False), ("LSODA", True), ("DOP853", True),
                                        ("Rodas4", True)])
def test_batch_equals_single_runs(msd, method, jac):
    """Four damping values in one call (flat state, block-diagonal Jacobian: sparse for Radau
    and BDF, dense for LSODA, or finite differences over the block pattern) equal four calls,
    and each the closed form. The batch takes other steps (one error norm for all), so the
    agreement is the solvers' accuracy."""
    t_eval = np.linspace(0.0, 2.0, 41)
    kw = dict(t_eval=t_eval, method=method, rtol=1e-8, atol=1e-11, jac=jac)
    batch = msd.simulate((0.0, 2.0), p={"c": BATCH_C}, **kw)
    assert batch.x.shape == (2, 4, len(t_eval))
    assert batch.y["position"].shape == (4, len(t_eval))
    if method in ("Radau", "BDF", "Rodas4"):
        assert batch.stats["njev"] >= 1
    for i, c in enumerate(BATCH_C):
        single = msd.simulate((0.0, 2.0), p={"c": c}, **kw)
        assert_close(batch.x[:, i], single.x, 1e-6)
        assert_close(batch.y["position"][i], msd_step(t_eval, c=c)[0], 1e-6)


def test_lsoda_batch_gets_the_dense_block_jacobian(msd):
    """A stiff spring (k = 2e6 N/m, zeta = 0.5: eigenvalues -500 +- 866i 1/s) over 2 s makes
    LSODA switch to BDF, which uses the analytic Jacobian: for a batch, a dense block matrix."""
    k, c = 2e6, np.array([1500.0, 2000.0])
    t_eval = np.linspace(0.0, 2.0, 41)
    res = msd.simulate((0.0, 2.0), t_eval=t_eval, method="LSODA", rtol=1e-8, atol=1e-13,
                       p={"k": k, "c": c})
    assert res.stats["njev"] >= 1
    for i in range(2):
        assert_close(res.y["position"][i], msd_step(t_eval, c=c[i], k=k)[0], 1e-5)


def test_two_dimensional_batch_with_per_instance_x0(msd):
    """p of shape (2, 3) and x0 of shape (n, 3) broadcast to the batch (2, 3), numpy-style."""
    m = np.array([[1.0], [3.0]]) * np.ones((2, 3))
    x0 = np.array([[0.0, 0.1, -0.2], [0.01, 0.0, 0.02]])  # (p, q) for 3 columns
    t_eval = np.linspace(0.0, 1.0, 11)
    kw = dict(t_eval=t_eval, method="BDF", rtol=1e-8, atol=1e-11)
    res = msd.simulate((0.0, 1.0), p={"m": m}, x0=x0, **kw)
    assert res.x.shape == (2, 2, 3, len(t_eval))
    for i in range(2):
        for j in range(3):
            single = msd.simulate((0.0, 1.0), p={"m": m[i, j]}, x0=x0[:, j], **kw)
            assert_close(res.x[:, i, j], single.x, 1e-6)


def test_finite_difference_jacobian_counts(gen):
    """jac=False: finite differences over JAC_SPARSITY give the same answer as the analytic
    Jacobian, and their rhs calls are counted."""
    mod = gen("point_mass_3d")
    x0 = np.linspace(-0.1, 0.1, 6)
    t_eval = np.linspace(0.0, 2.0, 41)
    kw = dict(t_eval=t_eval, method="Radau", rtol=1e-8, atol=1e-11, x0=x0)
    analytic = mod.simulate((0.0, 2.0), **kw)
    fd = mod.simulate((0.0, 2.0), jac=False, **kw)
    assert fd.stats["njev"] >= 1
    assert_close(fd.x, analytic.x, 1e-6)
    # every finite-difference Jacobian costs rhs calls the analytic run does not make
    assert fd.stats["nfev"] > analytic.stats["nfev"]
