"""The library's switching parts (hybrid components: modes and events inside a component, each
instance its own) against closed forms derived here by hand, on both backends (numpy, C) and
as FMUs under FMPy: RC charging through a switch closed and opened by a time schedule or by a
signal crossing a threshold (exponentials joined where the switch moves), a half-wave
rectifier with an ideal diode and a resistive load (the source's voltage divided while
conducting, the off conductance's share while blocking), a check valve (a chamber following a
sine source to its peak and holding it; one leaking towards a lower supply through the closed
valve, exponentially), a ball and an inertia bouncing on a
hard stop (free flights joined at impacts, apex heights e_r^(2 n) h0), and stick-slip friction
(a mass on a belt held by a spring; a disk driven through a torsion spring: harmonic slips
and linear sticks of closed-form lengths)."""
from __future__ import annotations

import math

import numpy as np
import pytest

import bgc

HEAD = "bgc: 1\nname: {name}\nunits: strict\nimports: [{imports}]\n"


from backend_targets import TARGETS, has_cc, private_cache  # noqa: F401 (fixture)


def _write(tmp_path_factory, name, imports, body):
    d = tmp_path_factory.mktemp(name)
    text = HEAD.format(name=name, imports=", ".join(f'{{from: "bgc:{i}"}}' for i in imports))
    path = d / f"{name}.yaml"
    path.write_text(text + body)
    return path


def _events(r, prefix):
    """(time, name) of the events of one instance, in order."""
    return [(float(ev[0]), ev[1]) for ev in r.events if ev[1].startswith(prefix + ".")]


def _times(r, prefix):
    return np.array([x for x, _ in _events(r, prefix)])


# ---------------------------------------------------------------------------------------------
# Electrical: switches and the ideal diode

ELECTRICAL = """
parameters:
  V0: {value: 10.0, unit: V, description: the rectifiers' source amplitude}
  f0: {value: 50.0, unit: Hz, description: their frequency}
elements:
  vs1: {type: voltage_source, V: 5.0}
  s1: {type: switch, t_close: 0.1, t_open: 0.3}
  r1: {type: resistor, R: 1000.0}
  c1: {type: capacitor, C: 1.0e-4}
  vs2: {type: voltage_source, V: "V0 * sin(2 * pi * f0 * t)"}
  d2: {type: ideal_diode}
  r2: {type: resistor, R: 100.0}
  vs3: {type: voltage_source, V: 5.0}
  s3: {type: controlled_switch, signal: "sin(2 * pi * 5 * t)", threshold: 0.5}
  r3: {type: resistor, R: 1000.0}
  c3: {type: capacitor, C: 1.0e-4}
  vs4: {type: voltage_source, V: "V0 * sin(2 * pi * f0 * t)"}
  d4: {type: switched_diode, Ron: 1.0, Goff: 1.0e-3}
  r4: {type: resistor, R: 100.0}
bonds: [[vs1.p, s1.p], [s1.n, r1.p], [r1.n, c1.p], [vs2.p, d2.p], [d2.n, r2.p],
        [vs3.p, s3.p], [s3.n, r3.p], [r3.n, c3.p], [vs4.p, d4.p], [d4.n, r4.p]]
outputs:
  v1: {expr: "e(c1.c)", unit: V}
  v2: {expr: "e(r2.r)", unit: V}
  i2: {expr: "f(d2.S)", unit: A}
  v3: {expr: "e(c3.c)", unit: V}
  v4: {expr: "e(r4.r)", unit: V}
"""
TAU = 1000.0 * 1.0e-4  # the two RC circuits' time constant
T_END = 0.4


def rc_timed(t, t_close=0.1, t_open=0.3, V=5.0):
    """Charging from 0 while closed, held (no current) while open."""
    on = np.clip(t, t_close, t_open) - t_close
    return V * (1 - np.exp(-on / TAU))


def controlled_intervals(t_end, f=5.0, level=0.5):
    """sin(2 pi f t) > level on (asin(level) + 2 pi k, pi - asin(level) + 2 pi k) / (2 pi f)."""
    a = math.asin(level)
    out, k = [], 0
    while (a + 2 * math.pi * k) / (2 * math.pi * f) < t_end:
        out.append(((a + 2 * math.pi * k) / (2 * math.pi * f),
                    (math.pi - a + 2 * math.pi * k) / (2 * math.pi * f)))
        k += 1
    return out


def rc_controlled(t, V=5.0):
    """Charging towards V on each closed interval from where the last one left it."""
    v, start = np.zeros_like(t), 0.0
    for t_c, t_o in controlled_intervals(t.max()):
        inside = (t > t_c) & (t <= t_o)
        v = np.where(inside, V + (start - V) * np.exp(-(t - t_c) / TAU), v)
        end = V + (start - V) * math.exp(-(t_o - t_c) / TAU)
        v = np.where(t > t_o, end, v)
        start = end
    return v


def rectified(t, Ron=0.0, Goff=0.0, R=100.0, V0=10.0, f0=50.0):
    """Conducting (vs > 0), the load's share of the source through Ron in parallel with
    1 / Goff; blocking, the share the off conductance lets through: i = Goff (vs - R i)."""
    vs = V0 * np.sin(2 * np.pi * f0 * t)
    r_on = Ron / (1 + Goff * Ron)
    return np.where(vs > 0, vs * R / (R + r_on), vs * R * Goff / (1 + Goff * R))


@pytest.fixture(scope="module", params=TARGETS)
def electrical(request, tmp_path_factory):
    path = _write(tmp_path_factory, "switching", ["electrical"], ELECTRICAL)
    return bgc.compile(str(path), target=request.param)


@pytest.mark.parametrize("method", ["Radau", "Rodas4"])
def test_switches_and_ideal_diodes_match_their_closed_forms(electrical, method):
    assert {"s1.on", "d2.on", "s3.on", "d4.on"} <= set(electrical.STATE_NAMES)
    t = np.linspace(0.0, T_END, 801)
    # max_step: a guard's sign is looked at at each step's end, and after t = 0.3 every state
    # is at rest: unbounded, a step could span a diode's whole blocking half period (10 ms)
    r = electrical.simulate((0.0, T_END), t_eval=t, rtol=1e-10, atol=1e-12, method=method,
                            max_step=2e-3)
    # the timed switch: its events at their times (breakpoints: to an ulp or two)
    (tc, nc), (to, no) = _events(r, "s1")
    assert (nc, no) == ("s1.closing", "s1.opening")
    assert abs(tc - 0.1) <= 4 * np.spacing(0.1) and abs(to - 0.3) <= 4 * np.spacing(0.3)
    assert np.max(np.abs(r.y["v1"] - rc_timed(r.t))) < 1e-7
    # the controlled switch: closes and opens where the signal crosses the threshold
    mine = _events(r, "s3")
    expected = [x for iv in controlled_intervals(T_END) for x in iv if x < T_END]
    assert [n for _, n in mine] == ["s3.closing", "s3.opening"] * (len(expected) // 2)
    assert np.max(np.abs(np.array([x for x, _ in mine]) - expected)) < 1e-9
    assert np.max(np.abs(r.y["v3"] - rc_controlled(r.t))) < 1e-7
    # the ideal diodes: the half-wave rectified source, each instance with its own events
    assert np.max(np.abs(r.y["v2"] - rectified(r.t))) < 1e-7
    assert np.max(np.abs(r.y["v4"] - rectified(r.t, Ron=1.0, Goff=1.0e-3))) < 1e-7
    assert np.all(r.y["i2"] >= -1e-9)  # an ideal diode never conducts backwards
    for d in ("d2", "d4"):
        off = [x for x, n in _events(r, d) if n == f"{d}.turn_off"]
        on = [x for x, n in _events(r, d) if n == f"{d}.turn_on"]
        # it stops conducting where the source falls through zero, starts where it rises
        assert np.max(np.abs(np.array(off) - (0.01 + 0.02 * np.arange(20)))) < 1e-9
        assert np.max(np.abs(np.array(on[1:]) - 0.02 * np.arange(1, 20))) < 1e-9
        assert on[0] < 1e-9  # blocking at t = 0 with no voltage: it turns on at once


# ---------------------------------------------------------------------------------------------
# Hydraulics: the check valve

HYDRAULIC = """
parameters:
  P0: {value: 1.0e+6, unit: Pa, description: the third source's amplitude}
elements:
  ps2: {type: pressure_source, P: 1.0e+6}
  cv2: {type: check_valve, G_leak: 1.0e-12}
  ch2: {type: chamber, V: 1.0e-3, beta: 1.0e+9, p0: 2.0e+6}
  ps3: {type: pressure_source, P: "P0 * sin(2 * pi * t)"}
  cv3: {type: check_valve, open0: 1}
  ch3: {type: chamber, V: 1.0e-3, beta: 1.0e+9}
bonds: [[ps2.p, cv2.a], [cv2.b, ch2.p], [ps3.p, cv3.a], [cv3.b, ch3.p]]
outputs:
  p2: {expr: "e(ch2.C)", unit: Pa}
  p3: {expr: "e(ch3.C)", unit: Pa}
"""


@pytest.mark.parametrize("target", TARGETS)
def test_check_valve_holds_and_leaks_as_the_closed_form(target, tmp_path_factory):
    path = _write(tmp_path_factory, "valves", ["hydraulic"], HYDRAULIC)
    model = bgc.compile(str(path), target=target)
    t = np.linspace(0.0, 1.0, 201)
    r = model.simulate((0.0, 1.0), t_eval=t, rtol=1e-10, atol=1e-12, max_step=1e-2)
    C = 1.0e-3 / 1.0e9  # the chambers' capacitance V / beta
    # closed against a higher pressure, only the leakage: p = P + (p0 - P) exp(-G t / C)
    assert np.max(np.abs(r.y["p2"] - (1.0e6 + 1.0e6 * np.exp(-1.0e-12 * r.t / C)))) < 1e-2
    # an ideal valve into a chamber: it follows the source up to its peak (t = 1/4), where
    # the flow C dP/dt falls through zero, and holds P0 from then on
    assert [n for _, n in _events(r, "cv3")] == ["cv3.closing"]
    assert abs(_times(r, "cv3")[0] - 0.25) < 1e-8
    exact = np.where(r.t < 0.25, 1.0e6 * np.sin(2 * np.pi * r.t), 1.0e6)
    assert np.max(np.abs(r.y["p3"] - exact)) < 1e-2
    assert not _events(r, "cv2")


# ---------------------------------------------------------------------------------------------
# Mechanics: hard stops and stick-slip friction

MECHANICS = """
elements:
  ball: {type: mass_stop, m: 0.1, x0: 1.0, e_r: 0.8}
  grav: {type: force, F: -0.981}
  ball2: {type: mass_stop, m: 0.2, x0: 0.5, e_r: 0.9, x_min: 0.1}
  grav2: {type: force, F: -1.962}
  belt: {type: velocity_source, v: 0.1}
  fr: {type: stick_slip, Fs: 2.0, Fk: 1.0}
  blk: {type: mass, m: 1.0, v0: 0.1}
  sp: {type: spring, k: 100.0}
  rot: {type: inertia_stop, J: 0.5, phi0: 1.0}
  trq: {type: torque, T: -2.0}
  base: {type: speed_source, omega: 0.5}
  tsp: {type: torsion_spring, k: 4.0}
  disk: {type: inertia, J: 0.25}
  rfr: {type: rotational_stick_slip, Ts: 0.6, Tk: 0.2}
bonds: [[grav.p, ball.p], [grav2.p, ball2.p], [belt.p, fr.a], [fr.b, blk.p], [blk.p, sp.a],
        [trq.w, rot.w], [base.w, tsp.a], [tsp.b, disk.w], [disk.w, rfr.a]]
outputs:
  h: {expr: "ball.pos", unit: m}
  h2: {expr: "ball2.pos", unit: m}
  x: {expr: "q(sp.C)", unit: m}
  v: {expr: "f(blk.I)", unit: m/s}
  F: {expr: "e(fr.J)", unit: N}
  phi: {expr: "rot.phi", unit: rad}
  tw: {expr: "q(tsp.C)", unit: rad}
  wd: {expr: "f(disk.I)", unit: rad/s}
"""
M_END = 3.0


def bounce(t, h0, e, g):
    """Height above the stop, the impact times and the apexes (time, height) of a body
    dropped from rest at h0 under a constant acceleration g: free fall to sqrt(2 h0 / g),
    then flights of 2 e^n v1 / g (v1 = sqrt(2 g h0)) reaching e^(2 n) h0."""
    t = np.asarray(t, dtype=float)
    v = math.sqrt(2 * g * h0)
    t_n = math.sqrt(2 * h0 / g)
    out = np.where(t < t_n, h0 - 0.5 * g * t**2, 0.0)
    impacts, apexes, n = [], [], 0
    while t_n <= t.max():
        impacts.append(t_n)
        n += 1
        v *= e
        apexes.append((t_n + v / g, e ** (2 * n) * h0))
        tau = t - t_n
        out = np.where((tau >= 0) & (tau < 2 * v / g), v * tau - 0.5 * g * tau**2, out)
        t_n += 2 * v / g
    return out, np.array(impacts), apexes


def stick_slip(t, m, k, vb, Fs, Fk):
    """The spring's extension y of a body held by friction against a surface moving at vb
    relative to it, started stuck with y = 0: y grows at vb until k y = Fs (breakaway at
    Fs / (k vb)); slipping, m y'' = -(k y - Fk), y = Fk/k + A cos(w tau) + vb/w sin(w tau)
    (w = sqrt(k/m), A = (Fs - Fk)/k) until y' = vb again, after 2 (pi - atan2(A w, vb)) / w,
    at y = (2 Fk - Fs)/k; stuck again for 2 (Fs - Fk) / (k vb); and so on."""
    w, A = math.sqrt(k / m), (Fs - Fk) / k
    t_slip = 2 * (math.pi - math.atan2(A * w, vb)) / w
    t_stick = 2 * (Fs - Fk) / (k * vb)
    y, dy = vb * t, np.full_like(t, vb)
    bounds, t0 = [], Fs / (k * vb)
    while t0 <= t.max():
        bounds += [t0, t0 + t_slip]
        tau = t - t0
        slip = (tau >= 0) & (tau < t_slip)
        y = np.where(slip, Fk / k + A * np.cos(w * tau) + vb / w * np.sin(w * tau), y)
        dy = np.where(slip, -A * w * np.sin(w * tau) + vb * np.cos(w * tau), dy)
        stick = (tau >= t_slip) & (tau < t_slip + t_stick)
        y = np.where(stick, (2 * Fk - Fs) / k + vb * (tau - t_slip), y)
        dy = np.where(stick, vb, dy)
        t0 += t_slip + t_stick
    return y, dy, np.array([b for b in bounds if b <= t.max()])


@pytest.fixture(scope="module", params=TARGETS)
def mechanics(request, tmp_path_factory):
    path = _write(tmp_path_factory, "stops", ["mechanics.translational",
                                              "mechanics.rotational"], MECHANICS)
    return bgc.compile(str(path), target=request.param)


_MECHANICS_RUNS: dict = {}


def _mechanics_run(mechanics, method):
    """The mechanics model's run over M_END at rtol 1e-10, output on a 601-point grid and at
    the ball's apexes: made once per model and method for the hard-stop test and the
    stick-slip test (its parts are independent, each test reads its own outputs and events;
    the stick-slip closed forms are evaluated at the run's own output times)."""
    key = (mechanics, method)  # (the model object itself: kept alive while it is a key)
    if key not in _MECHANICS_RUNS:
        _, _, apexes = bounce(np.array([M_END]), 1.0, 0.8, 9.81)
        t = np.union1d(np.linspace(0.0, M_END, 601), [a for a, _ in apexes])
        _MECHANICS_RUNS[key] = mechanics.simulate((0.0, M_END), t_eval=t, rtol=1e-10,
                                                  atol=1e-12, method=method)
    return _MECHANICS_RUNS[key]


@pytest.mark.parametrize("method", ["Radau", "Rodas4"])
def test_hard_stops_bounce_as_the_closed_form(mechanics, method):
    r = _mechanics_run(mechanics, method)
    for name, out, h0, e, g in (("ball", "h", 1.0, 0.8, 9.81), ("ball2", "h2", 0.4, 0.9, 9.81),
                                ("rot", "phi", 1.0, 0.8, 4.0)):
        exact, impacts, apexes = bounce(r.t, h0, e, g)
        base = 0.1 if name == "ball2" else 0.0  # ball2's stop is at x_min = 0.1
        assert np.max(np.abs(r.y[out] - base - exact)) < 1e-8, name
        assert [n for _, n in _events(r, name)] == [f"{name}.impact"] * len(impacts)
        assert np.max(np.abs(_times(r, name) - impacts)) < 1e-9, name
        if name == "ball":  # the apexes: e^(2 n) h0
            i = np.searchsorted(r.t, [a for a, _ in apexes])
            assert np.allclose(r.y["h"][i], [h for _, h in apexes], rtol=0, atol=1e-9)


@pytest.mark.parametrize("method", ["Radau", "Rodas4"])
def test_stick_slip_phases_match_the_closed_form(mechanics, method):
    r = _mechanics_run(mechanics, method)  # (the hard-stop test's run: one run, both tests)
    assert np.all(np.isin(np.linspace(0.0, M_END, 601), r.t))  # the 601-point grid at least
    # a mass on a belt (vb = 0.1) held by a spring to the ground: its extension is the
    # mass's position; stuck, it moves with the belt and the friction holds |k x| <= Fs
    x, dx, bounds = stick_slip(r.t, m=1.0, k=100.0, vb=0.1, Fs=2.0, Fk=1.0)
    names = [n for _, n in _events(r, "fr")]
    assert names == ["fr.breakaway", "fr.stick"] * (len(bounds) // 2) + \
        ["fr.breakaway"] * (len(bounds) % 2)
    assert np.max(np.abs(_times(r, "fr") - bounds)) < 1e-7
    assert np.max(np.abs(r.y["x"] - x)) < 1e-7
    assert np.max(np.abs(r.y["v"] - dx)) < 1e-6
    assert np.all(np.abs(r.y["F"]) <= 2.0 + 1e-9)
    # a disk held by friction to the ground, driven through a torsion spring whose far end
    # turns at 0.5 rad/s: the spring's twist plays the extension, the disk's speed is
    # the drive's minus the twist's rate
    tw, dtw, bounds = stick_slip(r.t, m=0.25, k=4.0, vb=0.5, Fs=0.6, Fk=0.2)
    assert bounds[0] == pytest.approx(0.6 / (4.0 * 0.5))  # Ts / (k omega_b)
    assert np.max(np.abs(_times(r, "rfr") - bounds)) < 1e-7
    assert np.max(np.abs(r.y["tw"] - tw)) < 1e-7
    assert np.max(np.abs(r.y["wd"] - (0.5 - dtw))) < 1e-6
    durations = np.diff(_times(r, "rfr"))  # slips and sticks, their closed-form lengths
    w, A = math.sqrt(4.0 / 0.25), 0.4 / 4.0
    assert np.allclose(durations[0::2], 2 * (math.pi - math.atan2(A * w, 0.5)) / w, atol=1e-7)
    assert np.allclose(durations[1::2], 2 * 0.4 / (4.0 * 0.5), atol=1e-7)


# ---------------------------------------------------------------------------------------------
# The FMUs: FMPy's solver finds the events on the components' indicators (Model Exchange),
# the C runtime inside each step does (Co-Simulation)


@pytest.mark.slow
def test_switching_parts_as_fmus_under_fmpy(tmp_path_factory):
    fmpy = pytest.importorskip("fmpy")
    from bgc.run.fmu import export_fmu

    if not has_cc():
        pytest.skip("no C compiler")
    d = tmp_path_factory.mktemp("fmus")
    el = export_fmu(_write(tmp_path_factory, "switching", ["electrical"], ELECTRICAL),
                    d / "switching.fmu")
    outs = ["v1", "v2", "v3", "v4"]
    r = fmpy.simulate_fmu(str(el), fmi_type="ModelExchange", solver="CVode", stop_time=T_END,
                          output_interval=1e-3, relative_tolerance=1e-9, output=outs)
    t = r["time"]
    assert np.max(np.abs(r["v1"] - rc_timed(t))) < 1e-5
    assert np.max(np.abs(r["v3"] - rc_controlled(t))) < 1e-5
    assert np.max(np.abs(r["v2"] - rectified(t))) < 1e-5
    assert np.max(np.abs(r["v4"] - rectified(t, Ron=1.0, Goff=1.0e-3))) < 1e-5
    r = fmpy.simulate_fmu(str(el), fmi_type="CoSimulation", stop_time=T_END,
                          output_interval=1e-3, output=outs)
    assert np.max(np.abs(r["v1"] - rc_timed(r["time"]))) < 1e-6
    assert np.max(np.abs(r["v2"] - rectified(r["time"]))) < 1e-6

    hy = export_fmu(_write(tmp_path_factory, "valves", ["hydraulic"], HYDRAULIC),
                    d / "valves.fmu")
    for kind in ("ModelExchange", "CoSimulation"):
        r = fmpy.simulate_fmu(str(hy), fmi_type=kind, solver="CVode", stop_time=1.0,
                              output_interval=1e-3, relative_tolerance=1e-10,
                              output=["p2", "p3"])
        t = r["time"]
        C = 1.0e-3 / 1.0e9
        assert np.max(np.abs(r["p2"] - (1.0e6 + 1.0e6 * np.exp(-1.0e-12 * t / C)))) < 1.0
        exact = np.where(t < 0.25, 1.0e6 * np.sin(2 * np.pi * t), 1.0e6)
        assert np.max(np.abs(r["p3"] - exact)) < 1.0, kind

    me = export_fmu(_write(tmp_path_factory, "stops", ["mechanics.translational",
                                                      "mechanics.rotational"], MECHANICS),
                    d / "stops.fmu")
    for kind in ("ModelExchange", "CoSimulation"):
        r = fmpy.simulate_fmu(str(me), fmi_type=kind, solver="CVode", stop_time=M_END,
                              output_interval=1e-3, relative_tolerance=1e-10,
                              output=["h", "x", "tw"])
        t = r["time"]
        assert np.max(np.abs(r["h"] - bounce(t, 1.0, 0.8, 9.81)[0])) < 1e-5, kind
        assert np.max(np.abs(r["x"] - stick_slip(t, 1.0, 100.0, 0.1, 2.0, 1.0)[0])) < 1e-5
        assert np.max(np.abs(r["tw"] - stick_slip(t, 0.25, 4.0, 0.5, 0.6, 0.2)[0])) < 1e-5
