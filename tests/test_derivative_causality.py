"""Derivative causality eliminated: rigid connections compile to ODEs (issue 13).

Every check is against an answer obtained outside bgc: the hand-reduced ODE of two inertias
through a gear, and equations of motion of planar rod chains derived here from a Lagrangian
with sympy (absolute angles as coordinates, integrated by scipy), energy conservation, and
the compliant model converging to the rigid one as the joint stiffness grows.
"""
from __future__ import annotations

import random
import sys
from functools import cache
from pathlib import Path

import numpy as np
import pytest
import sympy as sp
from scipy.integrate import solve_ivp

from bgc.backends.load import load_module
from bgc.base.errors import ModelError
from bgc.format.parse import parse_text
from bgc.run.driver import compile_model

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))
from planar_chain import LENGTH, MASS, TH0, W0, chain_yaml  # noqa: E402

_count = iter(range(10 ** 6))


def module(text: str, name: str = "m", **kw):
    c = compile_model(parse_text(text, f"{name}.yaml"), **kw)
    return c, load_module(c.source, f"deriv_{name}_{next(_count)}")


# ---------------------------------------------------------------------------------------------
# Two inertias through a rigid gear of ratio n, with dampers and a spring on shaft 1.
#   (J1 + n^2 J2) w1' = T(t) - (c1 + n^2 c2) w1 - k q,   q' = w1,   w2 = n w1

GEAR = """\
bgc: 1
name: gear_pair
parameters: {J1: 0.5, J2: 0.2, n: 3.0, c1: 0.1, c2: 0.05, k: 4.0, T0: 1.0}
elements:
  drive: {type: Se, effort: "T0 * sin(t)"}
  w1: {type: "1"}
  I1: {type: I, inertia: "J1", initial: "J1 * 2.0"}
  R1: {type: R, resistance: "c1"}
  K:  {type: C, stiffness: "k", initial: "0.1"}
  gear: {type: TF, ratio: "n"}
  w2: {type: "1"}
  I2: {type: I, inertia: "J2"}
  R2: {type: R, resistance: "c2"}
bonds: [[drive, w1], [w1, I1], [w1, R1], [w1, K], [w1, gear], [gear, w2], [w2, I2], [w2, R2]]
outputs: {speed2: "f(I2)", p2: "p(I2)", torque2: "e(I2)"}
"""
GP = dict(J1=0.5, J2=0.2, n=3.0, c1=0.1, c2=0.05, k=4.0, T0=1.0)


def gear_reduced(t, y, P=GP):
    w, q = y
    J = P["J1"] + P["n"] ** 2 * P["J2"]
    dw = (P["T0"] * np.sin(t) - (P["c1"] + P["n"] ** 2 * P["c2"]) * w - P["k"] * q) / J
    return np.array([dw, w])


@pytest.fixture(scope="module")
def gear():
    return module(GEAR, "gear_pair")


def test_gear_pair_states_and_rhs_at_random_points(gear):
    c, m = gear
    assert m.STATE_NAMES == ("I1.p", "K.q")  # one state per independent storage element
    assert c.causality.derivative == ("I2",)
    rng = np.random.default_rng(1)
    x = rng.normal(size=(2, 50))
    t = rng.uniform(0, 10, size=50)
    J1, J2, n = GP["J1"], GP["J2"], GP["n"]
    w = x[0] / J1
    dw, dq = gear_reduced(t, np.array([w, x[1]]))
    dx = m.rhs(t, x)
    np.testing.assert_allclose(dx[0], J1 * dw, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(dx[1], dq, rtol=1e-12, atol=1e-13)
    y = m.outputs(t, x)
    np.testing.assert_allclose(y["speed2"], n * w, rtol=1e-13)
    np.testing.assert_allclose(y["p2"], J2 * n * w, rtol=1e-13)
    np.testing.assert_allclose(y["torque2"], J2 * n * dw, rtol=1e-11, atol=1e-13)
    # the analytic Jacobian follows the solve: against central differences
    for k in range(5):
        J = m.jacobian(t[k], x[:, k])
        h = 1e-6
        fd = np.column_stack([(m.rhs(t[k], x[:, k] + h * e) - m.rhs(t[k], x[:, k] - h * e)) / (2 * h)
                              for e in np.eye(2)])
        np.testing.assert_allclose(J, fd, rtol=1e-7, atol=1e-8)
    # parameters are still parameters (the reduced inertia is not folded)
    p = {"J2": 0.7, "n": 0.5}
    P = {**GP, **p}
    dw2, _ = gear_reduced(t[:3], np.array([w[:3], x[1, :3]]), P)
    np.testing.assert_allclose(m.rhs(t[:3], x[:, :3], p)[0], J1 * dw2, rtol=1e-12)


def test_gear_pair_run_matches_reduced_ode(gear):
    _, m = gear
    t_eval = np.linspace(0, 10, 101)
    _, x, y = m.simulate((0, 10), t_eval=t_eval, method="DOP853", rtol=1e-11, atol=1e-12)
    ref = solve_ivp(gear_reduced, (0, 10), [2.0, 0.1], method="DOP853", t_eval=t_eval,
                    rtol=1e-11, atol=1e-12)
    np.testing.assert_allclose(x[0] / GP["J1"], ref.y[0], atol=1e-8)
    np.testing.assert_allclose(x[1], ref.y[1], atol=1e-8)
    np.testing.assert_allclose(y["speed2"], GP["n"] * ref.y[0], atol=1e-8)


def test_gear_pair_does_not_depend_on_file_order(gear):
    """Shuffled elements and bonds: the same states, the same derivatives."""
    _, m0 = gear
    lines = GEAR.splitlines()
    i0 = lines.index("elements:") + 1
    i1 = lines.index("bonds: [[drive, w1], [w1, I1], [w1, R1], [w1, K], [w1, gear], [gear, w2], "
                     "[w2, I2], [w2, R2]]")
    rng = random.Random(3)
    x = np.random.default_rng(2).normal(size=(2, 7))
    for trial in range(3):
        els = lines[i0:i1]
        rng.shuffle(els)
        bonds = ["[drive, w1]", "[w1, I1]", "[w1, R1]", "[w1, K]", "[w1, gear]", "[gear, w2]",
                 "[w2, I2]", "[w2, R2]"]
        rng.shuffle(bonds)
        text = "\n".join(lines[:i0] + els + [f"bonds: [{', '.join(bonds)}]"] + lines[i1 + 1:])
        c, m = module(text, f"gear_s{trial}")
        assert c.causality.derivative == ("I2",)
        perm = [m0.STATE_NAMES.index(s) for s in m.STATE_NAMES]
        np.testing.assert_allclose(m.rhs(0.3, x[perm]), m0.rhs(0.3, x)[perm], rtol=1e-13)


def test_strict_causality_keeps_the_error(tmp_path, monkeypatch):
    """The command line in-process (click's runner, from the repository root as a real run:
    three `bgc` processes cost 3 to 5 s of CPU in imports alone; tests/test_bad_input.py runs
    real processes for the exit status and the absence of a traceback)."""
    from click.testing import CliRunner

    from bgc.cli.commands import main

    with pytest.raises(ModelError, match=r"I 'I2' is forced into derivative causality"):
        compile_model(parse_text(GEAR, "g.yaml"), strict_causality=True)
    with pytest.raises(ModelError, match="derivative causality"):
        compile_model(parse_text(GEAR + "causality: strict\n", "g.yaml"))
    with pytest.raises(ModelError, match="causality: 'loose' is not one of"):
        parse_text(GEAR + "causality: loose\n", "g.yaml")
    f = tmp_path / "gear_pair.yaml"
    f.write_text(GEAR)
    monkeypatch.chdir(ROOT)

    def bgc_cli(*args):
        r = CliRunner().invoke(main, list(args), prog_name="bgc")
        assert r.exception is None or isinstance(r.exception, SystemExit), \
            (r.exception, r.stderr)
        return r
    for cmd in ("check", "compile"):
        r = bgc_cli(cmd, "--strict-causality", str(f), *(["-o", str(tmp_path / "o.py")]
                                                        if cmd == "compile" else []))
        assert r.exit_code == 2 and "gear_pair.yaml:12:3: derivative causality" in r.stderr, \
            r.stderr
        assert "Traceback" not in r.stderr
    assert not (tmp_path / "o.py").exists()
    r = bgc_cli("check", str(f))
    assert r.exit_code == 0, r.stderr
    assert "states (2 scalars)" in r.stdout and "I I2 (line 12)" in r.stdout
    assert "follows from I1.p" in r.stdout


def test_dependent_flow_law_is_a_located_error():
    text = GEAR.replace('I2: {type: I, inertia: "J2"}', 'I2: {type: I, flow: "p / J2"}')
    with pytest.raises(ModelError) as e:
        compile_model(parse_text(text, "g.yaml"))
    assert e.value.coord.line == 12 and "give it an `inertia:` law" in e.value.message


def test_numeric_solve_matches_symbolic(gear):
    """The numeric linear solve emitted for large systems gives the symbolic one's answers."""
    _, m = gear
    c, mn = module(GEAR, "gear_num", symbolic_max=0)
    assert "np.linalg.solve" in c.source
    rng = np.random.default_rng(4)
    x = rng.normal(size=(2, 3, 4))
    np.testing.assert_allclose(mn.rhs(0.7, x), m.rhs(0.7, x), rtol=1e-12)
    np.testing.assert_allclose(mn.jacobian(0.7, x), m.jacobian(0.7, x), rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(mn.rhs(0.7, x[:, 0, 0]), m.rhs(0.7, x[:, 0, 0]), rtol=1e-12)


# ---------------------------------------------------------------------------------------------
# Planar chains of rods with revolute joints: a Lagrangian in the absolute angles.


def lagrange_chain(n, c=None, tau0=0.3, g=9.81):
    """Equations of motion M(q) q'' = h(q, q', t) of the n-rod chain, derived with sympy from
    T - V (rod i: mass m_i, length l_i, centroidal inertia m_i l_i^2 / 12), with joint
    friction c_i on the relative angular velocity and a torque tau0 sin(2t) at the pivot.
    Derived once per set of arguments (the rhs and the run tests ask for the same chains)."""
    c = (0.05,) * n if c is None else tuple(c)
    return _lagrange_chain(n, c, tau0, g)


@cache
def _lagrange_chain(n, c, tau0, g):
    q = sp.symbols(f"q0:{n}", real=True)
    qd = sp.symbols(f"qd0:{n}", real=True)
    t = sp.Symbol("t", real=True)
    x = y = 0
    T = V = 0
    for i in range(n):
        m, L = MASS[i], LENGTH[i]
        xc = x + L / 2 * sp.cos(q[i])
        yc = y + L / 2 * sp.sin(q[i])
        vx = sum(sp.diff(xc, q[j]) * qd[j] for j in range(n))
        vy = sum(sp.diff(yc, q[j]) * qd[j] for j in range(n))
        T += m * (vx ** 2 + vy ** 2) / 2 + m * L ** 2 / 12 * qd[i] ** 2 / 2
        V += m * g * yc
        x += L * sp.cos(q[i])
        y += L * sp.sin(q[i])
    Lg = T - V
    Q = [0] * n
    Q[0] += tau0 * sp.sin(2 * t) - c[0] * qd[0]
    for i in range(1, n):
        rel = qd[i] - qd[i - 1]
        Q[i] += -c[i] * rel
        Q[i - 1] += c[i] * rel
    M = sp.Matrix(n, n, lambda i, j: sp.diff(Lg, qd[i], qd[j]))
    h = sp.Matrix([Q[i] + sp.diff(Lg, q[i]) - sum(sp.diff(Lg, qd[i], q[j]) * qd[j]
                                                   for j in range(n)) for i in range(n)])
    fM = sp.lambdify((q, qd), M, "numpy")
    fh = sp.lambdify((t, q, qd), h, "numpy")
    fE = sp.lambdify((q, qd), T + V, "numpy")

    def f(tt, s):
        qq, vv = s[:n], s[n:]
        acc = np.linalg.solve(np.array(fM(qq, vv), float), np.array(fh(tt, qq, vv), float).ravel())
        return np.concatenate([vv, acc])

    return f, fE


def chain_params(n, c=0.05, tau0=0.3):
    p = {"tau0": tau0}
    for i in range(n):
        p[f"c{i + 1}"] = c
    return p


@pytest.fixture(scope="module")
def chains():
    out = {}
    for n in (2, 3):
        text = (ROOT / "models" / f"{'double_pendulum' if n == 2 else 'three_rod'}_rigid.yaml"
                ).read_text()
        assert text == chain_yaml(n)  # the committed model is the generator's
        out[n] = module(text, f"chain{n}")
    return out


def _angles(m, x, n):
    names = m.STATE_NAMES
    th = np.array([x[names.index(f"rod{i + 1}.th")] for i in range(n)])
    w = np.array([x[names.index(f"rod{i + 1}.Ir.p")] / (MASS[i] * LENGTH[i] ** 2 / 12)
                  for i in range(n)])
    return th, w


@pytest.mark.parametrize("n", [2, 3])
def test_rigid_chain_states_are_the_angles_and_rates(chains, n):
    c, m = chains[n]
    assert sorted(m.STATE_NAMES) == sorted([f"rod{i}.Ir.p" for i in range(1, n + 1)]
                                           + [f"rod{i}.th" for i in range(1, n + 1)])
    assert set(c.causality.derivative) == {f"rod{i}.It" for i in range(1, n + 1)}
    # the MTFs (angle-dependent, 2x1) are never inverted
    for i in range(1, n + 1):
        for pt in "AB":
            el = c.graph.element(f"rod{i}.m{pt}")
            assert c.causality.form(c.graph, el) == "flow forward"


@pytest.mark.parametrize("n", [2, 3])
def test_rigid_chain_rhs_matches_lagrange(chains, n):
    _, m = chains[n]
    f, _ = lagrange_chain(n)
    rng = np.random.default_rng(10 + n)
    for _ in range(5):
        th = rng.uniform(-np.pi, np.pi, n)
        w = rng.normal(size=n)
        t = rng.uniform(0, 5)
        x = np.zeros(len(m.STATE_NAMES))
        for i in range(n):
            x[m.STATE_NAMES.index(f"rod{i + 1}.th")] = th[i]
            x[m.STATE_NAMES.index(f"rod{i + 1}.Ir.p")] = w[i] * MASS[i] * LENGTH[i] ** 2 / 12
        dx = m.rhs(t, x)
        dth, dw = _angles(m, dx, n)
        ref = f(t, np.concatenate([th, w]))
        np.testing.assert_allclose(dth, ref[:n], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(dw, ref[n:], rtol=1e-10, atol=1e-10)
        # analytic Jacobian against central differences
        J = m.jacobian(t, x)
        h = 1e-6
        fd = np.column_stack([(m.rhs(t, x + h * e) - m.rhs(t, x - h * e)) / (2 * h)
                              for e in np.eye(len(x))])
        np.testing.assert_allclose(J, fd, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("n", [2, 3])
def test_rigid_chain_run_matches_lagrange(chains, n):
    """Joint angles within 1e-6 rad over 5 s at tight tolerance (Radau with the analytic
    Jacobian for bgc, DOP853 for the Lagrangian reference)."""
    _, m = chains[n]
    f, _ = lagrange_chain(n)
    t_eval = np.linspace(0, 5, 51)
    _, x, _ = m.simulate((0, 5), t_eval=t_eval, method="Radau", rtol=1e-10, atol=1e-11)
    ref = solve_ivp(f, (0, 5), list(TH0[:n]) + list(W0[:n]), method="DOP853", t_eval=t_eval,
                    rtol=1e-12, atol=1e-12)
    th, w = _angles(m, x, n)
    assert np.abs(th - ref.y[:n]).max() < 1e-6
    assert np.abs(w - ref.y[n:]).max() < 1e-5
    assert np.ptp(ref.y[0]) > 0.3  # it does move


def test_rigid_chain_conserves_energy_without_friction(chains):
    """No friction, no torque: the kinetic energy (from the dependent elements' momenta and
    the rotational ones) plus the potential energy (from the angles) stays constant."""
    n = 3
    _, m = chains[n]
    p = chain_params(n, c=0.0, tau0=0.0)
    t_eval = np.linspace(0, 5, 26)
    _, x, y = m.simulate((0, 5), t_eval=t_eval, p=p, method="DOP853", rtol=1e-11, atol=1e-12)
    th, w = _angles(m, x, n)
    E = np.zeros_like(t_eval)
    height = 0.0
    for i in range(n):
        mi, L = MASS[i], LENGTH[i]
        v = y[f"v{i + 1}"]  # 2-vector velocity of the centre of mass: a dependent flow
        E += mi * (v[0] ** 2 + v[1] ** 2) / 2 + mi * L ** 2 / 12 * w[i] ** 2 / 2
        E += mi * 9.81 * (height + L / 2 * np.sin(th[i]))
        height = height + L * np.sin(th[i])
    _, fE = lagrange_chain(n, c=[0] * n, tau0=0)
    assert abs(E[0] - fE(np.array(TH0[:n]), np.array(W0[:n]))) < 1e-12
    assert np.abs(E - E[0]).max() < 1e-8 * max(1.0, abs(E[0]))
    # p(rod1.It) = m v: the dependent momentum as an output
    np.testing.assert_allclose(y["p1"], MASS[0] * y["v1"], rtol=1e-13)


def test_chain_does_not_depend_on_file_order(chains):
    """The three-rod chain with its elements and bonds shuffled: the same independent set."""
    text = chain_yaml(3)
    lines = text.splitlines()
    a = lines.index("elements:") + 1
    b = lines.index("", a)
    bb = lines.index("bonds:") + 1
    be = lines.index("", bb)
    rng = random.Random(7)
    els, bonds = lines[a:b], lines[bb:be]
    rng.shuffle(els)
    rng.shuffle(bonds)
    shuffled = "\n".join(lines[:a] + els + lines[b:bb] + bonds + lines[be:]) + "\n"
    _, m0 = chains[3]
    c, m = module(shuffled, "chain3s")
    assert sorted(m.STATE_NAMES) == sorted(m0.STATE_NAMES)
    perm = [m0.STATE_NAMES.index(s) for s in m.STATE_NAMES]
    x = np.random.default_rng(5).normal(size=(6, 4))
    np.testing.assert_allclose(m.rhs(0.2, x[perm]), m0.rhs(0.2, x)[perm], rtol=1e-11,
                               atol=1e-12)


@pytest.mark.slow
def test_compliant_chain_tends_to_rigid_as_one_over_stiffness(chains):
    """Stiff C || R joints: the angles' difference to the rigid model falls like 1/k."""
    _, rigid = chains[2]
    t_eval = np.linspace(0, 1, 11)
    _, xr, _ = rigid.simulate((0, 1), t_eval=t_eval, method="Radau", rtol=1e-10, atol=1e-12)
    thr, _ = _angles(rigid, xr, 2)
    errs = []
    # one compile: the joints' stiffness k_j and damping r_j are parameters of the model
    _, mc = module(chain_yaml(2, compliant=True), "cc")
    for k in (1e4, 1e5, 1e6):
        # damping scaled with sqrt(k) keeps the joint modes equally damped
        p = {"k_j": k, "r_j": 2 * np.sqrt(k) * 0.1}
        x0 = mc.initial_state(p)
        _, xc, _ = mc.simulate((0, 1), t_eval=t_eval, x0=x0, p=p, method="Radau", rtol=1e-10,
                               atol=1e-12)
        thc, _ = _angles(mc, xc, 2)
        errs.append(np.abs(thc - thr).max())
    ratios = [errs[i] / errs[i + 1] for i in range(2)]
    assert all(5 < r < 20 for r in ratios), (errs, ratios)
    assert errs[-1] < 1e-4


def test_chain_numeric_solve_matches_symbolic(chains):
    """The three-rod chain with its 3x3 system solved numerically (np.linalg.solve) in the
    generated code: the same derivatives and Jacobian as the symbolic solve."""
    _, m = chains[3]
    c, mn = module(chain_yaml(3), "chain3n", symbolic_max=2)
    assert "_bgc_linsolve(3," in c.source
    x = np.random.default_rng(6).normal(size=(6, 5))
    np.testing.assert_allclose(mn.rhs(0.4, x), m.rhs(0.4, x), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(mn.jacobian(0.4, x), m.jacobian(0.4, x), rtol=1e-9, atol=1e-10)


# ---------------------------------------------------------------------------------------------
# Closed kinematic loops and partly determined multibonds: located diagnostics, and the fix.


def fourbar(compliant_closure: bool) -> str:
    """The three-rod chain with its tip pinned to a second ground point: a planar four-bar."""
    t = chain_yaml(3).replace("name: three_rod_rigid", "name: fourbar")
    if not compliant_closure:
        return t.replace('  tip: {type: Se, effort: "[0, 0]"}  # the free end of the last rod',
                         '  tip: {type: Sf, flow: "[0, 0]"}  # a second pivot closes the loop')
    from planar_chain import COUPLING

    t = t.replace('  tip: {type: Se, effort: "[0, 0]"}  # the free end of the last rod',
                  '  tip: {type: Sf, flow: "[0, 0]"}\n  jc: {type: joint, k: 1.0e+6, r: 200.0}')
    t = t.replace("\nelements:\n  pivot", "\n" + COUPLING + "elements:\n  pivot")
    return t.replace("  - {from: tip, to: rod3.B, n: 2}",
                     "  - {from: tip, to: jc.a, n: 2}\n  - {from: jc.b, to: rod3.B, n: 2}")


def test_closed_kinematic_loop_with_inconsistent_velocities_is_named():
    """A rigid closed loop compiles (issue 24: the closing source becomes a constraint), but
    the chain's initial rates move the tip off the second pivot: a located error at that
    source naming the loop and the velocity residual."""
    text = fourbar(False)
    with pytest.raises(ModelError) as e:
        compile_model(parse_text(text, "fourbar.yaml"))
    msg = e.value.message
    assert msg.startswith("constraint 'tip' closing the kinematic loop through")
    for el in ("tip", "pivot", "rod1.A", "rod3.B"):  # the loop's elements, by instance path
        assert el in msg, msg
    assert "the initial velocities violate it" in msg
    assert e.value.coord.file == "fourbar.yaml" and e.value.coord.line > 0
    line = text.splitlines()[e.value.coord.line - 1]
    assert line.lstrip().startswith("tip:"), line


def test_closed_loop_with_one_compliant_coupling_compiles_and_holds():
    """The suggested fix: rigid joints elsewhere, one C || R where the loop closes. The
    closing joint's deflection stays small (of order force / k) and the rods move."""
    c, m = module(fourbar(True), "fourbar_c")
    assert len(m.STATE_NAMES) == 3 + 3 + 2  # three angles and rates, one 2-D deflection
    # the closing spring at rest (q = 0) in the initial pose: the second ground point is the
    # chain's initial tip; all rods at rest, so the start is on the loop
    names = m.STATE_NAMES
    x0 = m.initial_state()
    for i in range(3):
        x0[names.index(f"rod{i + 1}.Ir.p")] = 0.0
    t_eval = np.linspace(0, 2, 21)
    _, x, _ = m.simulate((0, 2), t_eval=t_eval, x0=x0, method="Radau", rtol=1e-8, atol=1e-10)
    q = x[[k for k, s in enumerate(names) if s.startswith("jc.C.q")]]
    th, _ = _angles(m, x, 3)
    assert np.abs(q).max() < 1e-3  # about (gravity + torque load) / k
    assert np.ptp(th, axis=1).max() > 1e-2  # the four-bar moves (driven by the torque)


def test_partly_determined_multibond_is_named():
    text = """\
bgc: 1
name: lever
elements:
  pivot: {type: Sf, flow: "[0, 0]"}
  A: {type: "1"}
  s: {type: "0"}
  vC: {type: "1"}
  mass: {type: I, inertia: "2.0"}
  mt: {type: MTF, modulus: "[0.5, -0.2]"}
  w: {type: "1"}
  fr: {type: R, resistance: "0.1"}
bonds:
  - {from: pivot, to: A, n: 2}
  - {from: s, to: A, n: 2}
  - {from: vC, to: s, n: 2}
  - {from: vC, to: mass, n: 2}
  - {from: w, to: mt}
  - {from: mt, to: s, n: 2}
  - [w, fr]
"""
    with pytest.raises(ModelError) as e:
        compile_model(parse_text(text, "lever.yaml"))
    assert e.value.coord.line == 9
    assert "multibond 'b6' (mt -> s, n=2) is only partly determined" in e.value.message


# ---------------------------------------------------------------------------------------------
# Nonlinear algebraic loops: Newton's method in the generated code.

NONLINEAR = """\
bgc: 1
name: nl_loop
elements:
  source:   {type: Se, effort: "10"}
  j_in:     {type: "1"}
  series_R: {type: R, effort: "1000 * f + f**3"}
  node:     {type: "0"}
  shunt_R:  {type: R, resistance: "2000"}
  j_out:    {type: "1"}
  load_R:   {type: R, resistance: "500"}
  cap:      {type: C, compliance: "0.001"}
bonds: [[source, j_in], [j_in, series_R], [j_in, node], [node, shunt_R], [node, j_out],
        [j_out, load_R], [j_out, cap]]
outputs: {vnode: "e(node)"}
"""


def test_nonlinear_loop_solved_by_newton():
    """The node voltage of a source - cubic resistor - (shunt || load + C) circuit, against
    scipy's brentq on the circuit's one-unknown equation."""
    from scipy.optimize import brentq

    c, m = module(NONLINEAR, "nl")
    assert "Newton" in c.source and any("Newton" in lp for lp in c.equations.loops)
    qs = np.array([0.0, 0.003, -0.01, 0.008])
    dq = m.rhs(0.0, qs[None])[0]
    y = m.outputs(0.0, qs[None])
    for k, q in enumerate(qs):
        vc = q / 0.001

        def res(f):
            en = 10 - (1000 * f + f ** 3)
            return f - (en / 2000 + (en - vc) / 500)
        f = brentq(res, -1, 1, xtol=1e-15)
        en = 10 - (1000 * f + f ** 3)
        assert abs(dq[k] - (en - vc) / 500) < 1e-12
        assert abs(y["vnode"][k] - en) < 1e-9
    # the Jacobian through the solution (implicit function theorem) against differences
    x = np.array([0.002])
    h = 1e-7
    fd = (m.rhs(0.0, x + h) - m.rhs(0.0, x - h)) / (2 * h)
    np.testing.assert_allclose(m.jacobian(0.0, x)[0, 0], fd[0], rtol=1e-6)
    # a run against the same equation integrated by scipy with brentq inside
    def ref(t, q):
        vc = q[0] / 0.001
        f = brentq(lambda f: f - ((10 - 1000 * f - f ** 3) / 2000
                                   + (10 - 1000 * f - f ** 3 - vc) / 500), -1, 1, xtol=1e-15)
        return [((10 - 1000 * f - f ** 3) - vc) / 500]
    t_eval = np.linspace(0, 2, 11)
    _, xs, _ = m.simulate((0, 2), t_eval=t_eval, method="Radau", rtol=1e-10, atol=1e-13)
    r = solve_ivp(ref, (0, 2), [0.0], t_eval=t_eval, rtol=1e-10, atol=1e-13)
    np.testing.assert_allclose(xs[0], r.y[0], rtol=1e-7, atol=1e-11)
    # strict: today's error
    with pytest.raises(ModelError, match="is nonlinear"):
        compile_model(parse_text(NONLINEAR, "nl.yaml"), strict_causality=True)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_newton_failure_is_located():
    text = NONLINEAR.replace('effort: "1000 * f + f**3"', 'effort: "1 / f"')
    _, m = module(text, "nlbad")
    with pytest.raises(m.SimulationError) as e:
        m.rhs(0.0, np.array([0.0]))
    msg = str(e.value)
    assert msg.startswith("nlbad.yaml:5:3: algebraic loop through") and "series_R" in msg
    assert "did not converge" in msg


def test_capacitors_in_parallel_dependent_c():
    """Two capacitors on one node: C2's charge follows from C1's (q2 = c2 e), its current is
    dq2/dt. Reduced: (c1 + c2) v' = (V - v) / R, against the closed form."""
    text = """\
bgc: 1
name: two_caps
parameters: {V: 5.0, R: 100.0, c1: 1.0e-3, c2: 3.0e-3}
elements:
  src: {type: Se, effort: "V"}
  j: {type: "1"}
  r: {type: R, resistance: "R"}
  node: {type: "0"}
  C1: {type: C, compliance: "c1"}
  C2: {type: C, compliance: "c2"}
bonds: [[src, j], [j, r], [j, node], [node, C1], [node, C2]]
outputs: {i2: "f(C2)", q2: "q(C2)", v: "e(node)"}
"""
    c, m = module(text, "two_caps")
    assert m.STATE_NAMES == ("C1.q",) and c.causality.derivative == ("C2",)
    V, R, c1, c2 = 5.0, 100.0, 1e-3, 3e-3
    t_eval = np.linspace(0, 1, 11)
    _, x, y = m.simulate((0, 1), t_eval=t_eval, method="Radau", rtol=1e-10, atol=1e-14)
    tau = R * (c1 + c2)
    v = V * (1 - np.exp(-t_eval / tau))
    np.testing.assert_allclose(y["v"], v, atol=1e-8)
    np.testing.assert_allclose(x[0], c1 * v, atol=1e-11)
    np.testing.assert_allclose(y["q2"], c2 * v, atol=1e-11)
    np.testing.assert_allclose(y["i2"], c2 * V / tau * np.exp(-t_eval / tau), rtol=1e-7,
                               atol=1e-11)


def test_strict_error_names_the_instance_path(chains):
    """The dependent element inside a shared component is named by its instance path, and
    located at its line in the component."""
    c, _ = chains[2]
    with pytest.raises(ModelError) as e:
        compile_model(parse_text(chain_yaml(2), "dp.yaml"), strict_causality=True)
    assert "I 'rod1.It' is forced into derivative causality by I 'rod1.Ir'" in e.value.message
    assert e.value.coord.line == c.graph.element("rod1.It").coord.line


def test_scene_on_a_rigid_model_specialises():
    """A scene that folds parameters and slices outputs works on a model with derivative
    causality: the rigid double pendulum's swing against the Lagrangian equations."""
    from bgc.run.runner import run_scene

    res = run_scene(ROOT / "models" / "scenes" / "double_pendulum_swing.yaml")
    assert "c1" not in res.module.PARAM_DEFAULTS  # folded
    f, _ = lagrange_chain(2, c=[0.02, 0.02])
    ref = solve_ivp(f, (0, 10), list(TH0[:2]) + list(W0[:2]), method="DOP853",
                    t_eval=res.t, rtol=1e-12, atol=1e-12)
    err = max(np.abs(res.y["th1"] - ref.y[0]).max(), np.abs(res.y["th2"] - ref.y[1]).max())
    assert err < 1e-6, err
