"""The heavy symmetric top (models/top.yaml, scene models/scenes/top_precession.yaml) against
the closed form of steady precession: a symmetric top about a fixed point, tilted theta from the
vertical, spinning omega3 about its axis, precesses steadily (theta' = 0) at Omega when
    I1 cos(theta) Omega^2 - I3 omega3 Omega + m g l = 0        (Goldstein, sec. 5.7),
and then its tilt stays theta and the axis's azimuth grows as Omega t. Omega, I1 and I3 are
computed here from the model's parameters; started off the condition (no precession) the top
nods, which the same measures see."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import bgc
from bgc.backends.c import build as cbuild
from bgc.format.scene import parse_scene
from bgc.run.runner import scene_module

ROOT = Path(__file__).resolve().parents[1]
M, G, L, RD, TH, W3 = 1.0, 9.81, 0.05, 0.05, 0.3, 300.0
I3 = M * RD ** 2 / 2
I1 = M * RD ** 2 / 4 + M * L ** 2
OMEGA = (I3 * W3 - math.sqrt((I3 * W3) ** 2 - 4 * I1 * math.cos(TH) * M * G * L)) / (
    2 * I1 * math.cos(TH))


def _deviations(res, omega=OMEGA):
    tilt = np.asarray(res.y["tilt"])
    az = np.unwrap(np.asarray(res.y["azimuth"]))
    t = np.asarray(res.t)
    d_tilt = float(np.max(np.abs(tilt - TH))) / TH
    d_az = float(np.max(np.abs(az - (-math.pi / 2 + omega * t)))) / (omega * t[-1])
    return d_tilt, d_az


@pytest.fixture(scope="module")
def top():
    return bgc.compile(str(ROOT / "models" / "top.yaml"))


def test_the_model_starts_on_the_condition(top):
    assert I1 * math.cos(TH) * OMEGA ** 2 - I3 * W3 * OMEGA + M * G * L == pytest.approx(
        0, abs=1e-12)
    x0 = np.asarray(top.initial_state()).reshape(-1)
    y = top.outputs(0.0, x0)
    w = np.asarray(y["omega"]).reshape(-1)
    axis = np.array([0.0, -math.sin(TH), math.cos(TH)])
    np.testing.assert_allclose(w, [0, 0, OMEGA] + (W3 - OMEGA * math.cos(TH)) * axis,
                               rtol=1e-12, atol=1e-12)
    assert float(np.dot(w, axis)) == pytest.approx(W3, rel=1e-12)


def test_steady_precession_stays_steady(top):
    res = top.simulate((0.0, 1.0), method="DOP853", rtol=1e-10, atol=1e-12, dt=0.01)
    d_tilt, d_az = _deviations(res)
    assert d_tilt < 1e-6 and d_az < 1e-6, (d_tilt, d_az)
    e = np.asarray(res.y["energy"])
    assert np.max(np.abs(e - e[0])) < 1e-9 * abs(e[0])


def test_off_the_condition_the_top_nods(top):
    """The same measures fail for a top started with its spin alone (no precession): it nods
    (nutation), the tilt moving by far more than 1e-6."""
    R0 = np.array([[1, 0, 0], [0, math.cos(TH), -math.sin(TH)],
                   [0, math.sin(TH), math.cos(TH)]])
    w = W3 * R0[:, 2]
    h = R0 @ np.diag([I1, I1, I3]) @ R0.T @ w
    names = list(top.STATE_NAMES)
    x0 = np.asarray(top.initial_state(), dtype=float).reshape(-1).copy()
    k = names.index("Ir.p[0]")
    x0[k:k + 3] = h
    res = top.simulate((0.0, 0.2), method="DOP853", rtol=1e-10, atol=1e-12, dt=0.001, x0=x0)
    d_tilt, _ = _deviations(res)
    assert d_tilt > 1e-4


@pytest.mark.slow
@pytest.mark.skipif(not (cbuild.available() and cbuild.runtime_sources()),
                    reason="no C compiler")
def test_the_scene_on_c_dop853_precesses_steadily():
    """The whole scene (5 s, about one precession) on the C backend's DOP853."""
    sc = parse_scene(ROOT / "models" / "scenes" / "top_precession.yaml")
    backend, mod = scene_module(sc, None, "c")
    assert backend == "c"
    res = mod.simulate(sc.t_span, method="DOP853", rtol=sc.rtol, atol=sc.atol, dt=sc.dt)
    d_tilt, d_az = _deviations(res)
    assert d_tilt < 1e-6 and d_az < 1e-6, (d_tilt, d_az)
