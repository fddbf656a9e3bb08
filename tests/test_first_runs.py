"""What a newcomer's first runs trip over (issue 23): max_steps from a scene and from the
command line, `bgc equations` on every model, `bgc simulate MODEL.yaml`, --t-end.

References: the C step loop's own step count (a budget of 5 steps cannot cover a 5 s run that
takes hundreds), the compiled modules' state lists (the equations must have the same states as
the module `bgc compile` writes), and the closed form of the mass-spring-damper's static
deflection (the run of the model alone must settle there).
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import bgc_in_process, seed_c_runtime

from bgc.backends.c import build as cbuild
from bgc.format.scene import MODEL_T_END, is_model_file, model_scene, parse_scene

ROOT = Path(__file__).resolve().parents[1]
MODELS = sorted((ROOT / "models").glob("*.yaml"))
HAS_C = cbuild.available() and bool(cbuild.runtime_sources())


def _bgc(*args, cache_dir):
    """``bgc ARGS`` in this process (conftest's bgc_in_process: the same entry as ``python -m
    bgc``, the run-record replay included; the properties here are the runs', not the
    process's), with its own cache and the system compiler's PATH."""
    if not os.path.lexists(cache_dir):  # a fresh cache: the C runtime's objects built (the
        seed_c_runtime(cache_dir)        # tests here are about the runs, not that build)
    return bgc_in_process(*args, env={"BGC_CACHE_DIR": str(cache_dir), "PATH": "/usr/bin:/bin"},
                          cwd=ROOT)


def _scene(tmp_path, solver: str, model="msd.yaml") -> Path:
    path = tmp_path / "s.yaml"
    path.write_text(f"bgc_scene: 1\nmodel: {ROOT / 'models' / model}\nduration: 5.0\n"
                    f"solver: {solver}\n")
    return path


def test_scene_max_steps_is_read_and_checked(tmp_path):
    sc = parse_scene(_scene(tmp_path, "{method: Radau, max_steps: 123}"))
    assert sc.max_steps == 123
    assert parse_scene(_scene(tmp_path, "{method: Radau}")).max_steps == 50_000
    for bad, what in (("0", "outside"), ("2.5", "whole number"), ("10000000000", "outside")):
        from bgc.base.errors import ModelError

        with pytest.raises(ModelError, match=what) as e:
            parse_scene(_scene(tmp_path, f"{{max_steps: {bad}}}"))
        assert e.value.coord.line == 4


@pytest.mark.skipif(not HAS_C, reason="no C compiler")
def test_max_steps_from_scene_and_command_line(tmp_path):
    """The C step loop counts step attempts: 5 cannot cover the run (exit 1, the message says
    max_steps), --max-steps 1000 on the command line overrides the scene and the run completes;
    the record of that run replays only with the same option."""
    scene = _scene(tmp_path, "{method: Radau, max_steps: 5, backend: c}")
    cache = tmp_path / "cache"
    few = _bgc("simulate", scene, cache_dir=cache)
    assert few.returncode == 1 and "max_steps = 5" in few.stderr, few.stderr
    many = _bgc("simulate", scene, "--max-steps", "1000", "--out", tmp_path / "a.npz",
                cache_dir=cache)
    assert many.returncode == 0, many.stderr
    again = _bgc("simulate", scene, "--max-steps", "1000", "--out", tmp_path / "b.npz",
                 cache_dir=cache)
    assert again.returncode == 0 and "run record" in again.stderr
    a, b = np.load(tmp_path / "a.npz"), np.load(tmp_path / "b.npz")
    np.testing.assert_array_equal(a["position"], b["position"])
    plain = _bgc("simulate", scene, cache_dir=cache)  # not the record of --max-steps 1000
    assert plain.returncode == 1 and "max_steps = 5" in plain.stderr
    bad = _bgc("simulate", scene, "--max-steps", "0", cache_dir=cache)
    assert bad.returncode == 2 and bad.stderr.strip().count("\n") == 0
    assert "--max-steps 0" in bad.stderr


@pytest.mark.parametrize("method", ["Radau", "RK45"])
def test_max_steps_on_the_numpy_backend(tmp_path, method):
    """scipy's step loop on the numpy backend holds max_steps too (issue 23, item 3): a scene's
    5 cannot cover the 5 s run (exit 1, one message naming max_steps and where it stopped);
    --max-steps 1000 covers it; the module's simulate says the same."""
    scene = _scene(tmp_path, f"{{method: {method}, max_steps: 5, backend: numpy}}")
    cache = tmp_path / "cache"
    few = _bgc("simulate", scene, cache_dir=cache)
    assert few.returncode == 1 and "max_steps = 5" in few.stderr, few.stderr
    assert f"{method} stopped at t = " in few.stderr and "Traceback" not in few.stderr
    many = _bgc("simulate", scene, "--max-steps", "1000", "--out", tmp_path / "a.npz",
                cache_dir=cache)
    assert many.returncode == 0, many.stderr
    # the run took more than 5 accepted steps (counted by scipy's solver itself)
    import bgc

    mod = bgc.compile(str(ROOT / "models" / "msd.yaml"))
    res = mod.simulate((0.0, 5.0), method=method, rtol=1e-6, atol=1e-9, max_steps=1000)
    n = int(res.stats["nsteps"])
    assert n > 5
    with pytest.raises(mod.SimulationError, match=f"max_steps = {n - 1}"):
        mod.simulate((0.0, 5.0), method=method, rtol=1e-6, atol=1e-9, max_steps=n - 1)
    assert mod.simulate((0.0, 5.0), method=method, rtol=1e-6, atol=1e-9,
                        max_steps=n).stats["nsteps"] == n


EVENT_BACKENDS = ["numpy", pytest.param("c", marks=pytest.mark.skipif(not HAS_C,
                                                                      reason="no C compiler"))]


@pytest.mark.parametrize("backend", EVENT_BACKENDS)
def test_max_steps_on_the_events_path(tmp_path, backend):
    """A hybrid model (the bouncing ball: its impacts are events, each a restart) holds
    max_steps over the whole run, across its restarts, like the plain path: a scene's 20 cannot
    cover the 3 s of bounces (exit 1, the plain path's message at the scene's line 1), the
    command line's --max-steps 1000 can (the module's own step count: below)."""
    scene = tmp_path / "s.yaml"
    scene.write_text(f"bgc_scene: 1\nmodel: {ROOT / 'models' / 'bouncing_ball.yaml'}\n"
                     "duration: 3.0\noutputs: [height]\n"
                     f"solver: {{method: Radau, rtol: 1.0e-8, max_steps: 20, backend: {backend}}}\n")
    cache = tmp_path / "cache"
    few = _bgc("simulate", scene, cache_dir=cache)
    assert few.returncode == 1 and "Traceback" not in few.stderr, few.stderr
    line = few.stderr.strip().splitlines()[-1]
    assert line.startswith(f"{scene}:1:1: ") and "Radau stopped at t = " in line
    assert "max_steps = 20 steps (raise the scene's solver max_steps or --max-steps)" in line
    many = _bgc("simulate", scene, "--max-steps", "1000", cache_dir=cache)
    assert many.returncode == 0 and "events" in many.stdout, many.stderr


def test_max_steps_on_the_events_path_of_the_module():
    """The module's events simulate: the run's own step count n passes with max_steps = n and
    stops with n - 1 (Radau and an explicit method)."""
    import bgc

    mod = bgc.compile(str(ROOT / "models" / "bouncing_ball.yaml"))
    for method in ("Radau", "RK45"):
        res = mod.simulate((0.0, 3.0), method=method, rtol=1e-8, max_steps=100_000)
        n = int(res.stats["nsteps"])
        assert n > 20 and res.stats["nevents"] >= 3
        with pytest.raises(mod.SimulationError, match=f"max_steps = {n - 1} steps"):
            mod.simulate((0.0, 3.0), method=method, rtol=1e-8, max_steps=n - 1)
        assert mod.simulate((0.0, 3.0), method=method, rtol=1e-8,
                            max_steps=n).stats["nsteps"] == n


@pytest.mark.parametrize("path", MODELS, ids=[p.stem for p in MODELS])
def test_equations_on_every_model(path):
    """bgc.equations (what `bgc equations` prints) accepts every model in models/, rigid
    connections included, with the states of the compiled golden module."""
    import bgc

    eq = bgc.equations(str(path))
    assert len(eq.derivatives) == len(eq.states) > 0
    golden = {}
    for g in (ROOT / "generated").glob("*.py"):
        text = g.read_text()
        if f"Source: {path.name} (" in text[:500]:
            golden = {"n": int(text.split("\nN_STATES = ", 1)[1].split("\n", 1)[0])}
    if golden:
        assert len(eq.states) == golden["n"]


def test_equations_cli_on_a_rigid_model(tmp_path):
    r = _bgc("equations", ROOT / "models" / "double_pendulum_rigid.yaml", cache_dir=tmp_path)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    # four independent states (the rotational momenta and the angles); the translational
    # inertias are eliminated, so they have no derivative line
    assert sum(1 for ln in lines if ln.startswith("d") and "/dt = " in ln) == 4
    assert not any(ln.startswith("dp_rod1__It") for ln in lines)


def test_model_file_is_a_scene_of_its_defaults():
    msd = ROOT / "models" / "msd.yaml"
    assert is_model_file(msd) and not is_model_file(ROOT / "models" / "scenes" / "msd_step.yaml")
    sc = model_scene(msd)
    assert sc.t_span == (0.0, MODEL_T_END) and sc.model_path == str(msd) and not sc.inputs


def test_simulate_a_model_file(tmp_path):
    """`bgc simulate MODEL.yaml` says it is a model and runs its defaults (10 s, or --t-end):
    the mass-spring-damper under its default force settles at F/k."""
    import yaml

    model = ROOT / "models" / "msd.yaml"
    r = _bgc("simulate", model, "--out", tmp_path / "m.npz", cache_dir=tmp_path / "c")
    assert r.returncode == 0, r.stderr
    assert "is a model" in r.stderr and "10 s" in r.stderr
    d = np.load(tmp_path / "m.npz")
    assert d["t"][0] == 0.0 and d["t"][-1] == pytest.approx(10.0)
    r2 = _bgc("simulate", model, "--t-end", "60", "--out", tmp_path / "n.npz",
              cache_dir=tmp_path / "c")
    assert r2.returncode == 0, r2.stderr
    d = np.load(tmp_path / "n.npz")
    assert d["t"][-1] == pytest.approx(60.0)
    p = {k: v["value"] for k, v in yaml.safe_load(model.read_text())["parameters"].items()}
    assert d["position"][-1] == pytest.approx(p["F0"] / p["k"], rel=1e-3)
    bad = _bgc("simulate", model, "--t-end", "-1", cache_dir=tmp_path / "c")
    assert bad.returncode == 2 and "--t-end" in bad.stderr


# ---------------------------------------------------------------------------------------------
# The quick-start's figures (bgc.run.plots), read as matplotlib objects before they are saved


def _circle_outputs():
    t = np.linspace(0.0, 4.0, 400)
    w = 2 * np.pi / 4
    desired = np.array([0.5 + 0.01 * np.cos(w * t), 0.01 * np.sin(w * t), 0.3 + 0 * t])
    projected = desired + 1e-4
    actual = desired + 2e-4 * np.sin(3 * w * t)
    c, s = np.cos(w * t), np.sin(w * t)
    R = np.array([[c, -s, 0 * t], [s, c, 0 * t], [0 * t, 0 * t, 1 + 0 * t]])
    return t, {"p3_desired": desired, "p3_projected": projected, "p3": actual, "R4": R}


def _inside(fig, artist):
    """The artist's drawn extent lies within the figure (not cut at its edges)."""
    fig.canvas.draw()
    box, page = artist.get_window_extent(), fig.bbox
    return box.x0 >= page.x0 - 1 and box.x1 <= page.x1 + 1 and box.y0 >= page.y0 - 1 \
        and box.y1 <= page.y1 + 1


def test_path3d_figure_axes_legend_and_labels():
    from bgc.run.plots import figure_path3d

    t, y = _circle_outputs()
    units = {"p3": "m", "p3_desired": "m", "p3_projected": "m"}
    fig = figure_path3d(t, y, ["p3_desired", "p3_projected", "p3"], "Circle: path of P3",
                        ("desired", "projected desired", "actual"), units)
    ax3, top = fig.axes
    assert (ax3.get_xlabel(), ax3.get_ylabel(), ax3.get_zlabel()) == ("X0 [m]", "Y0 [m]",
                                                                      "Z0 [m]")
    assert (top.get_xlabel(), top.get_ylabel()) == ("X0 [m]", "Y0 [m]")
    legend = top.get_legend()
    assert [x.get_text() for x in legend.get_texts()] == ["desired", "projected desired",
                                                         "actual"]
    lines = {ln.get_label(): ln for ln in top.get_lines()}
    # the projected path is drawn over the actual one, which is wider and half transparent
    assert lines["projected desired"].get_zorder() > lines["actual"].get_zorder()
    assert lines["actual"].get_alpha() < 1
    for label in (ax3.zaxis.label, ax3.xaxis.label, top.yaxis.label):
        assert _inside(fig, label), label.get_text()
    import matplotlib.pyplot as plt

    plt.close(fig)


def test_loci_figure_units_titles_apart_and_labels_inside():
    from bgc.run.plots import figure_loci

    t, y = _circle_outputs()
    fig = figure_loci(t, y, ["R4"], "Circle: loci of the unit vectors of R4 (Fig. 8)",
                      ("i4", "j4", "k4"), {"R4": "-"})
    fig.canvas.draw()
    sup = fig._suptitle.get_window_extent()
    for ax in fig.axes:
        assert (ax.get_xlabel(), ax.get_ylabel(), ax.get_zlabel()) == ("X0 [-]", "Y0 [-]",
                                                                       "Z0 [-]")
        title = ax.title.get_window_extent()
        assert title.y1 < sup.y0 or title.x1 < sup.x0 or title.x0 > sup.x1  # apart
        assert _inside(fig, ax.zaxis.label) and _inside(fig, ax.title)
    import matplotlib.pyplot as plt

    plt.close(fig)


def test_norm_of_a_matrix_is_frobenius_and_names_share_one_namespace():
    import bgc
    from bgc.base.errors import ModelError

    text = (ROOT / "models" / "msd.yaml").read_text()
    pos = '  position: {expr: "q(spring)", unit: m}'
    assert pos in text
    eq = bgc.equations(text.replace(pos, pos + '\n  nrm: "norm([[1, 2], [3, q(spring)]])"'))
    (nrm,) = [o.rhs for o in eq.outputs if str(o.lhs) == "nrm"]
    q = [s for s in nrm.free_symbols][0]
    for v in (0.0, 0.5, -2.0):  # the Frobenius norm, by numpy
        assert float(nrm.subs(q, v)) == pytest.approx(np.linalg.norm([[1, 2], [3, v]], "fro"))
    with pytest.raises(ModelError, match="already an element at line") as e:
        bgc.equations(text.replace(pos, pos + '\n  mass: "1"'))
    assert "one namespace" in str(e.value)


CONTACT = """\
bgc: 1
name: contact
description: a mass pushed onto a stiff wall (stiff only once it touches)
parameters:
  m: {value: 1.0, unit: kg}
  F: {value: 1.0, unit: N}
elements:
  push: {type: Se, effort: "F"}
  j: {type: "1"}
  mass: {type: I, inertia: "m"}
  wall: {type: C, effort: "where(q > 0.05, 1.0e7 * (q - 0.05), 0)"}
bonds: [[push, j], [j, mass], [j, wall]]
outputs:
  x: {expr: "q(wall)", unit: m}
"""


def test_accuracy_judges_stiffness_along_the_run(tmp_path, monkeypatch):
    """Free flight until x = 0.05 m (t = 0.32 s), then a 1e7 N/m wall: the Jacobian at t0 has
    eigenvalues 0 (index 0), on the wall sqrt(1e7) = 3162 1/s (index 3162 over 1 s): stiff."""
    from bgc.studies.accuracy import STIFF_THRESHOLD, is_stiff, prepare

    monkeypatch.setenv("BGC_CACHE_DIR", str(tmp_path / "cache"))
    (tmp_path / "contact.yaml").write_text(CONTACT)
    scene = tmp_path / "s.yaml"
    scene.write_text("bgc_scene: 1\nmodel: contact.yaml\nduration: 1.0\n"
                     "solver: {rtol: 1.0e-6, atol: 1.0e-9}\n")
    setup = prepare(str(scene))
    x0 = setup.module.initial_state().reshape(-1)
    J0 = np.asarray(setup.module.jacobian(0.0, x0)).reshape(2, 2)
    assert np.max(np.abs(np.linalg.eigvals(J0))) == 0.0  # t0 alone says: not stiff
    stiff, index = is_stiff(setup)
    assert stiff and index > STIFF_THRESHOLD
    assert index == pytest.approx(np.sqrt(1e7) * 1.0, rel=1e-6)


# ---------------------------------------------------------------------------------------------
# Linearisation: an initial guess, unstable modes said, the Bode range


def test_linearize_takes_an_initial_guess():
    """The pendulum has two equilibria: hanging (theta = 0, modes +/- j sqrt(g/l)) and upright
    (theta = pi, modes +/- sqrt(g/l)); x0 chooses which one Newton finds."""
    import bgc
    from bgc.linear import unstable_modes

    path = str(ROOT / "models" / "pendulum.yaml")
    mod = bgc.compile(path)
    k = list(mod.STATE_NAMES).index("gravity.q")
    w = np.sqrt(9.81 / 1.0)
    for theta, stable in ((0.4, True), (2.8, False)):
        x0 = np.zeros(len(mod.STATE_NAMES))
        x0[k] = theta
        lin = bgc.linearize(mod, x0=x0)
        assert float(lin.x[k]) == pytest.approx(0.0 if stable else np.pi, abs=1e-9)
        lam = np.linalg.eigvals(lin.A)
        if stable:
            np.testing.assert_allclose(sorted(lam.imag), [-w, w], rtol=1e-9)
            assert not unstable_modes(lin.A)
        else:
            np.testing.assert_allclose(sorted(lam.real), [-w, w], rtol=1e-9)
            assert [v.real for v in unstable_modes(lin.A)] == pytest.approx([w], rel=1e-9)


def test_bode_range_ignores_near_zero_eigenvalues():
    from bgc.linear import bode_range

    # a free integrator (eigenvalue 0, and one at round-off) beside a 10 rad/s oscillator
    A = np.array([[0.0, 0, 0, 0], [0, -1e-19, 0, 0], [0, 0, 0, 1], [0, 0, -100.0, -1]])
    lo, hi = bode_range(A)
    f = 10.0 / (2 * np.pi)
    assert lo == pytest.approx(f / 100) and hi == pytest.approx(f * 100)


def test_linearize_cli_warns_of_unstable_modes_and_takes_a_freq_range(tmp_path):
    """msd with a negative stiffness: the equilibrium F0/k is unstable, lambda = -1 + sqrt(101)
    (lambda^2 + (c/m) lambda + k/m = 0 with m = 2, c = 4, k = -200)."""
    text = (ROOT / "models" / "msd.yaml").read_text()
    old = "k:  {value: 200.0, unit: N/m, min: 0,"
    assert old in text
    model = tmp_path / "neg.yaml"
    model.write_text(text.replace(old, "k:  {value: -200.0, unit: N/m,"))
    r = _bgc("linearize", model, "--out", tmp_path / "lin", "--bode", "F:position",
             "--freq-range", "0.01", "100", cache_dir=tmp_path / "c")
    assert r.returncode == 0, r.stderr
    lam = -1 + np.sqrt(101)
    assert "warning: 1 unstable mode(s)" in r.stderr and f"{lam:+.3g}" in r.stderr
    assert (tmp_path / "lin" / "bode_F_position.png").stat().st_size > 1000
    bad = _bgc("linearize", model, "--out", tmp_path / "lin", "--bode", "F:position",
               "--freq-range", "100", "1", cache_dir=tmp_path / "c")
    assert bad.returncode == 2 and "--freq-range" in bad.stderr


# ---------------------------------------------------------------------------------------------
# The newcomer's three models (docs/first_models.md), written from the docs alone and run with
# the documented command at default settings (no method, tolerances, max_step or backend),
# each against an answer obtained outside bgc.

FIRST = ROOT / "docs" / "first_models"


def _first_run(tmp_path, scene):
    out = tmp_path / "r.npz"
    res = _bgc("simulate", FIRST / scene, "--out", out, cache_dir=tmp_path / "cache")
    assert res.returncode == 0, res.stderr
    return np.load(out)


@pytest.mark.slow  # a compile and a tight scipy reference: about 30 s on 2 shared cores
def test_first_rectifier_ripple_and_diode_current(tmp_path):
    """The library-built half-wave rectifier against a scipy model written here: the capacitor
    voltage by LSODA (rtol 1e-10, max_step 5e-5), the loop current of the Shockley diode in
    series with Rs by a bracketed root (brentq). The ripple of the last two periods and the
    diode's peak current agree within 0.5 %, the load voltage within 1 mV."""
    import scipy.integrate as si
    import scipy.optimize as so

    i_s, vt, rs, rl, c1, v0, f0 = 1e-12, 0.025852, 1.0, 1000.0, 1e-3, 10.0, 50.0

    def current(vs, vc):
        g = lambda i: i - i_s * np.expm1((vs - vc - rs * i) / vt)  # noqa: E731
        return so.brentq(g, -i_s, max((vs - vc) / rs, 0.0) + 1.0, xtol=1e-15, rtol=1e-14)

    r = _first_run(tmp_path, "rectifier_scene.yaml")
    t = r["t"]
    sol = si.solve_ivp(lambda tt, y: [(current(v0 * np.sin(2 * np.pi * f0 * tt), y[0])
                                       - y[0] / rl) / c1],
                       (0.0, float(t[-1])), [0.0], method="LSODA", rtol=1e-10, atol=1e-13,
                       t_eval=t, max_step=5e-5)
    assert sol.success
    v = sol.y[0]
    i = np.array([current(v0 * np.sin(2 * np.pi * f0 * a), b) for a, b in zip(t, v)])
    last = t >= 0.16
    ripple, ripple_ref = np.ptp(r["v_load"][last]), np.ptp(v[last])
    assert 0.1 < ripple_ref < 0.25  # the physics: a 1 mF, 1 kohm load on a 50 Hz half wave
    assert abs(ripple - ripple_ref) < 5e-3 * ripple_ref, (ripple, ripple_ref)
    peak, peak_ref = r["i_diode"][last].max(), i[last].max()
    assert abs(peak - peak_ref) < 5e-3 * peak_ref, (peak, peak_ref)
    assert np.max(np.abs(r["v_load"] - v)) < 1e-3


@pytest.mark.slow  # a compile and the reference: about 30 s on 2 shared cores
def test_first_fourbar_against_the_lagrange_reference(tmp_path):
    """The four-bar of library rods and rigid pins (its second ground pin closes the loop)
    against tests/reference/fourbar_lagrange.py (reduced Lagrange model, rtol 1e-12) with this
    model's friction: ground pivots only (c2 = c3 = 0). The angles within 1e-5 rad over 5 s
    of a crank swinging through 4.8 rad."""
    sys.path.insert(0, str(ROOT / "tests"))
    from reference import fourbar_lagrange as fl

    r = _first_run(tmp_path, "fourbar_scene.yaml")
    ref = fl.simulate(r["t"], params={"c2": 0.0, "c3": 0.0})
    assert np.ptp(ref["th1"]) > 3.0  # the crank turns over: a real motion
    for k in ("th1", "th2", "th3"):
        assert np.max(np.abs(r[k] - ref[k])) < 1e-5, k


@pytest.mark.slow  # a compile and a stiff 2 s run: about 20 s on 2 shared cores
def test_first_top_precesses_at_the_closed_form_rate(tmp_path):
    """The library rigid_rod held at its end Q by a stiff spherical joint, started in steady
    precession (the rod's w0 and vC0): its axis turns about the vertical at the slow root Omega of
    I1 cos(th) Omega^2 - I3 w3 Omega + m g L = 0 (Goldstein, sec. 5.7; I1 about the fixed point,
    computed here from the cylinder's dimensions), and its tilt stays th."""
    m, l, rho, g, th, w3 = 1.0, 0.1, 0.05, 9.81, 0.5, 200.0
    i3 = m * rho ** 2 / 2
    i1 = m * (3 * rho ** 2 + l ** 2) / 12 + m * (l / 2) ** 2
    a, b, c = i1 * np.cos(th), -i3 * w3, m * g * l / 2
    omega = (-b - np.sqrt(b * b - 4 * a * c)) / (2 * a)
    r = _first_run(tmp_path, "top_scene.yaml")
    rate = np.polyfit(r["t"], np.unwrap(r["azimuth"]), 1)[0]
    assert abs(rate - omega) < 1e-5 * omega, (rate, omega)
    assert np.max(np.abs(r["tilt"] - th)) < 1e-4
