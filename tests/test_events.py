"""Events (hybrid models): the format's located errors, and simulations that stop at events,
checked against answers obtained outside bgc: the bouncing ball's piecewise-analytic
trajectory, and the half-wave rectifier against an independent scipy model that switches
its equations at solve_ivp's own events."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

import bgc
from bgc.base.errors import ModelError
from bgc.run.driver import compile_file

ROOT = Path(__file__).resolve().parents[1]
BALL = ROOT / "models" / "bouncing_ball.yaml"
RECTIFIER = ROOT / "models" / "rectifier_ideal.yaml"
G = 9.81


from backend_targets import TARGETS, has_cc, private_cache  # noqa: F401 (fixture)
from conftest import bgc_in_process, seed_c_runtime


def ball_height(t, h0, e, g=G):
    """The ball's height, piecewise: free fall to sqrt(2 h0/g), then flights of 2 e^n v1/g."""
    t = np.asarray(t, dtype=float)
    v1 = np.sqrt(2 * g * h0)
    t_n, v_n = np.sqrt(2 * h0 / g), e * v1
    out = np.where(t < t_n, h0 - 0.5 * g * t ** 2, 0.0)
    while t_n <= t.max():
        tau = t - t_n
        out = np.where((tau >= 0) & (tau < 2 * v_n / g), v_n * tau - 0.5 * g * tau ** 2, out)
        t_n, v_n = t_n + 2 * v_n / g, v_n * e
    return out


def impact_times(h0, e, t_end, g=G):
    v1 = np.sqrt(2 * g * h0)
    times, t_n, v_n = [], np.sqrt(2 * h0 / g), v1
    while t_n <= t_end:
        times.append(t_n)
        v_n *= e
        t_n += 2 * v_n / g
    return np.array(times)


@pytest.fixture(scope="module", params=TARGETS)
def ball(request, tmp_path_factory):
    os.environ.setdefault("BGC_CACHE_DIR", str(tmp_path_factory.mktemp("cache")))
    return bgc.compile(str(BALL), target=request.param)


@pytest.mark.parametrize("method", ["Radau", "Rodas4"])
def test_ball_height_matches_the_piecewise_analytic_solution(ball, method):
    r = ball.simulate((0.0, 3.0), dt=1e-3, rtol=1e-10, atol=1e-12, method=method)
    assert np.max(np.abs(r.y["height"] - ball_height(r.t, 1.0, 0.8))) < 1e-8
    expected = impact_times(1.0, 0.8, 3.0)
    assert [ev[1] for ev in r.events] == ["impact"] * len(expected)
    assert np.max(np.abs([ev[0] for ev in r.events] - expected)) < 1e-9
    assert r.stats["nevents"] == len(expected)
    for t, _, index, before, after in r.events:  # the reset: p+ = -e p-, the height kept
        assert index == ()
        assert after[0] == pytest.approx(-0.8 * before[0], rel=1e-14)
        assert after[1] == before[1] and abs(before[1]) < 1e-12


def test_ball_with_dop853(ball):  # the explicit method's interpolant locates the impacts too
    r = ball.simulate((0.0, 3.0), dt=1e-3, rtol=1e-10, atol=1e-12, method="DOP853")
    assert np.max(np.abs(r.y["height"] - ball_height(r.t, 1.0, 0.8))) < 1e-8
    assert np.allclose([ev[0] for ev in r.events], impact_times(1.0, 0.8, 3.0), atol=1e-9,
                       rtol=0)


def test_ball_batched_over_restitution_and_height(ball):
    e = np.array([0.8, 0.85, 0.9])
    h0 = np.array([[1.0], [1.5], [2.0]])
    r = ball.simulate((0.0, 3.0), dt=1e-3, rtol=1e-10, atol=1e-12, p={"e_r": e, "h0": h0})
    assert r.y["height"].shape == (3, 3, len(r.t))
    for i in range(3):
        for j in range(3):
            exact = ball_height(r.t, h0[i, 0], e[j])
            assert np.max(np.abs(r.y["height"][i, j] - exact)) < 1e-8
            mine = [ev[0] for ev in r.events if ev[2] == (i, j)]
            assert np.allclose(mine, impact_times(h0[i, 0], e[j], 3.0), atol=1e-9, rtol=0)


@pytest.mark.parametrize("batch_events", ["own", "shared"])
def test_ball_batch_equals_the_single_runs(batch_events):
    """numpy: each instance of a batch has its own events; with batch_events="own" it is
    integrated on its own (exactly its single run), with "shared" the batch restarts together
    at every instance's event (the same trajectories to the solver's accuracy)."""
    model = bgc.compile(str(BALL))
    e = np.array([0.8, 0.85, 0.9])
    kw = dict(dt=1e-3, rtol=1e-8, atol=1e-10)
    r = model.simulate((0.0, 3.0), p={"e_r": e}, batch_events=batch_events, **kw)
    for i, ei in enumerate(e):
        single = model.simulate((0.0, 3.0), p={"e_r": float(ei)}, **kw)
        mine = [ev for ev in r.events if ev[2] == (i,)]
        assert len(mine) == len(single.events) == len(impact_times(1.0, ei, 3.0))
        if batch_events == "own":
            assert np.array_equal(r.x[:, i], single.x)
            assert [ev[0] for ev in mine] == [ev[0] for ev in single.events]
        else:
            assert np.max(np.abs(r.x[:, i] - single.x)) < 1e-9
            assert np.allclose([ev[0] for ev in mine], [ev[0] for ev in single.events],
                               atol=1e-9, rtol=0)
    assert [ev[0] for ev in r.events] == sorted(ev[0] for ev in r.events)


def test_zeno_is_a_located_error(ball):
    # e = 0.5: the impacts pile up at t1 (1 + e)/(1 - e) = 1.3546 s
    with pytest.raises(ball.SimulationError) as exc:
        ball.simulate((0.0, 3.0), dt=1e-3, rtol=1e-10, atol=1e-12, p={"e_r": 0.5})
    msg = str(exc.value)
    assert msg.startswith("bouncing_ball.yaml:34:3: event 'impact' at t = 1.3545")
    assert "Zeno" in msg and "\n" not in msg


def rectifier_reference(times, V0=10.0, f0=50.0, Ron=0.01, R=1000.0, C=1e-4):
    """The rectifier as two ODEs in v_C (diode conducting or blocking), switched at
    solve_ivp's terminal events: (v_C at the times, the switching times)."""
    from scipy.integrate import solve_ivp

    vs = lambda t: V0 * np.sin(2 * np.pi * f0 * t)  # noqa: E731
    t, v, on, out, switches, t_end = 0.0, 0.0, False, np.empty_like(times), [], times[-1]
    while t < t_end:
        if on:
            def f(t, y):
                return [((vs(t) - y[0]) / Ron - y[0] / R) / C]

            def ev(t, y):
                return (vs(t) - y[0]) / Ron
            ev.direction = -1
        else:
            def f(t, y):
                return [-y[0] / (R * C)]

            def ev(t, y):
                return vs(t) - y[0]
            ev.direction = 1
        ev.terminal = True
        sol = solve_ivp(f, (t, t_end), [v], method="Radau", rtol=1e-12, atol=1e-14,
                        events=ev, dense_output=True)
        sel = (times >= t) & (times <= sol.t[-1])
        out[sel] = sol.sol(times[sel])[0]
        t, v = sol.t[-1], sol.y[0, -1]
        if sol.status == 1:
            on = not on
            switches.append(t)
    return out, np.array(switches)


@pytest.mark.parametrize("target", TARGETS)
def test_rectifier_matches_an_independent_scipy_model(target):
    model = bgc.compile(str(RECTIFIER), target=target)
    times = np.linspace(0.0, 0.1, 1001)
    r = model.simulate((0.0, 0.1), t_eval=times, rtol=1e-10, atol=1e-12)
    v_ref, switches = rectifier_reference(times)
    assert len(switches) == 10
    assert np.max(np.abs(r.y["v_out"] - v_ref)) < 1e-5
    assert [ev[1] for ev in r.events] == ["turn_on", "turn_off"] * 5
    assert np.max(np.abs(np.array([ev[0] for ev in r.events]) - switches)) < 1e-6
    # blocking, no current flows; the mode is what the events made it
    assert np.all(r.y["i_diode"][r.y["conducting"] < 0.5] == 0)


def test_a_model_without_events_has_no_event_part():
    text = compile_file(ROOT / "models" / "msd.yaml").source
    assert "EVENT_NAMES" not in text and "bgc numpy events runtime" not in text
    ball_text = compile_file(BALL).source
    assert "EVENT_NAMES = ('impact', )" in ball_text


def test_c_sources_of_a_model_without_events_have_no_event_part():
    from bgc.backends.c.printer import render_c

    c = compile_file(ROOT / "models" / "msd.yaml")
    main = dict(render_c(c.lowered, source="msd.yaml", source_hash="0").files)["model.c"]
    assert "guards" not in main and ".nev" not in main
    ball = compile_file(BALL)
    main = dict(render_c(ball.lowered, source="b.yaml", source_hash="0").files)["model.c"]
    assert ".nev = 1, .guards = bgcm_guards" in main


# --- the format: every mistake is one located line ---------------------------------------------

BALL_TEXT = BALL.read_text()
IMPACT = '''  impact:
    when: "h"
    direction: falling
    do:
      "p(ball)": "-e_r*p(ball)"
'''


def _line_of(text: str, needle: str, start: int = 0) -> int:
    return text[:text.index(needle, start)].count("\n") + 1


BAD = [
    # (replacement of the impact event, the text the error points at, a piece of the message)
    ('  impact:\n    when: "h"\n    direction: down\n    do: {"p(ball)": "0"}\n', "down",
     "direction 'down' is not one of rising, falling, either"),
    ('  impact:\n    when: "hh"\n    do: {"p(ball)": "0"}\n', "hh",
     "undefined name 'hh'"),
    ('  impact:\n    when: "h +* 2"\n    do: {"p(ball)": "0"}\n', "h +* 2", "condition"),
    ('  impact:\n    when: "h"\n    do: {"p(wall)": "0"}\n', "p(wall)", "undefined name 'wall'"),
    ('  impact:\n    when: "h"\n    do: {g: "0"}\n', "g:", "cannot assign to 'g': it is not a "
                                                           "state"),
    ('  impact:\n    when: "h"\n    do: {"q(ball)": "0"}\n', "q(ball)", "q() takes a C element"),
    ('  impact:\n    when: "h"\n    do: {"p(ball)": "[1, 2]"}\n', "[1, 2]", "has shape scalar"),
    ('  impact:\n    when: "h"\n    at: "1"\n    do: {h: "0"}\n', "when", "give one of 'when'"),
    ('  impact:\n    when: "h"\n    do: {}\n', "{}", "'do' lists no action"),
    ('  impact:\n    when: "g"\n    do: {h: "0"}\n', "g", "never crosses zero"),
    ('  impact:\n    at: "h"\n    do: {h: "0"}\n', "h\"\n    do", "may only use parameters"),
    ('  impact:\n    when: "h"\n    do: {"1x": "0"}\n', "1x", "cannot assign to '1x'"),
    ('  impact:\n    when: "h"\n    speed: 2\n    do: {h: "0"}\n', "speed",
     "unknown key 'speed'"),
    ('  impact:\n    every: "h"\n    do: {h: "0"}\n', "h\"\n    do", "may only use parameters"),
    ('  impact:\n    when: "h"\n    every: "1"\n    do: {h: "0"}\n', "when",
     "or 'every' (a period)"),
    ('  impact:\n    every: "1"\n    direction: rising\n    do: {h: "0"}\n', "direction",
     "a time event ('at', 'every') has no direction"),
]


@pytest.mark.parametrize("event, at, message", BAD, ids=[m for _, _, m in BAD])
def test_event_mistakes_are_located(tmp_path, event, at, message):
    text = BALL_TEXT.replace(IMPACT, event)
    assert text != BALL_TEXT
    path = tmp_path / "ball.yaml"
    path.write_text(text)
    with pytest.raises(ModelError) as exc:
        compile_file(path)
    err = exc.value
    assert message in err.message, err.message
    events_at = _line_of(text, "events:")
    assert err.coord.file == str(path) and events_at < err.coord.line <= events_at + 6
    assert err.coord.line == _line_of(text, at, text.index("events:")), (str(err), at)


def test_mode_mistakes_are_located(tmp_path):
    text = RECTIFIER.read_text().replace("  on: 0 ", "  on: x ")
    path = tmp_path / "r.yaml"
    path.write_text(text)
    with pytest.raises(ModelError) as exc:
        compile_file(path)
    assert exc.value.coord.line == _line_of(text, "on: x") and "undefined name 'x'" in str(
        exc.value)


def test_cli_summary_counts_events_and_writes_the_log(tmp_path):
    """A full run, then the same command again, which replays the first's run record: each
    prints the summary and writes the same event log. (The full run and the replay were two
    tests before, the replay's test running the full run again first.)"""
    env = {"BGC_CACHE_DIR": str(seed_c_runtime(tmp_path / "c"))}
    scene = ROOT / "models" / "scenes" / "bouncing_ball.yaml"
    out = tmp_path / "run.npz"
    for run in ("full", "replayed"):  # the second run replays the run record
        out.unlink(missing_ok=True)
        # in this process: what `python -m bgc` runs, its replay included (conftest)
        proc = bgc_in_process("simulate", scene, "--out", out, env=env)
        assert proc.returncode == 0, proc.stderr
        assert "LU, 6 events;" in proc.stdout
        assert ("run record" in proc.stdout + proc.stderr) == (run == "replayed"), run
        with np.load(out) as data:
            expected = impact_times(1.0, 0.8, 3.0)
            assert np.allclose(data["event__t"], expected, atol=1e-9, rtol=0)
            assert list(data["event__name"]) == ["impact"] * len(expected)
            before, after = data["event__x_before"], data["event__x_after"]
            assert before.shape == (len(expected), 2)
            assert np.allclose(after[:, 0], -0.8 * before[:, 0], rtol=1e-14, atol=0)
            assert np.max(np.abs(data["height"] - ball_height(data["t"], 1.0, 0.8))) < 1e-8


# --- stick-slip: the closed-form periodic solution ---------------------------------------------

def stick_slip_exact(t, m=1.0, k=100.0, vb=0.1, Fs=2.0, Fk=1.0):
    """Position and the phase boundaries of the mass on the belt, started stuck at x = 0:
    stuck until k x = Fs, then a harmonic slip about Fk/k from (Fs/k, vb) to (2 Fk - Fs)/k
    where the velocity is vb again, then stuck, ..."""
    w, A = np.sqrt(k / m), (Fs - Fk) / k
    t_slip = 2 * (np.pi - np.arctan2(A * w, vb)) / w
    t_stick = 2 * (Fs - Fk) / (k * vb)
    x = vb * t
    bounds, t0, x_stick = [], Fs / (k * vb), 0.0
    while t0 <= t.max():
        bounds += [t0, t0 + t_slip]
        tau = t - t0
        slip = (tau >= 0) & (tau < t_slip)
        x = np.where(slip, Fk / k + A * np.cos(w * tau) + vb / w * np.sin(w * tau), x)
        x_stick = (2 * Fk - Fs) / k
        stick = (tau >= t_slip) & (tau < t_slip + t_stick)
        x = np.where(stick, x_stick + vb * (tau - t_slip), x)
        t0 += t_slip + t_stick
    return x, np.array([b for b in bounds if b <= t.max()]), t_slip, t_stick


@pytest.mark.parametrize("target", TARGETS)
@pytest.mark.parametrize("method", ["Radau", "Rodas4"])
def test_stick_slip_phases_match_the_closed_form(method, target):
    model = bgc.compile(str(ROOT / "models" / "stick_slip.yaml"), target=target)
    r = model.simulate((0.0, 3.0), dt=1e-3, rtol=1e-10, atol=1e-12, method=method)
    x, bounds, t_slip, t_stick = stick_slip_exact(r.t)
    names = [ev[1] for ev in r.events]
    assert names == ["breakaway", "stick"] * (len(bounds) // 2) + ["breakaway"] * (len(bounds) % 2)
    times = np.array([ev[0] for ev in r.events])
    assert np.max(np.abs(times - bounds)) < 1e-6
    durations = np.diff(times)
    assert np.max(np.abs(durations[0::2] - t_slip)) < 1e-6  # slipping
    assert np.max(np.abs(durations[1::2] - t_stick)) < 1e-6  # stuck
    assert np.max(np.abs(r.y["position"] - x)) < 1e-8
    # stuck, the mass moves with the belt and friction holds the spring's force
    stuck = r.y["sticking"] > 0.5
    assert np.all(np.abs(r.y["velocity"][stuck] - 0.1) < 1e-12)
    assert np.all(np.abs(r.y["friction_force"][stuck]) <= 2.0 + 1e-9)


# --- the FMU: event indicators and resets in Model Exchange ---------------------------------------

@pytest.mark.slow
def test_fmu_ball_under_fmpy_model_exchange_and_co_simulation(tmp_path):
    fmpy = pytest.importorskip("fmpy")
    from bgc.backends.c import build as cbuild
    from bgc.run.fmu import export_fmu

    if not cbuild.available():
        pytest.skip("no C compiler")
    fmu = export_fmu(BALL, tmp_path / "ball.fmu")
    md = fmpy.read_model_description(str(fmu))
    assert md.numberOfEventIndicators == 1
    for rtol in (1e-6, 1e-10):  # FMPy's own solver (CVode) finds the roots of our indicators
        r = fmpy.simulate_fmu(str(fmu), fmi_type="ModelExchange", solver="CVode",
                              stop_time=3.0, output_interval=1e-3, relative_tolerance=rtol,
                              output=["height", "velocity"])
        assert np.max(np.abs(r["height"] - ball_height(r["time"], 1.0, 0.8))) < 1e-5
    # FMPy records each event twice (before and after): the velocity jumps there
    t, v = r["time"], r["velocity"]
    jumps = t[1:][(np.diff(t) == 0) & (np.diff(v) > 1.0)]
    assert np.allclose(jumps, impact_times(1.0, 0.8, 3.0), atol=1e-8, rtol=0)
    # Co-Simulation: the FMU's own step (the C runtime) locates the impacts inside each step
    r = fmpy.simulate_fmu(str(fmu), fmi_type="CoSimulation", stop_time=3.0,
                          output_interval=1e-2, output=["height"])
    assert np.max(np.abs(r["height"] - ball_height(r["time"], 1.0, 0.8))) < 1e-8


# --- time events: breakpoints, not crossings ----------------------------------------------------

SAMPLER = """bgc: 1
name: sampler
parameters:
  P:  {value: 0.1, unit: s}
  Rl: {value: 0.5, unit: Ohm}
  Cc: {value: 1.0, unit: F}
elements:
  cap:  {type: C, compliance: "Cc", initial: "1"}
  load: {type: R, resistance: "Rl"}
  n:    {type: "0"}
bonds: [[n, cap], [n, load]]
states:
  held: {initial: "0", derivative: "0", unit: V}
events:
  sample:
    EVENT
    do: {held: "e(cap)"}
"""


@pytest.fixture(scope="module")
def samplers(tmp_path_factory):
    """``samplers(target)`` -> the sampler compiled with ``every: P`` and with ``at: P/2``
    added, once per target for the three methods' tests (each test's runs still start from
    its own private cache)."""
    built = {}

    def get(target):
        if target not in built:
            with pytest.MonkeyPatch.context() as mp:
                mp.setenv("BGC_CACHE_DIR", str(seed_c_runtime(tmp_path_factory.mktemp("c"))))
                built[target] = (
                    bgc.compile(SAMPLER.replace("EVENT", 'every: "P"'), target=target),
                    bgc.compile(SAMPLER.replace("EVENT", 'every: "P"\n    at: "P/2"'),
                                target=target))
        return built[target]
    return get


@pytest.mark.parametrize("target", TARGETS)
@pytest.mark.parametrize("method", ["Radau", "Rodas4", "DOP853"])
def test_periodic_time_event_hits_its_times_exactly(target, method, samplers):
    """A sample-and-hold of an RC discharge, v = exp(-t/(R C)): `every: P` fires at k P to an
    ulp or two (the integrator stops there: a breakpoint), and holds v(k P)."""
    model, shifted = samplers(target)
    assert "sample_count" in model.STATE_NAMES
    r = model.simulate((0.0, 1.05), dt=0.01, rtol=1e-10, atol=1e-12, method=method)
    times = np.array([ev[0] for ev in r.events])
    k = np.arange(1, 11)
    assert len(times) == 10
    assert np.all(np.abs(times - k * 0.1) <= 2 * np.spacing(k * 0.1))
    held = np.array([ev[4][1] for ev in r.events])
    assert np.max(np.abs(held - np.exp(-times / 0.5))) < 1e-10
    # between samples the hold keeps the last one (the output at a sample is its left limit)
    i = np.searchsorted(r.t, 0.555)
    assert r.x[list(model.STATE_NAMES).index("held"), i] == held[4]
    # `at` moves the first sample: at 0.05, then every 0.1
    r = shifted.simulate((0.0, 1.0), dt=0.01, rtol=1e-10, atol=1e-12, method=method)
    assert np.allclose([ev[0] for ev in r.events], 0.05 + 0.1 * np.arange(10), rtol=0,
                       atol=4e-16)


# --- two crossings in one step: only the earliest fires there -----------------------------------

TWO_CROSSINGS = """bgc: 1
name: two_crossings
parameters:
  C1: {value: 1.0, unit: F}
  R1: {value: 1.0e+9, unit: Ohm}
elements:
  cap:  {type: C, compliance: "C1", initial: "1"}
  n:    {type: "0"}
  load: {type: R, resistance: "R1"}
bonds: [[n, cap], [n, load]]
modes:
  a: 0
  b: 0
events:
  first:
    when: "t - 0.2"
    direction: rising
    do: {a: 1}
  second:
    when: "t - 0.3"
    direction: rising
    do: {b: "b + 1"}
outputs:
  na: {expr: "a", unit: "1"}
"""


@pytest.mark.parametrize("target", TARGETS)
@pytest.mark.parametrize("method", ["Radau", "Rodas4", "DOP853"])
def test_a_later_crossing_in_the_same_step_waits_for_its_time(target, method):
    """A capacitor at rest lets the steps grow past both guards' zeros (t = 0.2 and 0.3,
    linear in t: the root finder lands on them exactly). Each event fires once, at its own
    time (numpy once fired the second at the first's time too: an exact zero ended the search
    with its bracket's start still at the step's start)."""
    model = bgc.compile(TWO_CROSSINGS, target=target)
    r = model.simulate((0.0, 1.0), t_eval=np.linspace(0.0, 1.0, 5), rtol=1e-8, atol=1e-10,
                       method=method)
    assert [ev[1] for ev in r.events] == ["first", "second"]
    assert np.allclose([ev[0] for ev in r.events], [0.2, 0.3], rtol=0, atol=1e-12)
    b = list(model.STATE_NAMES).index("b")
    assert r.events[-1][4][b] == 1.0  # the second fired once
