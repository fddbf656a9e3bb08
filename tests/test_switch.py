"""Hybrid bond graphs: the ideal switch (Sw) whose mode changes causality (bgc.core.modes),
checked against answers obtained outside bgc: the ideal-diode rectifier against an independent
model (closed forms while conducting, scipy's solve_ivp with events while blocking), the clutch
against its closed form (momentum conserved at engagement, one body while engaged, released
where the transmitted torque reaches the static limit), the Jacobian against finite
differences in every mode, and the located errors of a mode that cannot be assigned."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import bgc
from bgc.base.errors import ModelError
from bgc.run.driver import compile_file

ROOT = Path(__file__).resolve().parents[1]
RECTIFIER = ROOT / "models" / "rectifier_switch.yaml"
CLUTCH = ROOT / "models" / "clutch.yaml"


from backend_targets import TARGETS, has_cc, private_cache  # noqa: F401 (fixture)


# --- the ideal-diode rectifier ------------------------------------------------------------------

def rectifier_reference(times, V0=10.0, f0=50.0, R=1000.0, C=1e-5):
    """Conducting, v_C = Vs(t) and the diode current C Vs'(t) + Vs(t)/R, whose zero (brentq)
    ends it; blocking, dv_C/dt = -v_C/(R C) with solve_ivp's event Vs - v_C rising. Returns
    v_C at the times and the switching times."""
    from scipy.integrate import solve_ivp
    from scipy.optimize import brentq

    w = 2 * np.pi * f0
    vs = lambda t: V0 * np.sin(w * t)  # noqa: E731
    cur = lambda t: C * V0 * w * np.cos(w * t) + vs(t) / R  # noqa: E731
    out, switches, t, t_end = np.full_like(times, np.nan), [], 0.0, times[-1]
    while t < t_end:
        # conducting from t: the current's first fall through zero after t
        k = np.floor(w * t / np.pi)
        t_off = brentq(cur, max(t, k * np.pi / w + 1e-12), (k + 1) * np.pi / w - 1e-12,
                       xtol=1e-15)
        t_off = min(t_off, t_end)
        sel = (times >= t) & (times <= t_off)
        out[sel] = vs(times[sel])
        if t_off >= t_end:
            break
        switches.append(t_off)

        def ev(t, y):
            return vs(t) - y[0]
        ev.direction, ev.terminal = 1, True
        sol = solve_ivp(lambda t, y: [-y[0] / (R * C)], (t_off, t_end), [vs(t_off)],
                        method="DOP853", rtol=1e-12, atol=1e-14, events=ev, dense_output=True)
        sel = (times >= t_off) & (times <= sol.t[-1])
        out[sel] = sol.sol(times[sel])[0]
        t = sol.t[-1]
        if sol.status == 1:
            switches.append(t)
    return out, np.array(switches)


@pytest.mark.parametrize("target", TARGETS)
@pytest.mark.parametrize("method", ["Radau", "Rodas4"])
def test_ideal_diode_rectifier_matches_an_independent_model(target, method):
    model = bgc.compile(str(RECTIFIER), target=target)
    times = np.linspace(0.0, 0.1, 1001)
    r = model.simulate((0.0, 0.1), t_eval=times, rtol=1e-10, atol=1e-12, method=method)
    v_ref, switches = rectifier_reference(times)
    assert len(switches) == 9
    assert [ev[1] for ev in r.events] == ["turn_off", "turn_on"] * 4 + ["turn_off"]
    assert np.max(np.abs(np.array([ev[0] for ev in r.events]) - switches)) < 1e-8
    assert np.max(np.abs(r.y["v_out"] - v_ref)) < 1e-5
    on = r.y["conducting"] > 0.5
    # blocking, no current; conducting, the capacitor follows the source (derivative causality)
    assert np.all(r.y["i_diode"][~on] == 0)
    vs = 10.0 * np.sin(2 * np.pi * 50.0 * times)
    assert np.max(np.abs(r.y["v_out"][on] - vs[on])) < 1e-12
    assert np.all(r.y["i_diode"][on] >= -1e-9)


def test_the_switch_mode_changes_causality():
    """Conducting, the capacitor's charge is no longer independent: its state follows the
    constraint q = C Vs(t), so its derivative is C Vs'(t); blocking, it is the load current."""
    model = bgc.compile(str(RECTIFIER))
    assert list(model.STATE_NAMES) == ["cap.q", "on"]
    t, q = 0.0123, 3e-5
    w, C, R = 2 * np.pi * 50.0, 1e-5, 1000.0
    conducting = model.rhs(t, np.array([q, 1.0]))
    assert conducting[0] == pytest.approx(C * 10.0 * w * np.cos(w * t), rel=1e-12)
    blocking = model.rhs(t, np.array([q, 0.0]))
    assert blocking[0] == pytest.approx(-q / C / R, rel=1e-12)
    assert conducting[1] == blocking[1] == 0


@pytest.mark.parametrize("path", [RECTIFIER, CLUTCH], ids=["rectifier", "clutch"])
def test_jacobian_matches_finite_differences_in_every_mode(path):
    model = bgc.compile(str(path))
    n = len(model.STATE_NAMES)
    rng = np.random.default_rng(5)
    for mode in (0.0, 1.0):
        x = rng.uniform(0.5, 2.0, n) * 1e-3 if path == RECTIFIER else rng.uniform(0.5, 2.0, n)
        x[-1] = mode
        J = np.asarray(model.jacobian(0.7e-2, x)).reshape(n, n)
        for j in range(n - 1):  # the mode column: a step, not a slope
            h = 1e-6 * max(1.0, abs(x[j]))
            xp, xm = x.copy(), x.copy()
            xp[j] += h
            xm[j] -= h
            fd = (model.rhs(0.7e-2, xp) - model.rhs(0.7e-2, xm)) / (2 * h)
            assert np.allclose(J[:, j], fd, rtol=1e-6, atol=1e-6 * np.max(np.abs(fd))), mode


# --- the clutch ---------------------------------------------------------------------------------

def clutch_exact(t, J1=1.0, J2=2.0, T=2.0, b=0.5, t_e=1.0, Ts=1.8):
    """Speeds and transmitted torque: free until t_e, a plastic engagement (momentum kept),
    one body until the torque (J2 T + J1 b w)/(J1 + J2) reaches Ts, then free again."""
    J = J1 + J2
    w1_e = T * t_e / J1  # driven from rest; the driven shaft starts at rest
    w_star = J1 * w1_e / J
    w_rel = (Ts * J - J2 * T) / (J1 * b)  # the common speed at release
    t_r = t_e - J / b * np.log((T / b - w_rel) / (T / b - w_star))
    w_lock = T / b + (w_star - T / b) * np.exp(-b * (t - t_e) / J)
    w1 = np.where(t < t_e, T * t / J1, np.where(t < t_r, w_lock, w_rel + T * (t - t_r) / J1))
    w2 = np.where(t < t_e, 0.0, np.where(t < t_r, w_lock,
                                         w_rel * np.exp(-b * (t - t_r) / J2)))
    tau = np.where((t >= t_e) & (t < t_r), (J2 * T + J1 * b * w_lock) / J, 0.0)
    return w1, w2, tau, t_r


@pytest.mark.parametrize("target", TARGETS)
@pytest.mark.parametrize("method", ["Radau", "Rodas4"])
def test_clutch_matches_the_closed_form(target, method):
    model = bgc.compile(str(CLUTCH), target=target)
    times = np.arange(900) * 0.01 + 0.005  # (an output at an event's time is its left limit)
    r = model.simulate((0.0, 9.0), t_eval=times, rtol=1e-10, atol=1e-12, method=method)
    w1, w2, tau, t_r = clutch_exact(times)
    assert [ev[1] for ev in r.events] == ["engage", "release"]
    (t_e, _, _, before, after), (t_rel, *_) = r.events
    assert t_e == 1.0 and abs(t_rel - t_r) < 1e-8
    # the engagement conserves the angular momentum and leaves one common speed
    assert after[0] + after[1] == pytest.approx(before[0] + before[1], rel=1e-14)
    assert after[0] / 1.0 == pytest.approx(after[1] / 2.0, rel=1e-14)
    assert np.max(np.abs(r.y["speed1"] - w1)) < 1e-7
    assert np.max(np.abs(r.y["speed2"] - w2)) < 1e-7
    # the engaged clutch's torque is the constraint's effort: (J2 T + J1 b w)/(J1 + J2)
    assert np.max(np.abs(r.y["clutch_torque"] - tau)) < 1e-7
    engaged = r.y["engaged"] > 0.5
    assert np.array_equal(engaged, (times >= 1.0) & (times < t_r))


# --- mistakes: one located line each --------------------------------------------------------------

TWO_BATTERIES = """bgc: 1
name: two_batteries
parameters:
  V1: {value: 12.0, unit: V}
  V2: {value: 11.0, unit: V}
  R1: {value: 10.0, unit: Ohm}
modes:
  on: 0
elements:
  bat1: {type: Se, effort: "V1"}
  bat2: {type: Se, effort: "V2"}
  sw:   {type: Sw, closed: "on"}
  loop: {type: "1"}
  n2:   {type: "0"}
  load: {type: R, resistance: "R1"}
bonds:
  - [bat1, loop]
  - [loop, sw]
  - [loop, n2]
  - [bat2, n2]
  - [n2, load]
events:
  close:
    at: "1"
    do: {on: 1}
"""


def test_a_mode_that_cannot_be_assigned_is_a_located_error(tmp_path):
    path = tmp_path / "two.yaml"
    path.write_text(TWO_BATTERIES)  # closing the switch puts two batteries in parallel
    with pytest.raises(ModelError) as exc:
        compile_file(path)
    err = exc.value
    assert err.message.startswith("switch mode (sw closed): causal conflict")
    assert "Sw 'sw' (closed)" in err.message and "Se 'bat2'" in err.message
    assert (err.coord.file, err.coord.line) == (str(path), 12)


@pytest.mark.parametrize("closed, message", [
    ('"where(t > 1, 1, 0)"', "must be an expression of modes and parameters"),
    ('"onn"', "undefined name 'onn'"),
])
def test_switch_position_mistakes_are_located(tmp_path, closed, message):
    text = TWO_BATTERIES.replace('closed: "on"', f"closed: {closed}").replace(
        "  - [bat2, n2]\n", "").replace("  bat2: {type: Se, effort: \"V2\"}\n", "")
    path = tmp_path / "sw.yaml"
    path.write_text(text)
    with pytest.raises(ModelError) as exc:
        compile_file(path)
    assert message in exc.value.message
    assert exc.value.coord.line == 11


def test_too_many_switches_is_a_located_error(tmp_path):
    elements = "".join(f"  s{i}: {{type: Sw, closed: \"on\"}}\n" for i in range(7))
    bonds = "".join(f"  - [loop, s{i}]\n" for i in range(7))
    text = TWO_BATTERIES.replace("  sw:   {type: Sw, closed: \"on\"}\n", elements).replace(
        "  - [loop, sw]\n", bonds)
    path = tmp_path / "many.yaml"
    path.write_text(text)
    with pytest.raises(ModelError) as exc:
        compile_file(path)
    assert "more than 6 switches" in exc.value.message
    assert exc.value.coord.line == text[:text.index("s6:")].count("\n") + 1


# --- events inside components: each instance its own --------------------------------------------

@pytest.mark.parametrize("target", TARGETS)
def test_component_events_belong_to_each_instance(target):
    """Two instances of an ideal-diode component (its mode and events inside it), each in a
    rectifier of its own load: each matches the independent model of its circuit."""
    model = bgc.compile(str(ROOT / "models" / "rectifier_pair.yaml"), target=target)
    assert list(model.STATE_NAMES) == ["cap_a.q", "cap_b.q", "d_a.on", "d_b.on"]
    times = np.linspace(0.0, 0.1, 1001)
    r = model.simulate((0.0, 0.1), t_eval=times, rtol=1e-10, atol=1e-12)
    for name, R in (("a", 1000.0), ("b", 500.0)):
        v_ref, switches = rectifier_reference(times, R=R)
        mine = [ev for ev in r.events if ev[1].startswith(f"d_{name}.")]
        assert [ev[1] for ev in mine] == [f"d_{name}.turn_off", f"d_{name}.turn_on"] * (
            len(switches) // 2) + [f"d_{name}.turn_off"] * (len(switches) % 2)
        assert np.max(np.abs(np.array([ev[0] for ev in mine]) - switches)) < 1e-8
        assert np.max(np.abs(r.y[f"v_{name}"] - v_ref)) < 1e-5


@pytest.mark.slow
def test_switched_rectifier_fmu_under_fmpy(tmp_path):
    """Model Exchange: FMPy's CVode finds the switching times on our event indicators; the
    mode change resets the capacitor's charge to its constraint (C Vs at turn-off), so the
    blocking mode's guard starts where it should. Co-Simulation: the C runtime inside."""
    fmpy = pytest.importorskip("fmpy")
    from bgc.run.fmu import export_fmu

    if not has_cc():
        pytest.skip("no C compiler")
    fmu = str(export_fmu(RECTIFIER, tmp_path / "rs.fmu"))
    r = fmpy.simulate_fmu(fmu, fmi_type="ModelExchange", solver="CVode", stop_time=0.1,
                          output_interval=1e-3, relative_tolerance=1e-8, output=["v_out"])
    t = r["time"]
    _, switches = rectifier_reference(np.linspace(0.0, 0.1, 11))
    assert np.allclose(t[1:][np.diff(t) == 0], switches, atol=1e-7, rtol=0)
    v_ref, _ = rectifier_reference(np.linspace(0.0, 0.1, 101))
    r = fmpy.simulate_fmu(fmu, fmi_type="CoSimulation", stop_time=0.1, output_interval=1e-3,
                          output=["v_out"])
    assert np.max(np.abs(r["v_out"] - v_ref)) < 1e-4
