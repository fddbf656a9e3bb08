"""Self-checks of the numpy reference ``mech3r2s`` against closed forms from the spec
(/work/shared/spec/3r2s.md).  Fast tests only, except those marked ``slow``."""

import numpy as np
import pytest

from . import mech3r2s as m

RNG = np.random.default_rng(20240611)


# --- initial pose ("Bodies, joints and points", "Body frames") -------------------------
def test_initial_points_match_spec():
    np.testing.assert_allclose(m.Q1, [0, 0, 0])
    np.testing.assert_allclose(m.P1, [0.07, 0, 0], atol=1e-12)
    np.testing.assert_allclose(m.P2, [0.12196152, 0, 0.03], atol=1e-8)
    np.testing.assert_allclose(m.P3, [0.14696152, 0, -0.01330127], atol=1e-8)
    np.testing.assert_allclose(m.P4, [0.14696152, 0, -0.06330127], atol=1e-8)
    np.testing.assert_allclose(m.RC0, 0.5 * (m.PROX0 + m.DIST0))


def test_initial_frames_match_spec():
    c, s = np.cos(np.pi / 6), np.sin(np.pi / 6)
    table = [  # x, y, z of links 1..4
        ([1, 0, 0], [0, 1, 0], [0, 0, 1]),
        ([c, 0, s], [-s, 0, c], [0, -1, 0]),
        ([s, 0, -c], [c, 0, s], [0, -1, 0]),
        ([0, 0, -1], [1, 0, 0], [0, -1, 0]),
    ]
    for R, cols in zip(m.R0, table):
        np.testing.assert_allclose(R, np.column_stack(cols), atol=1e-15)
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-15)
        assert np.isclose(np.linalg.det(R), 1.0)
    # x_i runs from the proximal to the distal point
    for i in range(4):
        np.testing.assert_allclose(m.DIST0[i] - m.PROX0[i], m.L[i] * m.R0[i][:, 0], atol=1e-15)


def test_inertia_solid_rod():
    np.testing.assert_allclose(m.IB[0], [0.7 * 1e-4 / 2, 0.7 * (3e-4 + 0.0049) / 12,
                                         0.7 * (3e-4 + 0.0049) / 12])


def test_initial_outputs():
    y0 = m.initial_state()
    out = m.outputs(0.0, y0[:, None], "circle")
    got = [out[f"theta{i}"][0] for i in range(1, 5)]
    np.testing.assert_allclose(got, [0, np.pi / 6, -np.pi / 2, -np.pi / 6], atol=1e-14)
    np.testing.assert_allclose(out["p3"][:, 0], m.P3, atol=1e-15)
    np.testing.assert_allclose(out["energy"][0], -0.0210506, atol=5e-8)
    np.testing.assert_allclose(m.energy(y0, 0.0, "circle")["total"], -0.02105054936, rtol=1e-9)


# --- inverse kinematics --------------------------------------------------------------
def _random_angles(n):
    th1 = RNG.uniform(-1.0, 1.0, n)
    th2 = RNG.uniform(-0.5, 1.5, n)
    th3 = RNG.uniform(-np.pi + 0.05, -0.05, n)  # the elbow branch of the initial pose
    return th1, th2, th3


def test_ik_initial_pose():
    np.testing.assert_allclose(m.ik_3r(m.P3), [0, np.pi / 6, -np.pi / 2, -np.pi / 6], atol=1e-14)
    np.testing.assert_allclose(m.ik_2r(m.P3, m.R0[0], m.RC0[0]), [np.pi / 6, -np.pi / 2],
                               atol=1e-14)


def test_fk_rigid_initial_pose():
    fk = m.fk_rigid(m.THETA0[:3])
    for key, i in (("R1", 0), ("R2", 1), ("R3", 2)):
        np.testing.assert_allclose(fk[key][:, :, 0], m.R0[i], atol=1e-15)
    np.testing.assert_allclose(fk["P3"][:, 0], m.P3, atol=1e-15)


def test_ik_3r_inverts_fk():
    th1, th2, th3 = _random_angles(500)
    fk = m.fk_rigid((th1, th2, th3))
    g1, g2, g3, g4 = m.ik_3r(fk["P3"])
    np.testing.assert_allclose(g1, th1, atol=1e-12)
    np.testing.assert_allclose(g2, th2, atol=1e-10)
    np.testing.assert_allclose(g3, th3, atol=1e-10)
    # theta4: angle from x3 to x4 = (P4 - P3)/|P4 - P3| about a3 = z3 (spec "Outputs")
    x4 = m.P4[:, None] - fk["P3"]
    x4 /= np.linalg.norm(x4, axis=0)
    R3 = fk["R3"]
    want = np.arctan2(np.sum(x4 * R3[:, 1], axis=0), np.sum(x4 * R3[:, 0], axis=0))
    np.testing.assert_allclose(g4, want, atol=1e-12)


def _random_rotation():
    q = RNG.normal(size=4)
    a, b, c, d = q / np.linalg.norm(q)
    return np.array([[a*a + b*b - c*c - d*d, 2*(b*c - a*d), 2*(b*d + a*c)],
                     [2*(b*c + a*d), a*a - b*b + c*c - d*d, 2*(c*d - a*b)],
                     [2*(b*d - a*c), 2*(c*d + a*b), a*a - b*b - c*c + d*d]])


@pytest.mark.parametrize("trial", range(10))
def test_ik_2r_inverts_fk_from_any_link1_pose(trial):
    R1 = _random_rotation()
    rC1 = RNG.normal(size=3) * 0.05
    _, th2, th3 = _random_angles(50)
    x1, a2 = R1[:, 0], -R1[:, 1]
    e = np.cross(a2, x1)
    p1 = rC1 + 0.5 * m.L[0] * x1
    x2 = np.outer(x1, np.cos(th2)) + np.outer(e, np.sin(th2))
    x3 = np.outer(x1, np.cos(th2 + th3)) + np.outer(e, np.sin(th2 + th3))
    p3 = p1[:, None] + m.L[1] * x2 + m.L[2] * x3
    g2, g3 = m.ik_2r(p3, R1, rC1)
    np.testing.assert_allclose(g2, th2, atol=1e-10)
    np.testing.assert_allclose(g3, th3, atol=1e-10)
    # spec's angle definitions: signed angles about a2
    np.testing.assert_allclose(g2, m.signed_angle(np.tile(x1[:, None], (1, 50)), x2,
                                                  np.tile(a2[:, None], (1, 50))), atol=1e-10)
    # an offset along a2 (off the plane of motion) is projected away
    g2b, g3b = m.ik_2r(p3 + 1e-4 * a2[:, None], np.repeat(R1[:, :, None], 50, axis=2),
                       np.repeat(rC1[:, None], 50, axis=1))
    np.testing.assert_allclose(g2b, th2, atol=1e-10)
    np.testing.assert_allclose(g3b, th3, atol=1e-10)


# --- desired paths ("Scenes", "The drive") ---------------------------------------------
@pytest.mark.parametrize("scene", m.SCENES)
def test_p_desired_is_integral_of_v_desired(scene):
    b = m.BREAKS[scene]
    for seg in range(len(b) - 1):
        t = np.linspace(b[seg], b[seg + 1], 20001)
        v = m.v_desired(scene, t, segment=seg)
        p = m.p_desired(scene, t, segment=seg)
        dt = np.diff(t)
        integral = np.concatenate([np.zeros((3, 1)),
                                   np.cumsum(0.5 * (v[:, 1:] + v[:, :-1]) * dt, axis=1)], axis=1)
        np.testing.assert_allclose(p - p[:, :1], integral, atol=1e-9)
    # p_d is continuous across the jumps of v_d and starts at P3(0)
    np.testing.assert_allclose(m.p_desired(scene, 0.0), m.P3, atol=1e-15)
    for k in range(1, len(b) - 1):
        np.testing.assert_allclose(m.p_desired(scene, b[k], segment=k - 1),
                                   m.p_desired(scene, b[k], segment=k), atol=1e-15)
    # vectorised and scalar forms agree; time on the last axis
    t = np.linspace(0, m.T_END[scene], 777)
    assert m.v_desired(scene, t).shape == (3, 777)
    vs = np.array([m.v_desired_scalar(scene, tt) for tt in t]).T
    np.testing.assert_allclose(m.v_desired(scene, t), vs, atol=1e-15)


def test_path_key_points():
    r = 0.01
    off = lambda sc, t: (m.p_desired(sc, t) - m.P3)[:2]
    np.testing.assert_allclose(off("circle", 2.0), [r, 0], atol=1e-15)
    np.testing.assert_allclose(off("circle", 4.0), [-r, 0], atol=1e-15)
    np.testing.assert_allclose(off("circle", 6.0), [r, 0], atol=1e-15)
    np.testing.assert_allclose(m.v_desired("circle", 0.0)[:2], [r / 2, 0])  # t >= 0 side
    np.testing.assert_allclose(m.v_desired("circle", 2.0)[:2], [0, r * np.pi / 2])  # t >= 2
    np.testing.assert_allclose(off("figure8", 0.5), [0.008, 0], atol=1e-15)
    np.testing.assert_allclose(off("figure8", 1.5), [-0.016, 0], atol=1e-15)
    np.testing.assert_allclose(m.v_desired("figure8", 0.0)[:2], [0, -2 * np.pi * 0.004],
                               atol=1e-15)
    np.testing.assert_allclose(m.v_desired("figure8", 1.0)[:2], [0, -2 * np.pi * 0.008],
                               atol=1e-15)
    gates = [(0, 0), (0, .008), (.01, .008), (0, .008), (-.01, .008), (0, .008), (0, -.008),
             (.01, -.008), (0, -.008), (-.01, -.008), (0, -.008), (0, 0)]
    tk = [0, 0.5, 1.5, 2.5, 3.5, 4.5, 5.5, 6.5, 7.5, 8.5, 9.5, 10]
    for t, g in zip(tk, gates):
        np.testing.assert_allclose(off("gearshift", t), g, atol=1e-15)
        np.testing.assert_allclose(m.v_desired("gearshift", t), 0, atol=1e-15)
    for sc in m.SCENES:  # horizontal plane through P3(0)
        t = np.linspace(0, m.T_END[sc], 101)
        np.testing.assert_allclose(m.p_desired(sc, t)[2], m.P3[2], atol=1e-15)


def test_p_projected_on_sphere():
    pd = m.p_desired("circle", np.linspace(0, 6, 50))
    pp = m.p_projected(pd)
    np.testing.assert_allclose(np.linalg.norm(pp - m.P4[:, None], axis=0), m.L[3], atol=1e-15)


# --- the compliant model ("Couplings", "The initial state") -----------------------------
def _random_state(scale=1e-3, rng=None):
    y = m.initial_state()
    return y + scale * (RNG if rng is None else rng).normal(size=y.size)


def test_rhs_at_rest_is_gravity_only():
    dy = m.rhs(0.0, m.initial_state(), "gearshift")  # v_d(0) = 0 for the gearshift
    expect = np.zeros(m.NSTATE)
    for i in range(4):
        expect[m.body_slices(i)[0]] = m.M[i] * m.G
    np.testing.assert_allclose(dy, expect, atol=1e-15)


def test_rhs_vectorised_matches_joint_by_joint():
    Y = np.stack([_random_state() for _ in range(6)], axis=1)
    for scene, t in (("circle", 0.7), ("figure8", 1.3), ("gearshift", 3.1)):
        a = m.rhs(t, Y, scene)
        b = m.rhs_loop(t, Y, scene)
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(m.rhs(t, Y[:, 2], scene), a[:, 2], rtol=1e-14, atol=1e-12)


@pytest.mark.parametrize("trial", range(5))
def test_energy_balance(trial):
    """dE/dt along the flow = drive power - dissipation (exact for any state).

    dE/dt by the fourth-order central difference at eps = 1e-5 along f: over 40 random states
    its relative error was at most 2e-11, where the second-order one at eps = 1e-7 reached
    1.2e-6 (rounding), too close to a 1e-6 tolerance. Each trial draws its own state, so the
    test does not depend on which tests ran before it in the worker."""
    scene, t = "circle", 2.5
    y = _random_state(rng=np.random.default_rng(7000 + trial))
    f = m.rhs(t, y, scene)
    eps = 1e-5
    E = [m.energy(y + k * eps * f, t, scene)["total"] for k in (-2, -1, 1, 2)]
    dEdt = (E[0] - 8 * E[1] + 8 * E[2] - E[3]) / (12 * eps)
    diss = 0.0
    for name, s in m.TRANS.items():
        diss += m.R_T[name] * f[s] @ f[s]
    for name, s in m.ROT.items():
        diss += m.R_R[name] * f[s] @ f[s]
    sd = m.TRANS["drive"]
    power_in = (m.K_T["drive"] * y[sd] + m.R_T["drive"] * f[sd]) @ m.v_desired(scene, t)
    np.testing.assert_allclose(dEdt, power_in - diss, rtol=1e-8)


@pytest.mark.slow
def test_settling_transient():
    """Spec "The initial state": theta2 rises ~0.01 rad within 50 ms, link 1 tilts
    ~5.5e-3 rad; the translational states equal the separations of the joined points."""
    t = np.linspace(0, 0.05, 51)
    r = m.simulate("gearshift", t_eval=t, rtol=1e-6, atol=1e-8, t_end=0.05)
    dth2 = r["theta2"] - np.pi / 6
    assert 0.006 < dth2.max() < 0.012
    x1z = r["y"][m.body_slices(0)[2]][6, -1]  # R1[2, 0] = x1 . Z0
    assert -6e-3 < x1z < -5e-3
    _, p, h, R, rC = m.unpack(r["y"])
    tip = lambda i, e: rC[i] + e * 0.5 * m.L[i] * R[i][:, 0]
    np.testing.assert_allclose(r["y"][m.TRANS["J2"]], tip(0, 1) - tip(1, -1), atol=1e-9)
    np.testing.assert_allclose(r["y"][m.TRANS["J5"]], tip(3, 1) - m.P4[:, None], atol=1e-9)
    np.testing.assert_allclose(r["y"][m.TRANS["drive"]], r["p3_desired"] - r["p3"], atol=1e-9)
