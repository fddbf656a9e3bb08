"""Constraint components dropped as redundant at the start, watched along a run (issue 24).

The compile drops a component whose row of the velocity constraints' Jacobian adds nothing at
the initial state (reaction 0). A run then checks, at its output times, each dropped
component's velocity residual (its violation state's rate, a row of the generated rhs) and
warns where it left the run's tolerance scale: the mechanism left the configuration in which
the component was redundant.

Answers from outside bgc:
- tests/loops/parallelogram_slider.yaml: the parallelogram linkage hanging straight down
  with a slider holding crank 1's far end B at y = -l. At the hanging pose the slider's row
  and the ground pin O1's vertical row coincide (both l cos th times the crank's rate vanish
  with the pin's own), so one of them is dropped; bgc keeps the slider (locks first) and drops
  O1.q[1]. B then stays at y = -l, so the pin's point A = B - l (cos th1, sin th1) has
  y_A = -l (1 + sin th1): its vertical velocity, O1.q[1]'s residual, is -l cos(th1) w1,
  computed here from the run's crank angle and rate alone. The torque swings the linkage
  away from th1 = -pi/2, so the residual grows: a warning.
- tests/loops/parallelogram.yaml (its redundant O3.q[1] stays redundant on the whole motion:
  a parallelogram stays one) and tests/loops/fourbar_3dpins.yaml (the planar loop of 3-D
  joints: its dropped components are out of the plane, and nothing leaves the plane): no
  warning, residuals at rounding level. (The four-bar's test is in tests/test_loops_3d.py,
  which builds that model's C module once for all its tests.)
"""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml

import bgc
from bgc.run.runner import run_scene
from bgc.run.watch import dropped_residuals

ROOT = Path(__file__).resolve().parents[1]
LOOPS = ROOT / "tests" / "loops"
SLIDER = LOOPS / "parallelogram_slider.yaml"
LEFT = "the mechanism left the configuration in which O1.q[1] was redundant"


def _params(path: Path) -> dict:
    """The model's base parameter values, read as data (nothing evaluated)."""
    raw = yaml.safe_load(path.read_text())["parameters"]
    return {k: v["value"] for k, v in raw.items() if isinstance(v["value"], (int, float))}


def _run(m, span=2.0):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = m.simulate((0.0, span), t_eval=np.linspace(0.0, span, 201), method="Radau",
                         rtol=1e-9, atol=1e-11)
    return res, [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]


@pytest.mark.parametrize("target", ["numpy", "c"])
def test_a_component_that_stops_being_redundant_is_reported(target):
    m = bgc.compile(str(SLIDER), target=target)
    assert "O1.q[1]" in m.module.CONSTRAINT_DROPPED
    res, caught = _run(m)
    t, x = res[0], res[1]
    names, r = dropped_residuals(m.module, t, x)
    got = r[:, names.index("O1.q[1]")]
    pv = _params(SLIDER)
    l, m1 = pv["l"], pv["m1"]
    names_x = list(m.module.STATE_NAMES)
    th1 = x[names_x.index("crank1.th")]
    w1 = x[names_x.index("crank1.Ir.p")] / (m1 * l ** 2 / 12)  # the rod's J = m l^2 / 12
    expected = -l * np.cos(th1) * w1
    assert abs(got[0]) < 1e-12  # redundant at the start
    assert np.abs(expected).max() > 1e-3  # the linkage swings away from the hanging pose
    assert np.abs(got - expected).max() < 1e-6 * np.abs(expected).max()
    # the pin's point drifts as the closed form says: y_A - y_A(0) = -l (1 + sin th1)
    q = x[names_x.index("O1.q[1]")]
    assert np.abs(q - (-l * (1 + np.sin(th1)))).max() < 1e-7
    assert len(caught) == 1, caught
    assert LEFT in caught[0] and "O1.q[1]" in caught[0]
    k = int(np.argmax(np.abs(got)))
    assert f"reaches {got[k]:.3g} at t = {t[k]:.6g} s" in caught[0]


def test_a_scene_run_warns_on_the_c_backend(tmp_path):
    scene = tmp_path / "slider.yaml"
    scene.write_text(f"bgc_scene: 1\nname: slider\nmodel: {SLIDER}\nduration: 2.0\n"
                     "outputs: [th1]\nsolver: {method: Radau, rtol: 1.0e-8, atol: 1.0e-10, "
                     "dt: 0.01, backend: c}\n")
    said: list = []
    r = run_scene(scene, progress=said.append)
    assert r.backend == "c"
    warned = [s for s in said if s.startswith("warning: ") and LEFT in s]
    assert len(warned) == 1, said


def test_a_component_that_stays_redundant_is_quiet():
    m = bgc.compile(str(LOOPS / "parallelogram.yaml"))
    assert m.module.CONSTRAINT_DROPPED == ("O3.q[1]",)
    res, caught = _run(m)
    names, r = dropped_residuals(m.module, res[0], res[1])
    assert caught == []
    assert np.abs(r).max() < 1e-10


# The 3-D-pin four-bar's run without the warning is in tests/test_loops_3d.py
# (test_the_3d_pin_fourbar_runs_without_the_watch_warning), where its C module is built once
# for all the tests of that model.


def test_bgc_simulate_warns_and_so_does_its_replay(tmp_path):
    """The command line, twice: the full way, then the warm replay from its run record."""
    import os
    import subprocess
    import sys

    scene = tmp_path / "slider.yaml"
    scene.write_text(f"bgc_scene: 1\nname: slider\nmodel: {SLIDER}\nduration: 2.0\n"
                     "outputs: [th1]\nsolver: {method: Radau, rtol: 1.0e-8, atol: 1.0e-10, "
                     "dt: 0.01, backend: c}\n")
    env = dict(os.environ)
    src = str(ROOT / "src")
    env["PYTHONPATH"] = src + os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else src
    for _ in range(2):
        r = subprocess.run([sys.executable, "-m", "bgc", "simulate", str(scene)], cwd=tmp_path,
                           env=env, text=True, capture_output=True, timeout=600,
                           stdin=subprocess.DEVNULL)
        assert r.returncode == 0, r.stderr
        out = r.stdout + r.stderr
        assert out.count(LEFT) == 1, out
    assert "run record" in out  # the second run was the replay
