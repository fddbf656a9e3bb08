"""Orientation over a long run: 100 s of the 3R2S going round its circle
(models/scenes/3r2s_long.yaml: the circle scene repeated, 24.5 revolutions), Radau at
rtol 1e-6 (atol 5e-7).

Each link's rotation matrix R is integrated as nine auxiliary states (R' = [w x] R), so
R^T R = I holds only up to integration error. Without help that error accumulates: measured
at the solver's steps, ||R^T R - I|| of link 4 grew linearly from 4.9e-8 (first 10 s) to
7.8e-7 (last 10 s), and would pass 1e-6 at about 130 s. The model therefore carries the
stabilising term -(gamma_R / 2) R (R^T R - I) (models/3r2s.yaml, gamma_R = 1 / s), which
vanishes on R^T R = I and pulls R back to it at rate gamma_R.

Checked (||.|| the Frobenius norm, all four links):
* at the solver's steps (the integrated states): below 1e-6, and no larger over the last
  10 s than twice the first 10 s (measured 3.6e-8 overall; 2.7e-8 against 2.4e-8);
* on the scene's 10 ms output grid (Radau's dense output between steps, whose interpolation
  adds its own error): below 1e-6 (measured 8.7e-7);
* over the whole 100 s the power balance holds: energy - E(0) = work of the drive - energy
  dissipated, to 3e-5 of the energy's swing (tests/test_3r2s.py asks 1e-5 over 6 s; the work
  integrals accumulate their integration error over the 100 s: measured 7.5e-6).
"""
from __future__ import annotations

import numpy as np
import pytest
from stability_helpers import SCENES, orthogonality_error, rows, scene_module, scene_run

LINKS = ("link1", "link2", "link3", "link4")


def deviation(mod, x):
    """(4, N): ||R^T R - I|| of each link."""
    return np.array([orthogonality_error(rows(mod, x, f"{k}.R", (3, 3))) for k in LINKS])


@pytest.fixture(scope="module")
def long_runs():
    scene, mod = scene_module(SCENES / "3r2s_long.yaml")
    assert scene.t_span == (0.0, 100.0) and scene.rtol == 1e-6
    assert mod.PARAM_DEFAULTS.get("gamma_R", 1.0) > 0
    steps = scene_run(scene, mod, dt=None)  # the solution at every step
    grid = scene_run(scene, mod)  # the scene's output grid
    return scene, mod, steps, grid


@pytest.mark.slow
def test_rotation_matrices_stay_orthogonal_at_the_steps(long_runs):
    _, mod, steps, _ = long_runs
    t, x = steps.t, steps.x
    assert t[-1] == 100.0 and np.all(np.isfinite(x))
    dev = deviation(mod, x)
    assert np.max(dev) < 1e-6
    first, last = dev[:, t <= 10.0].max(), dev[:, t >= 90.0].max()
    assert last <= 2.0 * first, (first, last)


@pytest.mark.slow
def test_rotation_matrices_stay_orthogonal_on_the_output_grid(long_runs):
    _, mod, _, grid = long_runs
    dev = deviation(mod, grid.x)
    assert np.max(dev) < 1e-6
    t = grid.t
    assert dev[:, t >= 90.0].max() <= 2.0 * dev[:, t <= 10.0].max()


@pytest.mark.slow
def test_power_balance_over_100_s(long_runs):
    _, _, _, grid = long_runs
    y = grid.y
    assert all(np.all(np.isfinite(v)) for v in y.values())
    E = y["energy"]
    balance = E - E[0] - (y["work_drive"] - y["dissipated"])
    assert np.max(np.abs(balance)) < 3e-5 * (np.max(E) - np.min(E))
