"""`method: auto` (bgc.run.method_choice): DOP853 for a model that is not stiff, Radau for one
that is, from the analytic Jacobian's eigenvalues along a short probe.

The expected choices come from the models' known spectra, worked out by hand here: the Van der
Pol oscillator at mu = 1000 (Hairer's stiff test problem: at y = (2, 0) the scaled Jacobian
[[0, 1], [-1, -3 mu^2]] has an eigenvalue near -3e6), the RC ladder (eigenvalues down to about
-4 / (R C) = -400 1/s over 10 s: thousands of stable explicit steps), and the frictionless
pendulum (eigenvalues on the imaginary axis: no decaying mode, so stability binds nothing).
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

import bgc
from bgc.format.scene import parse_scene
from bgc.run import method_choice
from bgc.run.runner import run_scene

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

from bench_scale import ladder_yaml  # noqa: E402


def test_stability_steps_by_hand():
    # one decaying mode -1000 1/s over 10 s: 1000 * 10 / 5.9 steps
    assert method_choice.stability_steps([-1000.0], 10.0) == pytest.approx(1000 * 10 / 5.9)
    # an undamped oscillation and a slow decay (e^-1 over the span) do not count
    assert method_choice.stability_steps([5j, -5j, -0.1], 10.0) == 0.0
    assert method_choice.stability_steps([np.nan], 1.0) == np.inf


def test_van_der_pol_mu_1000_is_stiff(gen):
    vdp = gen("van_der_pol")
    method, why = method_choice.choose(vdp, (0.0, 2.0))
    assert method == "Radau" and "stiff" in why


def test_the_rc_ladder_is_stiff():
    ladder = bgc.compile(ladder_yaml(8)).module
    method, why = method_choice.choose(ladder, (0.0, 10.0))
    assert method == "Radau", why


def test_the_pendulum_is_not_stiff(gen):
    pend = gen("pendulum")
    method, why = method_choice.choose(pend, (0.0, 10.0))
    assert method == "DOP853" and "not stiff" in why


def test_a_scene_with_method_auto_runs_the_chosen_method(tmp_path):
    """Through run_scene (what bgc simulate runs): the pendulum's swing with DOP853, its
    energy kept (m g l (1 - cos 2) + the kinetic energy stays the start's potential)."""
    (tmp_path / "pendulum.yaml").write_bytes((ROOT / "models" / "pendulum.yaml").read_bytes())
    (tmp_path / "s.yaml").write_text(
        "bgc_scene: 1\nmodel: pendulum.yaml\nduration: 5.0\n"
        "solver: {method: auto, rtol: 1.0e-9, atol: 1.0e-12, dt: 0.05}\n")
    res = run_scene(parse_scene(tmp_path / "s.yaml"), backend="numpy")
    assert res.method == "DOP853" and "auto: not stiff" in res.backend_why
    p, q = res.x  # (bob.p = m l^2 w, gravity.q = theta)
    energy = p ** 2 / 2 + 9.81 * (1 - np.cos(q))
    assert np.max(np.abs(energy - 9.81 * (1 - np.cos(2.0)))) < 1e-6
