"""Discontinuous inputs: no blow-up, and the solver recovers, with or without a breakpoint at
the jump.

* The 3R2S circle (models/scenes/3r2s_circle.yaml): v_d jumps at t = 2 s (from the straight
  run onto the circle). Over 0..2.5 s, the run that is not told about the jump (no
  breakpoint) equals the scene's run (breakpoint at 2) to the scene's accuracy after the
  jump, at a few more steps. (The scene's run itself is compared with the independent
  reference model in tests/test_3r2s.py.)
* Step sources: the mass-spring-damper (generated/msd.py) under a square-wave force (27
  jumps in 5 s), every method, against the exact solution (a sum of closed-form step
  responses of the underdamped oscillator); and the stiff two-mass chain under a force step
  at t = 0.5 s against the matrix-exponential solution.
"""
from __future__ import annotations

import numpy as np
import pytest
from stability_helpers import SCENES, chain_exact, scene_module

ANGLES = ("theta1", "theta2", "theta3", "theta4")


# ---------------------------------------------------------------------------------------
# The circle's velocity jump
# ---------------------------------------------------------------------------------------
@pytest.mark.slow
def test_circle_velocity_jump_without_breakpoint():
    scene, mod = scene_module(SCENES / "3r2s_circle.yaml")
    assert scene.breakpoints == (2.0,)
    kw = dict(dt=0.005, method=scene.method, rtol=scene.rtol, atol=scene.atol)
    told = mod.simulate((0.0, 2.5), breakpoints=(2.0,), **kw)
    blind = mod.simulate((0.0, 2.5), **kw)
    for r in (told, blind):
        assert r.t[-1] == 2.5 and np.all(np.isfinite(r.x))
        assert all(np.all(np.isfinite(v)) for v in r.y.values())
    after = told.t >= 2.0
    # the scene's angles are within 1e-5 rad of the reference model (tests/test_3r2s.py);
    # measured here: 2.7e-6 rad, 1.9e-7 m
    for a in ANGLES:
        assert np.max(np.abs(blind.y[a] - told.y[a])[after]) < 2e-5, a
    assert np.max(np.abs(blind.y["p3"] - told.y["p3"])[:, after]) < 1e-6
    # an unannounced jump costs a few rejected steps, not a restart of the whole run
    assert blind.stats["nsteps"] < 1.2 * told.stats["nsteps"]


# ---------------------------------------------------------------------------------------
# Step sources
# ---------------------------------------------------------------------------------------
SQUARE_PERIOD = 0.37  # s: F = F0 on [0, 0.37), 0 on [0.37, 0.74), ...
SQUARE_END = 5.0


def square(F0):
    return lambda t: F0 * (np.floor(np.asarray(t, dtype=float) / SQUARE_PERIOD) % 2 == 0)


def msd_square_exact(P, t):
    """Position and velocity of m x'' + c x' + k x = F(t) from rest, F the square wave:
    the sum of the step responses x_s(tau) = dF/k [1 - e^(-z w tau) (cos wd tau
    + z / sqrt(1 - z^2) sin wd tau)] of its jumps (underdamped: z < 1)."""
    m, k, c, F0 = P["m"], P["k"], P["c"], P["F0"]
    wn, z = np.sqrt(k / m), c / (2 * np.sqrt(k * m))
    wd, s = wn * np.sqrt(1 - z * z), np.sqrt(1 - z * z)
    x, v = np.zeros_like(t), np.zeros_like(t)
    for j, tj in enumerate(np.arange(0.0, SQUARE_END, SQUARE_PERIOD)):
        dF = F0 if j % 2 == 0 else -F0
        on = t >= tj
        tau = np.where(on, t - tj, 0.0)
        e = np.exp(-z * wn * tau)
        x += on * dF / k * (1 - e * (np.cos(wd * tau) + z / s * np.sin(wd * tau)))
        v += on * dF / k * (wn / s) * e * np.sin(wd * tau)
    return x, v


@pytest.mark.parametrize("method", ["Radau", "BDF", "LSODA", "RK45", "DOP853", "Rodas4"])
def test_square_wave_force_without_breakpoints(gen, method):
    """Measured, no breakpoints: errors 2.7e-8 (Radau) to 7.7e-7 (RK45) of F0/k, the same
    as with a breakpoint at every jump; 7 to 110 % more steps."""
    mod = gen("msd")
    P = mod.PARAM_DEFAULTS
    assert P["c"] ** 2 < 4 * P["k"] * P["m"]  # underdamped, as the closed form assumes
    te = np.linspace(0.0, SQUARE_END, 2001)
    x_ex, v_ex = msd_square_exact(P, te)
    jumps = tuple(np.arange(SQUARE_PERIOD, SQUARE_END, SQUARE_PERIOD))
    kw = dict(t_eval=te, method=method, rtol=1e-8, atol=1e-10, u={"F": square(P["F0"])})
    blind = mod.simulate((0.0, SQUARE_END), **kw)
    told = mod.simulate((0.0, SQUARE_END), breakpoints=jumps, **kw)
    for r in (blind, told):
        assert np.all(np.isfinite(r.x))
        assert np.max(np.abs(r.y["position"] - x_ex)) < 1e-5 * P["F0"] / P["k"]
        assert np.max(np.abs(r.y["velocity"] - v_ex)) < 1e-5 * np.max(np.abs(v_ex))
    assert blind.stats["nsteps"] < 3 * told.stats["nsteps"]


@pytest.mark.parametrize("method", ["Radau", "BDF", "Rodas4"])
def test_stiff_chain_force_step_without_breakpoint(gen, method):
    """The two-mass chain (stiff link 1e8 N/m) at rest until its force steps on at 0.5 s."""
    mod = gen("two_mass_chain")
    P = mod.PARAM_DEFAULTS
    te = np.linspace(0.0, 1.5, 301)
    ex = chain_exact(P, te, t_on=0.5)
    F = lambda t: np.where(np.asarray(t) >= 0.5, P["F0"], 0.0)  # noqa: E731
    t, x, y = mod.simulate((0.0, 1.5), t_eval=te, method=method, rtol=1e-8,
                           atol=[1e-10, 1e-10, 1e-10, 1e-15], u={"F": F})
    assert np.all(np.isfinite(x))
    assert np.all(x[:, te < 0.5] == 0.0)  # nothing moves before the step
    err = np.max(np.abs(x - ex), axis=1) / np.max(np.abs(ex), axis=1)
    assert np.all(err < 1e-5), err
