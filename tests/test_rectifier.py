"""The half-wave rectifier (models/rectifier.yaml, models/scenes/rectifier.yaml) at its default
settings, against an independent scipy model: a Shockley diode in series with a resistor makes
a nonlinear algebraic loop that bgc solves by damped Newton in the generated code; the
reference integrates the capacitor's charge with solve_ivp and finds the loop current with its
own bracketed root solve (brentq) of i = Is (exp((Vs - vC - Rs i) / nVt) - 1).

Also here: the scene's periodic input bounds the step by default (the ripple at default
settings agrees with a run at a tight max_step), the loop converges from a cold start far from
its root (plain Newton needs hundreds of iterations there), and a loop without a root fails
with its place, the time and a remedy on both backends.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import scipy.integrate as si
import scipy.optimize as so
from conftest import seed_c_runtime

from bgc.backends.c import build as cbuild
from bgc.format.scene import parse_scene
from bgc.run.runner import run_scene

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "models" / "scenes" / "rectifier.yaml"
IS, NVT, RS, RL, C1, V0, F0 = 1e-12, 0.02585, 1.0, 1000.0, 1e-3, 10.0, 50.0
BACKENDS = ["numpy", pytest.param("c", marks=pytest.mark.skipif(
    not cbuild.available() or not cbuild.runtime_sources(), reason="no C compiler"))]


def _loop_current(vs, vc):
    """The loop current: the root of i - Is (exp((vs - vc - Rs i) / nVt) - 1), bracketed."""
    g = lambda i: i - IS * np.expm1((vs - vc - RS * i) / NVT)  # noqa: E731
    return so.brentq(g, -IS, max((vs - vc) / RS, 0.0) + 1.0, xtol=1e-15, rtol=1e-14)


@pytest.fixture(scope="module")
def reference():
    """(t, v_load) of the scipy model on the scene's output grid, tightly resolved."""
    t = np.linspace(0.0, 0.2, 2001)

    def f(tt, y):
        vc = y[0] / C1
        return [_loop_current(V0 * np.sin(2 * np.pi * F0 * tt), vc) - vc / RL]
    sol = si.solve_ivp(f, (0.0, 0.2), [0.0], method="LSODA", rtol=1e-10, atol=1e-13,
                       t_eval=t, max_step=5e-5)
    assert sol.success
    return t, sol.y[0] / C1


def _ripple(t, v):
    last = t >= 0.16  # the last two periods: the steady state
    return float(np.ptp(v[last]))


@pytest.mark.slow
@pytest.mark.parametrize("backend", BACKENDS)
def test_rectifier_default_settings_match_scipy(backend, reference, tmp_path, monkeypatch):
    """Default scene settings (Radau, rtol 1e-6, no max_step given): the load voltage within
    2 mV of the reference over the whole run, charge-up included, and its ripple within 1 %."""
    monkeypatch.setenv("BGC_CACHE_DIR", str(seed_c_runtime(tmp_path)))
    res = run_scene(parse_scene(SCENE), backend=backend)
    t_ref, v_ref = reference
    np.testing.assert_allclose(res.t, t_ref)
    v = res.y["v_load"]
    assert np.max(np.abs(v - v_ref)) < 2e-3
    assert abs(_ripple(res.t, v) - _ripple(t_ref, v_ref)) < 0.01 * _ripple(t_ref, v_ref)
    # the diode current is the load's current plus the capacitor's: positive pulses only
    assert np.min(res.y["i_diode"]) > -1e-9
    assert res.run_args["max_step"] == pytest.approx(0.02 / 50)


@pytest.mark.slow
def test_ripple_default_vs_tight_max_step(tmp_path, monkeypatch):
    """The input's period bounds the step by default: the ripple at default settings is within
    1 % of a run at max_step = 1e-5 s (C backend when there is a compiler: it is fast)."""
    monkeypatch.setenv("BGC_CACHE_DIR", str(seed_c_runtime(tmp_path)))
    backend = "c" if cbuild.available() and cbuild.runtime_sources() else "numpy"
    scene = parse_scene(SCENE)
    default = run_scene(scene, backend=backend)
    tight = run_scene(dataclasses.replace(scene, max_step=1e-5), backend=backend)
    r0, r1 = _ripple(default.t, default.y["v_load"]), _ripple(tight.t, tight.y["v_load"])
    assert 0.1 < r1 < 0.3
    assert abs(r0 - r1) < 0.01 * r1
    # without the bound (max_step = the span) Radau steps over the conduction pulses: the
    # answer is wrong, and the run says so (a spike in the outputs)
    loose = run_scene(dataclasses.replace(scene, max_step=0.2), backend="numpy",
                      progress=(lines := []).append)
    if abs(_ripple(loose.t, loose.y["v_load"]) - r1) > 0.05 * r1:
        assert any("warning: the solution misses" in ln and "max_step" in ln
                   for ln in lines), lines


def _module(backend, tmp_path):
    from bgc.run.runner import scene_module

    return scene_module(parse_scene(SCENE), backend=backend)[1]


@pytest.mark.parametrize("backend", BACKENDS)
def test_loop_converges_from_a_cold_start(backend, tmp_path, monkeypatch):
    """At the sine's peak with an empty capacitor the loop current is ~9.3 A; from a cold
    start (0 A) plain Newton moves the diode's exponent by one unit per iteration (~360 of
    them). The damped Newton solves it; the derivative agrees with the bracketed root."""
    monkeypatch.setenv("BGC_CACHE_DIR", str(seed_c_runtime(tmp_path)))
    mod = _module(backend, tmp_path)
    getattr(mod, "_NEWTON_WARM", {}).clear()
    for vc in (0.0, 5.0, 9.0):
        t = 0.005  # the sine's peak: Vs = 10 V
        dx = mod.rhs(t, np.array([vc * C1]))
        i = _loop_current(10.0, vc)
        np.testing.assert_allclose(dx[0], i - vc / RL, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("backend", BACKENDS)
def test_loop_without_root_names_time_and_remedy(backend, tmp_path, monkeypatch):
    """A negative saturation current leaves the loop without a root (the residual is
    positive everywhere): the failure names the loop's place, when, and what to try."""
    monkeypatch.setenv("BGC_CACHE_DIR", str(seed_c_runtime(tmp_path)))
    mod = _module(backend, tmp_path)
    with pytest.raises(mod.SimulationError) as e:
        mod.simulate((0.0, 0.01), p={"Is": -1e-12}, method="Radau")
    msg = str(e.value)
    assert "rectifier.yaml:" in msg and "R 'diode'" in msg and "did not converge" in msg
    assert "at t = " in msg and "max_step" in msg and "compliance" in msg
