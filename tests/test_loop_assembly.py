"""Closed loops at position level (issue 24, continued): the `closure:` residual the Baumgarte
law acts on, consistent initial conditions (checked, or projected with `initial: project`),
numerically redundant constraints found at compile time.

Answers from outside bgc: the closed-form decay of a critically damped residual, the
four-bar's closed-form assembly (tests/reference/fourbar_lagrange.py), its loop closure and
velocity constraint written here from the geometry, and the closed-form motion of a
parallelogram linkage (one degree of freedom: its coupler translates without turning).
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bgc  # noqa: E402
from bgc.base.errors import ModelError  # noqa: E402
from reference import fourbar_lagrange as fl  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RIGID = ROOT / "models" / "fourbar_rigid.yaml"
PARALLELOGRAM = ROOT / "tests" / "loops" / "parallelogram.yaml"
CRANK = "  crank: {type: rod, m: m1, l: l1, g: g, th0: th1_0}"
L = (0.3, 0.9, 0.7)


def _without_closure(text: str) -> str:
    start = text.index("    closure:")
    end = text.index("\n", text.index("+ l3", start))
    return text[:start] + text[end + 1:]


def _with(text: str, constraints: str) -> str:
    return text.replace("\nparameters:", f"\nconstraints: {constraints}\nparameters:", 1)


def _closure(th) -> np.ndarray:
    """The loop's residual from the angles (the rocker's B minus O2 = (1, 0))."""
    return np.array([sum(li * np.cos(a) for li, a in zip(L, th)) - 1.0,
                     sum(li * np.sin(a) for li, a in zip(L, th))])


# ---------------------------------------------------------------------------------------------
# closure: the Baumgarte law on the geometric residual


@pytest.fixture(scope="module")
def fourbar_numpy():
    return bgc.compile(str(RIGID))


DECAY_T = np.array([0.0, 0.02, 0.05, 0.1, 0.2, 0.4])


def _off_the_loop(mod, t):
    """mod's run from its initial state with the crank turned by 1e-5 rad (at rest, so
    Phi'(0) = 0) over (0, t[-1]), Radau at rtol 1e-11: the loop's residual Phi at the times t
    (2, len(t)). The start is inconsistent on purpose (check_constraints=False)."""
    x0 = np.array(mod.initial_state(), dtype=float)
    x0[list(mod.STATE_NAMES).index("crank.th")] += 1e-5
    r = mod.module.simulate((0.0, t[-1]), t_eval=t, x0=x0, method="Radau", rtol=1e-11,
                            atol=1e-14, check_constraints=False)
    return _closure([r.y["th1"], r.y["th2"], r.y["th3"]])


@pytest.fixture(scope="module")
def closed_off_the_loop(fourbar_numpy):
    """The stabilised four-bar started off the loop, one run over 1 s for both tests below:
    Phi at DECAY_T and at t = 1 s (the last column)."""
    return _off_the_loop(fourbar_numpy, np.append(DECAY_T, 1.0))


def test_closure_residual_decays_critically_damped(closed_off_the_loop):
    """Started off the loop (crank turned by 1e-5 rad, at rest: Phi'(0) = 0), the residual
    follows Phi(t) = Phi(0) (1 + alpha t) exp(-alpha t), alpha = 20 1/s (the law is exact:
    Phi' is the flow the constraint holds)."""
    t = DECAY_T
    phi = closed_off_the_loop[:, :len(t)]
    alpha = 20.0
    want = phi[:, :1] * (1 + alpha * t) * np.exp(-alpha * t)
    assert np.abs(phi[:, 0]).max() > 2e-6
    assert np.abs(phi - want).max() < 1e-4 * np.abs(phi[:, 0]).max()


def test_without_closure_the_residual_stays(closed_off_the_loop):
    m = bgc.compile(_without_closure(RIGID.read_text()))
    for phi, stays in ((_off_the_loop(m, np.array([0.0, 1.0])), True),
                       (closed_off_the_loop[:, [0, -1]], False)):
        ratio = np.linalg.norm(phi[:, 1]) / np.linalg.norm(phi[:, 0])
        assert (ratio > 0.3) if stays else (ratio < 1e-6)


@pytest.mark.parametrize("closure, words", [
    ('"t * f(crank.B)"', "states, parameters and t only"),
    ('"[crank.th, 0]"', "closure '[crank.th, 0]' is 1, but the displacement"),
])
def test_closure_is_checked(closure, words):
    text = RIGID.read_text()
    start = text.index("    closure:")
    end = text.index("\n", text.index("+ l3", start))
    text = text[:start] + f"    closure: {closure}\n" + text[end + 1:]
    with pytest.raises(ModelError) as e:
        bgc.compile(text)
    assert words in str(e.value)
    assert "closure" in text.splitlines()[e.value.coord.line - 1]


def test_closure_on_an_ordinary_source_is_refused():
    text = RIGID.read_text().replace('  pivot1: {type: Sf, flow: "[0, 0]"}',
                                     '  pivot1: {type: Sf, flow: "[0, 0]", closure: "[0, 0]"}')
    with pytest.raises(ModelError) as e:
        bgc.compile(text)
    assert "closes no kinematic loop" in str(e.value) and "pivot1" in str(e.value)


# ---------------------------------------------------------------------------------------------
# consistent initial conditions


def test_inconsistent_initial_positions_are_located(tmp_path):
    text = RIGID.read_text().replace(CRANK, CRANK.replace("th1_0}", "th1_0 + 0.05}"))
    f = tmp_path / "fb.yaml"
    f.write_text(text)
    from conftest import bgc_in_process

    # in-process: the exit status is the SystemExit's (tests/test_bad_input.py runs real
    # processes for the status and the absence of a traceback)
    out = bgc_in_process("check", str(f))
    assert out.returncode == 2 and "Traceback" not in out.stderr
    head = out.stderr.strip().splitlines()[0]
    line = int(head.split(":")[1])
    assert head.startswith(f"{f}:") and "pivot2:" in text.splitlines()[line - 1]
    assert "constraint 'pivot2' closing the kinematic loop through" in head
    assert "initial positions violate its closure" in head and "initial: project" in head
    # the residual: the loop opened by turning the crank alone
    p = fl.model_params()
    th = fl.FourBar(p).assemble(p["th1_0"])
    res = [float(v) for v in head.split("residual is [")[1].split("]")[0].split(",")]
    assert np.allclose(res, _closure([th[0] + 0.05, th[1], th[2]]), rtol=1e-5)


def test_project_assembles_the_loop(tmp_path):
    text = _with(RIGID.read_text().replace(CRANK, CRANK.replace("th1_0}", "th1_0 + 0.05}")),
                 "{initial: project}")
    m = bgc.compile(text)
    x0 = dict(zip(m.STATE_NAMES, m.initial_state()))
    th = [x0["crank.th"], x0["coupler.th"], x0["rocker.th"]]
    ref = fl.FourBar(fl.model_params()).assemble(th[0])
    assert np.abs(np.array(th) - ref).max() < 1e-10
    assert abs(th[0] - 1.05) < 0.05  # a nearby pose, not the model's own
    f = tmp_path / "fb.yaml"
    f.write_text(text)
    from conftest import bgc_in_process

    out = bgc_in_process("check", str(f))  # in-process
    assert out.returncode == 0, out.stderr
    note = next(x for x in out.stdout.splitlines() if "initial positions projected" in x)
    assert "crank.th 1.05 -> " in note and "coupler.th" in note and "rocker.th" in note


def test_project_corrects_the_initial_velocities():
    spun = CRANK.replace("th0: th1_0}", "th0: th1_0, w0: 1.0}")
    text = RIGID.read_text().replace(CRANK, spun)
    with pytest.raises(ModelError) as e:
        bgc.compile(text)
    assert "initial velocities violate it" in str(e.value)
    m = bgc.compile(_with(text, "{initial: project}"))
    y = m.outputs(0.0, m.initial_state())
    th = [y["th1"], y["th2"], y["th3"]]
    w = np.array([y["w1"], y["w2"], y["w3"]])
    jac = np.array([[-li * np.sin(a) for li, a in zip(L, th)],
                    [li * np.cos(a) for li, a in zip(L, th)]])
    assert np.abs(w).max() > 1e-3  # corrected, not zeroed (the smallest change of the momenta)
    assert np.abs(jac @ w).max() < 1e-10


def test_api_x0_is_checked_at_run_start(fourbar_numpy):
    """x0 from the caller: the position residual (from the stabilised law: the closure's
    value) and the velocity residual, each against the geometry's own."""
    m = fourbar_numpy
    names = list(m.STATE_NAMES)
    x0 = np.array(m.initial_state(), dtype=float)
    x0[names.index("crank.th")] += 1e-3
    with pytest.raises(ModelError) as e:
        m.simulate((0.0, 0.1), x0=x0)
    msg = str(e.value)
    assert "constraint 'pivot2'" in msg and "positions violate its closure" in msg
    th = [x0[names.index(n)] for n in ("crank.th", "coupler.th", "rocker.th")]
    res = [float(v) for v in msg.split("residual is [")[1].split("]")[0].split(",")]
    assert np.allclose(res, _closure(th), rtol=1e-5, atol=1e-12)  # 6 digits shown
    x0 = np.array(m.initial_state(), dtype=float)
    x0[names.index("crank.Ir.p")] += 1e-3  # the crank alone spun: the rocker's end moves
    with pytest.raises(ModelError) as e:
        m.simulate((0.0, 0.1), x0=x0)
    assert "velocities violate it" in str(e.value)
    r = m.simulate((0.0, 0.1), x0=np.array(m.initial_state(), dtype=float))
    assert r.t[-1] == pytest.approx(0.1)


def test_scene_initial_is_checked_at_run_start(tmp_path):
    scene = tmp_path / "s.yaml"
    scene.write_text(f"bgc_scene: 1\nname: s\nmodel: {RIGID}\nduration: 0.1\n"
                     "initial: {crank.th: 1.01}\n")
    from conftest import bgc_in_process

    out = bgc_in_process("simulate", str(scene), "--backend", "numpy")  # in-process
    assert out.returncode == 2 and "Traceback" not in out.stderr
    head = out.stderr.strip().splitlines()[-1]
    assert head.startswith(f"{scene}:5:") and "positions violate its closure" in head


def test_initial_option_is_validated():
    with pytest.raises(ModelError) as e:
        bgc.compile(_with(RIGID.read_text(), "{initial: fix}"))
    assert "constraints: initial must be 'check' or 'project'" in str(e.value)


# ---------------------------------------------------------------------------------------------
# numerically redundant constraints


def test_numerically_redundant_constraint_is_reported():
    from conftest import bgc_in_process

    out = bgc_in_process("check", str(PARALLELOGRAM))  # in-process
    assert out.returncode == 0, out.stderr
    line = next(x for x in out.stdout.splitlines() if "redundant constraint components" in x)
    assert line.count(".q[") == 1  # 12 degrees of freedom, 12 components, mobility 1


def _parallelogram_reference(t):
    g, l, ms, mc, tau0 = 9.81, 0.4, (0.5, 0.7, 0.6), 1.5, 0.5

    def f(t, y):
        th, w = y
        torque = tau0 * np.sin(2 * t) - g * np.cos(th) * (l / 2 * sum(ms) + mc * l)
        return [w, torque / (l ** 2 * (sum(ms) / 3 + mc))]

    r = solve_ivp(f, (0, t[-1]), [-1.0, 0.0], t_eval=t, rtol=1e-12, atol=1e-12,
                  method="DOP853")
    return r.y[0]


def test_redundant_parallelogram_against_its_closed_form():
    m = bgc.compile(str(PARALLELOGRAM))
    t = np.linspace(0.0, 5.0, 101)
    r = m.simulate((0.0, 5.0), t_eval=t, method="Radau", rtol=1e-10, atol=1e-12)
    ref = _parallelogram_reference(t)
    for name in ("th1", "th2", "th3"):
        assert np.abs(r.y[name] - ref).max() < 1e-6
    assert np.abs(r.y["thc"]).max() < 1e-8


# ---------------------------------------------------------------------------------------------
# linearisation on the constraint manifold


def _reference_small_oscillation():
    """The reference's one-degree-of-freedom form (crank angle and rate) without the torque:
    its stable equilibrium (a sign change of w1' from + to -) and the eigenvalues of its
    Jacobian there (central differences)."""
    from scipy.optimize import brentq

    p = fl.model_params()
    p["tau0"] = 0.0
    fb = fl.FourBar(p)

    def acc(a):
        return fb.rhs_reduced(0.0, np.array([a, 0.0, 0.0, 0.0]))[1]

    grid = np.linspace(-np.pi, np.pi, 73)
    a, b = next((a, b) for a, b in zip(grid, grid[1:]) if acc(a) > 0 > acc(b))
    th1 = brentq(acc, a, b, xtol=1e-15)
    h, jac = 1e-6, np.zeros((2, 2))
    for k in range(2):
        e = np.zeros(4)
        e[k] = h
        y = np.array([th1, 0.0, 0.0, 0.0])
        jac[:, k] = (fb.rhs_reduced(0.0, y + e)[:2] - fb.rhs_reduced(0.0, y - e)[:2]) / (2 * h)
    return fb.assemble(th1), np.linalg.eigvals(jac)


def test_linearize_reduces_to_the_constraint_manifold(fourbar_numpy):
    th, ref = _reference_small_oscillation()
    m = fourbar_numpy
    x0 = np.array(m.initial_state(), dtype=float)
    names = list(m.STATE_NAMES)
    for n, v in zip(("crank.th", "coupler.th", "rocker.th"), th):
        x0[names.index(n)] = v
    lin = bgc.linearize(m, x0=x0)
    full = np.linalg.eigvals(lin.A)
    assert np.sum(np.abs(full + 20.0) < 1e-3) == 4  # the stabilisation's modes, in A
    assert lin.reduced is not None and "constraint manifold" in lin.reduced.note
    red = np.linalg.eigvals(lin.reduced.A)
    assert len(red) == 4 and not np.any(np.abs(red + 20.0) < 1.0)
    pair = max(ref, key=lambda z: z.imag)
    got = [md.eigenvalue for md in lin.modes]
    assert min(abs(z - pair) for z in got) < 1e-6 * abs(pair)
    # the rest: the two energy integrators W_in, W_diss
    assert sorted(abs(z) for z in got)[:2] == pytest.approx([0.0, 0.0], abs=1e-9)
