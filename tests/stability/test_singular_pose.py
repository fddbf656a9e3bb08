"""Near-singular pose: the 3R2S driven out to the edge of its workspace and back
(models/scenes/3r2s_stretch.yaml): link 4 tilts outward about P4 by up to 0.63 rad, P3 runs
out on the sphere about P4 until links 2 and 3 nearly line up (theta3 -> -0.25 rad,
|P3| -> 0.178 m of l1 + l2 + l3 = 0.18 m), holds, and returns.

Near theta3 = 0 the arm's Jacobian is nearly singular: small tip motions need large joint
motions, and the elbow could snap to its other branch. Checked against the independent
reference (tests/reference/mech3r2s.py: closed-form paths and inverse kinematics):
* everything finite and bounded: joint gaps below 1e-6 m, the tip within 1 mm of the path;
* the pose does get near-singular, and the elbow stays on its branch (theta3 < 0);
* the angles are continuous: no change between 5 ms samples above 3 times the largest
  change of the rigid arm's closed-form inverse kinematics along the same path;
* the angles are the closed-form 2R inverse kinematics of the tip from link 1's actual pose;
* the power balance holds.
A second run tilts to 0.66 rad, beyond the compliant arm's reach: the elbow snaps through the
singular pose (theta3 crosses 0) and the arm comes back elbow up, on the mirror branch. The
solution stays bounded and continuous through it.
"""
from __future__ import annotations

import numpy as np
import pytest
from stability_helpers import SCENES, link1_pose, ref, scene_module, scene_run

ANGLES = ("theta1", "theta2", "theta3", "theta4")
REACH = float(np.sum(ref.L[:3]))  # l1 + l2 + l3 = 0.18 m


def check_bounded(r):
    assert r.t[-1] == 6.0 and np.all(np.isfinite(r.x))
    assert all(np.all(np.isfinite(v)) for v in r.y.values())
    assert np.max(r.y["joint_gap"]) < 2e-6
    E = r.y["energy"]
    balance = E - E[0] - (r.y["work_drive"] - r.y["dissipated"])
    assert np.max(np.abs(balance)) < 1e-5 * (np.max(E) - np.min(E))


@pytest.fixture(scope="module")
def stretch():
    scene, mod = scene_module(SCENES / "3r2s_stretch.yaml")
    return scene, mod, scene_run(scene, mod)


@pytest.mark.slow
def test_bounded_and_near_singular(stretch):
    scene, mod, r = stretch
    assert sorted(scene.breakpoints) == [2.0, 3.0, 5.0]
    check_bounded(r)
    assert np.max(r.y["joint_gap"]) < 1e-6
    # the desired path (the integral of the scene's v_d) is the closed form: a great circle
    # on the sphere of radius l4 about P4 (solver error of the state p_d: ~1e-6 m)
    t = r.t
    phi = np.select([t < 2, t < 3, t < 5], [0.315 * t, 0.63, 0.63 - 0.315 * (t - 3)], 0.0)
    p_d = ref.P4[:, None] + ref.L[3] * np.array([np.sin(phi), 0 * phi, np.cos(phi)])
    np.testing.assert_allclose(r.y["p3_desired"], p_d, rtol=0, atol=2e-6)
    assert np.max(np.linalg.norm(r.y["p3"] - r.y["p3_desired"], axis=0)) < 1e-3
    # near-singular: theta3 within 0.3 rad of the stretched arm, |P3| at 98.5 % of the reach
    th3 = r.y["theta3"]
    assert -0.3 < np.max(th3) < 0.0
    assert np.max(np.linalg.norm(r.y["p3"], axis=0)) > 0.985 * REACH
    # back where it started: the angles are the initial ones up to the settling under
    # gravity (theta2 rises by about 0.01 rad, spec "The initial state")
    for a in ANGLES:
        assert abs(r.y[a][-1] - r.y[a][0]) < 0.02, a


@pytest.mark.slow
def test_angles_continuous_and_consistent_with_the_tip(stretch):
    _, mod, r = stretch
    y = r.y
    rigid = ref.ik_3r(y["p3_projected"])  # the rigid arm along the same path
    for k, a in enumerate(ANGLES):
        step = np.max(np.abs(np.diff(y[a])))
        assert step <= 3.0 * np.max(np.abs(np.diff(rigid[k]))) + 1e-9, a
    # 2R inverse kinematics of p3 from link 1's actual (compliant) pose
    R1, rC1 = link1_pose(mod, r.x)
    th2, th3 = ref.ik_2r(y["p3"], R1, rC1)
    assert np.max(np.abs(th2 - y["theta2"])) < 2e-4
    assert np.max(np.abs(th3 - y["theta3"])) < 2e-4


@pytest.mark.slow
def test_snap_through_the_singular_pose(tmp_path):
    """Tilting to 0.66 rad (beyond the compliant arm's reach): the elbow passes theta3 = 0
    and the arm returns elbow up. Measured: largest change between 5 ms samples 0.075 rad
    (the snap, ~15 rad/s); a wrap of an angle at +-pi or a numerical blow-up would jump by
    more than 1 rad."""
    text = (SCENES / "3r2s_stretch.yaml").read_text(encoding="utf-8")
    head, vd = text.split("\ninputs:\n")
    vd, tail = vd.split("\nbreakpoints:")
    assert vd.count("0.315") == 9 and vd.count("0.63 - ") == 2  # 8 in v_d, 1 comment
    vd = vd.replace("0.315", "0.33").replace("0.63 - ", "0.66 - ")
    head = head.replace("model: ../3r2s.yaml", f"model: {SCENES.parent / '3r2s.yaml'}")
    text = f"{head}\ninputs:\n{vd}\nbreakpoints:{tail}"
    path = tmp_path / "3r2s_snap.yaml"
    path.write_text(text, encoding="utf-8")
    scene, mod = scene_module(path)
    r = scene_run(scene, mod)
    check_bounded(r)
    th3 = r.y["theta3"]
    assert th3[0] < -1.5 and np.any(th3 > 0.0)  # from elbow down through theta3 = 0
    for a in ANGLES:
        assert np.max(np.abs(np.diff(r.y[a]))) < 0.25, a
    # back at the start point, elbow up: the mirror image of the 2R solution there
    R1, rC1 = link1_pose(mod, r.x[:, -1:])
    _, th3_down = ref.ik_2r(r.y["p3"][:, -1:], R1, rC1)
    assert th3[-1] == pytest.approx(-th3_down[0], abs=1e-3)
    assert th3[-1] > 1.5
