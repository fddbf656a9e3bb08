"""A newcomer's first systems (docs/first_models.md, "The textbook systems"), built from the
component library and run as `bgc simulate SCENE --out r.npz` at default settings (no method,
tolerance, max_step or backend: the scenes give the span and the output grid only), each
against a closed form worked out here by hand:

- RC low-pass (R C = tau): step v = 1 - exp(-t/tau); sine at w: v = A sin(w t + phi)
  - A sin(phi) exp(-t/tau), A = 1/sqrt(1 + (w tau)^2), phi = -atan(w tau);
- mass-spring-damper released from rest at x0: x = x0 exp(-s t)(cos(wd t) + s/wd sin(wd t)),
  s = c/(2m), wd = sqrt(k/m - s^2);
- a block thrown at v0 against dry friction Fk: v = v0 - Fk t/m until t* = m v0/Fk, where it
  sticks at x* = m v0^2/(2 Fk);
- a DC motor (R, L, k) on an inertia J and viscous drag b, a voltage step U: the second-order
  linear system's step response, steady speed k U/(R b + k^2), poles of s^2 + (R/L + b/J) s +
  (R b + k^2)/(L J);
- two open tanks (A1, A2) joined by a linear restriction Rh: the level difference decays as
  exp(-t/tau), tau = Rh A1 A2/(rho g (A1 + A2));
- a rod of length l pinned at its end: small-amplitude period 2 pi sqrt(2 l/(3 g)), times
  (1 + th0^2/16) for the amplitude th0;
- a ball dropped from h0 with restitution e: first impact at sqrt(2 h0/g), then intervals
  2 e^k v1/g, v1 = sqrt(2 g h0).

Also what tripped the newcomer on the way: a library part's elements (what an output reads)
were named nowhere, and a Zeno stop advised an option `bgc simulate` does not have.

Every run compiles one small model (the C backend where a C compiler works): a few seconds
each on the shared cores.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from conftest import bgc_in_process, seed_c_runtime

ROOT = Path(__file__).resolve().parents[1]
FIRST = ROOT / "docs" / "first_models"


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """One compile cache for the module's runs (the C runtime's objects seeded)."""
    d = tmp_path_factory.mktemp("newcomer") / "cache"
    seed_c_runtime(d)
    return d


def _run(tmp_path, cache, scene):
    """``bgc simulate SCENE --out r.npz`` with nothing else: (the saved arrays, stderr)."""
    out = tmp_path / "r.npz"
    res = bgc_in_process("simulate", FIRST / scene, "--out", out,
                         env={"BGC_CACHE_DIR": str(cache), "PATH": os.environ.get("PATH", "")},
                         cwd=ROOT)
    assert res.returncode == 0, res.stderr
    return np.load(out), res.stderr


def test_rc_step_at_default_settings(tmp_path, cache):
    """The step response within 1e-5 V of 1 V. The capacitor's charge is at most 1e-6 C, so
    the default atol 1e-9 alone held it to 8e-5 V; the run tightens atol and says so."""
    r, err = _run(tmp_path, cache, "rc_step_scene.yaml")
    t, tau = r["t"], 1e-3
    assert np.max(np.abs(r["v_out"] - (1 - np.exp(-t / tau)))) < 1e-5
    assert "rerunning" in err and "'c1.c.q'" in err


def test_rc_sine_amplitude_and_phase(tmp_path, cache):
    """At the corner frequency: the whole response (transient included) against the closed
    form, and the steady state's amplitude and phase (a least-squares fit over the last
    periods) against |H| = 1/sqrt(2), arg H = -pi/4."""
    r, _ = _run(tmp_path, cache, "rc_sine_scene.yaml")
    t, v, w, tau = r["t"], r["v_out"], 1000.0, 1e-3
    amp, phi = 1 / np.sqrt(1 + (w * tau) ** 2), -np.arctan(w * tau)
    exact = amp * np.sin(w * t + phi) - amp * np.sin(phi) * np.exp(-t / tau)
    assert np.max(np.abs(v - exact)) < 1e-5
    late = t > 0.03  # 30 tau: the transient is below 1e-13
    a, b = np.linalg.lstsq(np.c_[np.sin(w * t[late]), np.cos(w * t[late])], v[late],
                           rcond=None)[0]
    assert abs(np.hypot(a, b) - amp) < 1e-5 * amp
    assert abs(np.arctan2(b, a) - phi) < 1e-5


def test_mass_spring_damper_released_from_rest(tmp_path, cache):
    """The damped oscillation: the trajectory within 1e-5 x0, hence its damped frequency and
    decay rate; the zero crossings' spacing is half the damped period."""
    r, _ = _run(tmp_path, cache, "msd_free_scene.yaml")
    t, x = r["t"], r["x"]
    m, k, c, x0 = 1.0, 100.0, 2.0, 0.1
    s = c / (2 * m)
    wd = np.sqrt(k / m - s * s)
    exact = x0 * np.exp(-s * t) * (np.cos(wd * t) + s / wd * np.sin(wd * t))
    assert np.max(np.abs(x - exact)) < 1e-5 * x0
    i = np.nonzero(np.sign(x[:-1]) != np.sign(x[1:]))[0]
    tc = t[i] - x[i] * (t[i + 1] - t[i]) / (x[i + 1] - x[i])
    assert abs(np.mean(np.diff(tc)) - np.pi / wd) < 1e-4 * np.pi / wd


def test_block_slides_to_rest_under_dry_friction(tmp_path, cache):
    """It sticks once, at t* = m v0/Fk, and rests at x* = m v0^2/(2 Fk); the position is the
    parabola before and x* after."""
    r, _ = _run(tmp_path, cache, "slide_scene.yaml")
    m, v0, fk = 2.0, 3.0, 5.0
    t_stop, x_stop = m * v0 / fk, m * v0 ** 2 / (2 * fk)
    assert list(r["event__name"]) == ["floor.stick"]
    assert abs(r["event__t"][0] - t_stop) < 1e-6 * t_stop
    t = r["t"]
    exact = np.where(t < t_stop, v0 * t - fk / (2 * m) * t * t, x_stop)
    assert np.max(np.abs(r["pos"] - exact)) < 1e-6 * x_stop
    assert abs(r["pos"][-1] - x_stop) < 1e-6 * x_stop and abs(r["vel"][-1]) < 1e-9


def test_dc_motor_speed_and_time_constant(tmp_path, cache):
    """The speed against the second-order step response (within 1e-5 of the steady speed)
    and the slow pole's time constant read off the run's approach to the steady speed."""
    r, _ = _run(tmp_path, cache, "dc_motor_load_scene.yaml")
    ra, la, k, j, b, u = 2.0, 0.005, 0.1, 1.0e-4 + 0.01, 1.0e-5 + 0.001, 12.0
    w_ss = k * u / (ra * b + k * k)
    tr, det = ra / la + b / j, (ra * b + k * k) / (la * j)
    s1, s2 = (-tr + np.sqrt(tr * tr - 4 * det)) / 2, (-tr - np.sqrt(tr * tr - 4 * det)) / 2
    t, w = r["t"], r["speed"]
    exact = w_ss * (1 + (s2 * np.exp(s1 * t) - s1 * np.exp(s2 * t)) / (s1 - s2))
    assert np.max(np.abs(w - exact)) < 1e-5 * w_ss
    late = (t > 1.0) & (t < 6.0)  # the fast (electrical) pole has decayed by e^-400
    slope = np.polyfit(t[late], np.log(w_ss - w[late]), 1)[0]
    assert abs(-1 / slope - (-1 / s1)) < 1e-4 * (-1 / s1)
    # the torque balance k i = J w' + b w along the closed form
    dw = w_ss * s1 * s2 * (np.exp(s1 * t) - np.exp(s2 * t)) / (s1 - s2)
    assert np.max(np.abs(r["current"] - (j * dw + b * exact) / k)) < 1e-5 * u / ra


def test_two_tanks_level_out(tmp_path, cache):
    """The level difference decays with tau = Rh A1 A2/(rho g (A1 + A2)); the volume stays."""
    r, _ = _run(tmp_path, cache, "tanks_scene.yaml")
    rho, g, a1, a2, rh, h0 = 1000.0, 9.81, 1.0, 0.5, 1.0e6, 2.0
    tau = rh * a1 * a2 / (rho * g * (a1 + a2))
    t = r["t"]
    assert np.max(np.abs(r["h1"] - r["h2"] - h0 * np.exp(-t / tau))) < 1e-5 * h0
    assert np.max(np.abs(a1 * r["h1"] + a2 * r["h2"] - a1 * h0)) < 1e-6 * a1 * h0


def test_pendulum_period_at_small_amplitude(tmp_path, cache):
    """The rod's period from its zero crossings against 2 pi sqrt(2 l/(3 g)) (1 + th0^2/16);
    the amplitude's correction is 6e-6, so 1e-7 tells it apart. Its output reads pi/2, which
    the C backend prints as a number (a strict C99 build has no M_PI_2)."""
    r, err = _run(tmp_path, cache, "pendulum_rod_scene.yaml")
    l, g, th0 = 1.0, 9.81, 0.01
    period = 2 * np.pi * np.sqrt(2 * l / (3 * g)) * (1 + th0 ** 2 / 16)
    t, th = r["t"], r["swing"]
    i = np.nonzero((th[:-1] > 0) & (th[1:] <= 0))[0]
    tc = t[i] - th[i] * (t[i + 1] - t[i]) / (th[i + 1] - th[i])
    assert len(tc) >= 5
    assert abs(np.mean(np.diff(tc)) / period - 1) < 1e-7
    assert "fell back" not in err and "failed building" not in err


def test_bouncing_ball_bounce_times(tmp_path, cache):
    """Six impacts at the closed-form times (relative 1e-9)."""
    r, _ = _run(tmp_path, cache, "ball_scene.yaml")
    g, h0, e = 9.81, 1.0, 0.8
    t1, v1 = np.sqrt(2 * h0 / g), np.sqrt(2 * g * h0)
    times = t1 + np.r_[0.0, np.cumsum([2 * e ** k * v1 / g for k in range(1, 6)])]
    assert list(r["event__name"]) == ["ball.impact"] * 6
    assert np.allclose(r["event__t"], times, rtol=1e-9, atol=0)


def test_zeno_stop_says_what_a_scene_can_do(tmp_path, cache):
    """The ball run past its Zeno time t1 + 2 e v1/(g (1 - e)): one located message that
    names the time to end the run before, and no option the command line lacks."""
    g, h0, e = 9.81, 1.0, 0.8
    t_zeno = np.sqrt(2 * h0 / g) * (1 + 2 * e / (1 - e))
    res = bgc_in_process("simulate", FIRST / "ball.yaml",
                         env={"BGC_CACHE_DIR": str(cache), "PATH": os.environ.get("PATH", "")},
                         cwd=ROOT)
    assert res.returncode == 1
    msg = res.stderr.strip().splitlines()[-1]
    assert "Zeno" in msg and "raise max_events" not in msg
    said = float(msg.split("end the run before t = ")[1].split()[0])
    assert abs(said - t_zeno) < 1e-4 * t_zeno


def test_a_library_parts_elements_are_named(tmp_path, cache):
    """`bgc library capacitor` lists its elements (the charge's C element is `c`); an output
    that reads e() of the instance's parameter instead is one located line naming them."""
    shown = bgc_in_process("library", "capacitor")
    assert shown.returncode == 0 and "Elements:" in shown.stdout
    assert "c (C)" in shown.stdout.split("Elements:")[1].split("Laws:")[0]
    text = (FIRST / "rc_lowpass.yaml").read_text().replace("e(c1.c)", "e(c1.C)")
    (tmp_path / "rc.yaml").write_text(text)
    bad = bgc_in_process("check", tmp_path / "rc.yaml",
                         env={"BGC_CACHE_DIR": str(cache)})
    line = text.splitlines().index(next(s for s in text.splitlines() if "e(c1.C)" in s)) + 1
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1, bad.stderr
    assert f"rc.yaml:{line}:" in bad.stderr and "the elements of 'c1': S, c" in bad.stderr
    (tmp_path / "rc.yaml").write_text(text.replace("e(c1.C)", "e(c1)"))
    bad = bgc_in_process("check", tmp_path / "rc.yaml", env={"BGC_CACHE_DIR": str(cache)})
    assert bad.returncode == 2 and "the elements of 'c1': S, c" in bad.stderr, bad.stderr


def test_default_atol_tightening_rules():
    """The rule of docs/model-format.md ("the default atol follows the states' sizes") on a
    stand-in module: only a state above 1e-4 atol whose size times rtol is over 10 times below
    atol counts (not a mode, not round-off); the new atol is rtol times the smallest such
    size, rounded down to a power of ten; a rerun that fails leaves the first run standing."""
    from bgc.run.steps import rerun_tightened, tightened_atol

    class Stand:
        STATE_NAMES = ("cap.q", "mass.p", "noise", "on")
        MODE_NAMES = ("on",)
        SimulationError = RuntimeError

        @staticmethod
        def simulate(span, method=None, **run):
            raise Stand.SimulationError("max_steps")

    x = np.array([[0.0, -5e-7], [0.0, 2.0], [1e-14, 0.0], [0.0, 1.0]])
    new, note = tightened_atol(Stand, x, 1e-6, 1e-9)
    assert new == pytest.approx(1e-13, rel=1e-12) and "'cap.q'" in note
    assert "'noise'" not in note and "'on'" not in note and "'mass.p'" not in note
    # at atol 1e-12, 5e-13 (rtol times cap.q) is not 10 times below it; 1e-14 is no longer
    # round-off next to that atol
    assert "'cap.q'" not in tightened_atol(Stand, x, 1e-6, 1e-12)[1]
    said, run, first = [], {"rtol": 1e-6, "atol": 1e-9}, (None, x, None)
    res, why = rerun_tightened(Stand, (0.0, 1.0), "Radau", run, first, said.append)
    assert res is first and why == "" and run["atol"] == 1e-9
    assert said[-1].startswith("warning: the run at atol 1e-13 failed")
