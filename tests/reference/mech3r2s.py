"""Independent numpy reference for the compliant 3R2S mechanism.

Everything here follows ``/work/shared/spec/3r2s.md`` (the "spec"); section names in the
docstrings refer to it.  Nothing is imported from ``bgc``: this module is meant to check the
compiler's generated code, so it is written by hand from the spec alone.

Contents
--------
* constants: lengths, masses, body inertias, coupling table, gravity    ("Bodies", "Inertia",
  "Couplings (Table 2)")
* the initial pose: ``R0[i]``, ``RC0[i]`` and the points Q1, P1..P4      ("Bodies", "Body frames")
* desired paths ``v_desired`` / ``p_desired`` for the three scenes      ("Scenes", "The drive")
* closed-form inverse kinematics ``ik_2r`` and ``ik_3r``              ("What a good result looks like")
* forward kinematics of the rigid arm ``fk_rigid`` (used by the self-check tests)
* the compliant model ``rhs`` / ``simulate`` and the outputs            ("Couplings", "Outputs")

Conventions of the hand-written model
-------------------------------------
State vector ``y`` (length ``NSTATE`` = 96), all vectors in the inertial frame {0}:

=================  =====  ============================================================
slice              size   meaning
=================  =====  ============================================================
body i (i=0..3)    18     at ``18*i``: CM momentum p (3), angular momentum about the CM
                          h (3), rotation matrix R (9, row-major, columns x_i y_i z_i),
                          CM position rC (3)
``TRANS``          6 x 3  translational coupling states of J1, J2, J3, J4, J5, drive
``ROT``            3 x 2  rotational coupling states of J1, J2, J3
=================  =====  ============================================================

A translational coupling joins point a of body A to the coincident point b of body B
(either may be the ground).  Its state d obeys  d' = v_a - v_b,  and the force
F = k d + r d'  acts on B at b, -F on A at a.  Because d(0) = 0 and the points start
coincident, d = r_a - r_b exactly (the spring energy is k|d|^2/2).  For the drive,
"A" is the flow source: d' = v_d(t) - v_P3, so d = p_d(t) - p3 (spec, "The drive").

A rotational coupling of a revolute joint (proximal body A, distal body B) has the state
s (2) with  s' = P R_B^T (w_B - w_A),  P = eye(3)[:2]  (spec, "Couplings"); the torque
T = R_B P^T (K s + Rr s') acts on A and -T on B.  The joint axis is z_B (column 3 of R_B),
so the coupling is free about the axis.

Body dynamics: p' = sum F + m g, h' = sum tau + sum (r_point - rC) x F_point,
w = R I_b^-1 R^T h, R' = [w x] R, rC' = p / m.
"""

from __future__ import annotations

import math
import time

import numpy as np
from scipy.integrate import solve_ivp

# ---------------------------------------------------------------------------------------
# Constants (spec: "Frames and units", "Bodies, joints and points", "Inertia", Table 2)
# ---------------------------------------------------------------------------------------
G = np.array([0.0, 0.0, -9.81])  #: gravity [m/s^2]
L = np.array([0.07, 0.06, 0.05, 0.05])  #: link lengths l1..l4 [m]
M = np.array([0.7, 0.6, 0.5, 0.4])  #: link masses m1..m4 [kg]
RHO = 0.01  #: rod radius [m] (diameter 0.02 m)

#: principal inertias about the CM in the body frame, one row per link: (Ixx, Iyy, Izz)
IB = np.stack([M * RHO**2 / 2, M * (3 * RHO**2 + L**2) / 12, M * (3 * RHO**2 + L**2) / 12], axis=1)

#: translational couplings: (name, k [N/m], r [N s/m])
K_T = {"J1": 1e8, "J2": 1e8, "J3": 1e8, "J4": 1e8, "J5": 1e8, "drive": 1e5}
R_T = {"J1": 50.0, "J2": 50.0, "J3": 50.0, "J4": 50.0, "J5": 5.0, "drive": 5.0}
#: rotational couplings of the revolute joints (kx = ky, Rx = Ry)
K_R = {"J1": 100.0, "J2": 100.0, "J3": 100.0}
R_R = {"J1": 1.0, "J2": 1.0, "J3": 1.0}

#: Table 1 initial relative angles
THETA0 = np.array([0.0, np.pi / 6, -np.pi / 2, -np.pi / 6])


def _d(phi):
    """Unit vector d(phi) = (cos phi, 0, sin phi) of the spec's initial-pose construction."""
    return np.array([np.cos(phi), 0.0, np.sin(phi)])


# ---------------------------------------------------------------------------------------
# Initial pose (spec: "Bodies, joints and points", "Body frames")
# ---------------------------------------------------------------------------------------
Q1 = np.zeros(3)
P1 = L[0] * _d(THETA0[0])
P2 = P1 + L[1] * _d(THETA0[0] + THETA0[1])
P3 = P2 + L[2] * _d(THETA0[0] + THETA0[1] + THETA0[2])
P4 = P3 + L[3] * _d(THETA0[0] + THETA0[1] + THETA0[2] + THETA0[3])

#: proximal and distal points of each link at t = 0
PROX0 = np.array([Q1, P1, P2, P3])
DIST0 = np.array([P1, P2, P3, P4])
#: CM positions rC_i(0) (mid-length)
RC0 = 0.5 * (PROX0 + DIST0)


def _frame(x, z):
    """Rotation matrix [x y z] with y = z x x (spec, "Body frames")."""
    return np.column_stack([x, np.cross(z, x), z])


_A_Y = np.array([0.0, -1.0, 0.0])  # a2 = a3 at t = 0
#: R_i(0), columns x_i, y_i, z_i; z4 = a3 at t = 0
R0 = np.array([
    _frame(np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])),
    _frame((P2 - P1) / L[1], _A_Y),
    _frame((P3 - P2) / L[2], _A_Y),
    _frame((P4 - P3) / L[3], _A_Y),
])

# ---------------------------------------------------------------------------------------
# Desired paths (spec: "Scenes", "The drive")
# ---------------------------------------------------------------------------------------
SCENES = ("circle", "figure8", "gearshift")
#: end time of each scene [s]
T_END = {"circle": 6.0, "figure8": 2.0, "gearshift": 10.0}

_CIRCLE_R = 0.01
_CIRCLE_W = 2 * np.pi / 4
_F8_A = 0.004
_F8_B = 0.008
_GS_T = np.array([0, 0.5, 1.5, 2.5, 3.5, 4.5, 5.5, 6.5, 7.5, 8.5, 9.5, 10.0])
_GS_PTS = {
    "N": (0.0, 0.0), "G12": (0.0, 0.008), "1st": (0.01, 0.008), "2nd": (-0.01, 0.008),
    "G34": (0.0, -0.008), "3rd": (0.01, -0.008), "4th": (-0.01, -0.008),
}
_GS_SEQ = ["N", "G12", "1st", "G12", "2nd", "G12", "G34", "3rd", "G34", "4th", "G34", "N"]
_GS_XY = np.array([_GS_PTS[n] for n in _GS_SEQ])  # (12, 2)

#: segment boundaries of each scene: v_d is smooth inside a segment
BREAKS = {
    "circle": np.array([0.0, 2.0, 6.0]),
    "figure8": np.array([0.0, 1.0, 2.0]),
    "gearshift": _GS_T.copy(),
}


def segment_index(scene, t):
    """Index of the path segment that holds time t (array).

    At a boundary the later segment is chosen (spec: "one-sided values"; the brief asks for
    the value for t >= jump instant).  Times before 0 / after the end map to the first / last
    segment, whose formula is then extended (gearshift: clamped, i.e. at rest).
    """
    b = BREAKS[scene]
    return np.clip(np.searchsorted(b, np.asarray(t, float), side="right") - 1, 0, len(b) - 2)


def _offsets(scene, t, seg):
    """Planar offsets (dx, dy) and their rates (vx, vy) from P3(0), each of shape t.shape."""
    t = np.asarray(t, float)
    z = np.zeros_like(t)
    if scene == "circle":
        r, w = _CIRCLE_R, _CIRCLE_W
        phi = w * (t - 2.0)
        line = seg == 0
        dx = np.where(line, r * t / 2.0, r * np.cos(phi))
        dy = np.where(line, z, r * np.sin(phi))
        vx = np.where(line, r / 2.0 + z, -r * w * np.sin(phi))
        vy = np.where(line, z, r * w * np.cos(phi))
    elif scene == "figure8":
        a, b = _F8_A, _F8_B
        small = seg == 0
        phi = np.where(small, np.pi + 2 * np.pi * t, -2 * np.pi * (t - 1.0))
        dphi = np.where(small, 2 * np.pi, -2 * np.pi)
        rad = np.where(small, a, b)
        cx = np.where(small, a, -b)
        dx = cx + rad * np.cos(phi)
        dy = rad * np.sin(phi)
        vx = -rad * dphi * np.sin(phi)
        vy = rad * dphi * np.cos(phi)
    elif scene == "gearshift":
        t0, t1 = _GS_T[seg], _GS_T[seg + 1]
        T = t1 - t0
        tau = np.clip((t - t0) / T, 0.0, 1.0)
        s = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
        ds = (30 * tau**2 - 60 * tau**3 + 30 * tau**4) / T
        A, B = _GS_XY[seg], _GS_XY[seg + 1]
        dx = A[..., 0] + (B[..., 0] - A[..., 0]) * s
        dy = A[..., 1] + (B[..., 1] - A[..., 1]) * s
        vx = (B[..., 0] - A[..., 0]) * ds
        vy = (B[..., 1] - A[..., 1]) * ds
    else:
        raise ValueError(f"unknown scene {scene!r}")
    return dx, dy, vx, vy


def _path(scene, t, segment):
    t_arr = np.asarray(t, float)
    scalar = t_arr.ndim == 0
    t1 = np.atleast_1d(t_arr)
    seg = segment_index(scene, t1) if segment is None else np.full(t1.shape, segment)
    dx, dy, vx, vy = _offsets(scene, t1, seg)
    z = np.zeros_like(t1)
    p = P3[:, None] + np.stack([dx, dy, z])
    v = np.stack([vx, vy, z])
    return (p[:, 0], v[:, 0]) if scalar else (p, v)


def v_desired_scalar(scene, t, segment=None):
    """Scalar fast path of ``v_desired`` (pure Python, used inside ``rhs``): (3,) array."""
    seg = int(segment_index(scene, t)) if segment is None else segment
    if scene == "circle":
        if seg == 0:
            return np.array([_CIRCLE_R / 2.0, 0.0, 0.0])
        phi = _CIRCLE_W * (t - 2.0)
        c = _CIRCLE_R * _CIRCLE_W
        return np.array([-c * math.sin(phi), c * math.cos(phi), 0.0])
    if scene == "figure8":
        if seg == 0:
            rad, dphi, phi = _F8_A, 2 * math.pi, math.pi + 2 * math.pi * t
        else:
            rad, dphi, phi = _F8_B, -2 * math.pi, -2 * math.pi * (t - 1.0)
        return np.array([-rad * dphi * math.sin(phi), rad * dphi * math.cos(phi), 0.0])
    if scene == "gearshift":
        t0, t1 = _GS_T[seg], _GS_T[seg + 1]
        tau = min(max((t - t0) / (t1 - t0), 0.0), 1.0)
        ds = (30 * tau**2 - 60 * tau**3 + 30 * tau**4) / (t1 - t0)
        dxy = (_GS_XY[seg + 1] - _GS_XY[seg]) * ds
        return np.array([dxy[0], dxy[1], 0.0])
    raise ValueError(f"unknown scene {scene!r}")


def p_desired(scene, t, segment=None):
    """Desired path p_d(t) = P3(0) + integral of v_d, closed form (spec "Scenes").

    t: scalar or array (N,) -> (3,) or (3, N).  ``segment`` forces the formula of one
    segment (used by the integrator so that a step ending on a jump uses the left piece).
    """
    return _path(scene, t, segment)[0]


def v_desired(scene, t, segment=None):
    """Desired velocity v_d(t) of P3 (the flow source), shape (3,) or (3, N)."""
    return _path(scene, t, segment)[1]


def p_projected(p_d):
    """p_d projected on the sphere of radius l4 about P4 (spec "Outputs": p3_projected)."""
    p_d = np.asarray(p_d, float)
    P4c = P4.reshape((3,) + (1,) * (p_d.ndim - 1))
    e = p_d - P4c
    return P4c + L[3] * e / np.linalg.norm(e, axis=0, keepdims=True)


# ---------------------------------------------------------------------------------------
# Angles and inverse kinematics (spec: "Outputs", "What a good result looks like")
# ---------------------------------------------------------------------------------------
def _cols(v):
    """(3,) -> (3, 1); (3, N) unchanged."""
    v = np.asarray(v, float)
    return v[:, None] if v.ndim == 1 else v


def _mats(R):
    """(3, 3) -> (3, 3, 1); (3, 3, N) unchanged."""
    R = np.asarray(R, float)
    return R[:, :, None] if R.ndim == 2 else R


def signed_angle(u, v, axis):
    """atan2((u x v) . axis, u . v): the signed angle from u to v about axis (arrays (3, N))."""
    return np.arctan2(np.sum(np.cross(u, v, axis=0) * axis, axis=0), np.sum(u * v, axis=0))


def ik_2r(p3, R1, rC1):
    """Closed-form IK of the 2R sub-arm (joints 2 and 3) from link 1's actual pose.

    P1 = rC1 + R1 [l1/2, 0, 0]; the sub-arm moves in the plane through P1 normal to
    a2 = -y1.  p3 is first projected orthogonally on that plane (with compliance it lies
    slightly off it), then expressed in the in-plane basis (x1, e = a2 x x1), in which
    P3 - P1 = l2 (cos th2, sin th2) + l3 (cos(th2+th3), sin(th2+th3)).  The elbow branch
    is th3 <= 0 (initial pose th3 = -pi/2).  th2 is the signed angle from x1 to x2 about a2
    and th3 from x2 to x3 about a2, as in the spec's "Outputs".

    p3: (3,) or (3, N); R1: (3, 3) or (3, 3, N); rC1: (3,) or (3, N).
    Returns (th2, th3), scalars or arrays (N,).
    """
    scalar = np.ndim(p3) == 1 and np.ndim(R1) == 2 and np.ndim(rC1) == 1
    p3, R1, rC1 = _cols(p3), _mats(R1), _cols(rC1)
    x1 = R1[:, 0]
    a2 = -R1[:, 1]
    P1_ = rC1 + 0.5 * L[0] * x1
    e = np.cross(a2, x1, axis=0)
    rel = p3 - P1_
    u = np.sum(rel * x1, axis=0)  # projection on the plane = dropping the a2 component
    w = np.sum(rel * e, axis=0)
    l2, l3 = L[1], L[2]
    c3 = np.clip((u * u + w * w - l2 * l2 - l3 * l3) / (2 * l2 * l3), -1.0, 1.0)
    th3 = -np.arccos(c3)
    th2 = np.arctan2(w, u) - np.arctan2(l3 * np.sin(th3), l2 + l3 * np.cos(th3))
    th2 = (th2 + np.pi) % (2 * np.pi) - np.pi
    if scalar:
        return float(th2[0]), float(th3[0])
    return th2, th3


def _rot_z(th):
    """Rz(th) stacked: th (N,) -> (3, 3, N)."""
    c, s = np.cos(th), np.sin(th)
    o, z = np.ones_like(th), np.zeros_like(th)
    return np.array([[c, -s, z], [s, c, z], [z, z, o]])


def ik_3r(p3):
    """Closed-form IK of the rigid 3R arm plus link 4 for a tip position p3.

    th1 = atan2(p3y, p3x) (the rigid arm's plane contains Z0 and P3); link 1 is then
    R1 = Rz(th1), rC1 = R1 [l1/2, 0, 0], and th2, th3 follow from ``ik_2r``.  th4 is the
    angle from x3 to x4 = (P4 - p3)/|P4 - p3| about a3 = a2 = -y1, i.e. the angle of x4's
    projection on link 3's plane of motion (spec "Outputs": theta4).

    p3: (3,) or (3, N) -> (th1, th2, th3, th4), scalars or arrays (N,).
    """
    scalar = np.ndim(p3) == 1
    p3 = _cols(p3)
    th1 = np.arctan2(p3[1], p3[0])
    R1 = _rot_z(th1)
    rC1 = 0.5 * L[0] * R1[:, 0]
    th2, th3 = ik_2r(p3, R1, rC1)
    x1, a2 = R1[:, 0], -R1[:, 1]
    e = np.cross(a2, x1, axis=0)
    x3 = np.cos(th2 + th3) * x1 + np.sin(th2 + th3) * e
    x4 = P4[:, None] - p3
    x4 = x4 / np.linalg.norm(x4, axis=0)
    th4 = signed_angle(x3, x4, a2)
    out = (th1, th2, th3, th4)
    return tuple(float(a[0]) for a in out) if scalar else out


def fk_rigid(th):
    """Forward kinematics of the rigid 3R arm (spec "Body frames" conventions).

    th: (th1, th2, th3), scalars or arrays (N,).  Returns a dict with R1, R2, R3 (3, 3, N)
    and the points P1, P2, P3 (3, N).  Joint 1 turns about Z0; joints 2 and 3 about
    a2 = a3 = -y1; z2 = z3 = a2, y = z x x.
    """
    th1, th2, th3 = (np.atleast_1d(np.asarray(a, float)) for a in th)
    R1 = _rot_z(th1)
    x1, a2 = R1[:, 0], -R1[:, 1]
    e = np.cross(a2, x1, axis=0)
    x2 = np.cos(th2) * x1 + np.sin(th2) * e
    x3 = np.cos(th2 + th3) * x1 + np.sin(th2 + th3) * e
    R2 = np.stack([x2, np.cross(a2, x2, axis=0), a2], axis=1)
    R3 = np.stack([x3, np.cross(a2, x3, axis=0), a2], axis=1)
    p1 = L[0] * x1
    p2 = p1 + L[1] * x2
    p3 = p2 + L[2] * x3
    return {"R1": R1, "R2": R2, "R3": R3, "P1": p1, "P2": p2, "P3": p3}


# ---------------------------------------------------------------------------------------
# Compliant model (spec: "Couplings", "The initial state", "The drive")
# ---------------------------------------------------------------------------------------
NBODY = 4
NSTATE = 18 * NBODY + 6 * 3 + 3 * 2  # 96
TRANS = {name: slice(72 + 3 * j, 75 + 3 * j)
         for j, name in enumerate(["J1", "J2", "J3", "J4", "J5", "drive"])}
ROT = {name: slice(90 + 2 * j, 92 + 2 * j) for j, name in enumerate(["J1", "J2", "J3"])}

#: translational joints: name -> ((body A, end of A), (body B, end of B)); body None = ground,
#: end -1 = proximal point (-l/2 on x), +1 = distal point (+l/2 on x)
TRANS_JOINTS = {
    "J1": ((None, 0), (0, -1)),
    "J2": ((0, +1), (1, -1)),
    "J3": ((1, +1), (2, -1)),
    "J4": ((2, +1), (3, -1)),
    "J5": ((3, +1), (None, 0)),
}
#: rotational couplings: name -> (proximal body A or None, distal body B)
ROT_JOINTS = {"J1": (None, 0), "J2": (0, 1), "J3": (1, 2)}


def body_slices(i):
    """Slices (p, h, R, rC) of body i (0-based) in the state vector."""
    o = 18 * i
    return slice(o, o + 3), slice(o + 3, o + 6), slice(o + 6, o + 15), slice(o + 15, o + 18)


def initial_state():
    """The spec's initial state: at rest, every coupling undeflected, pose of Table 1."""
    y = np.zeros(NSTATE)
    for i in range(NBODY):
        _, _, sR, sC = body_slices(i)
        y[sR] = R0[i].reshape(-1)
        y[sC] = RC0[i]
    return y


def _cross(a, b):
    """Cross product of (3, K) arrays (faster than np.cross for small K)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def unpack(y):
    """Split states y (NSTATE,) or (NSTATE, K) into per-body lists of (3, K) / (3, 3, K)."""
    y = np.asarray(y, float)
    y = y[:, None] if y.ndim == 1 else y
    p, h, R, rC = [], [], [], []
    for i in range(NBODY):
        sp, sh, sR, sC = body_slices(i)
        p.append(y[sp])
        h.append(y[sh])
        R.append(y[sR].reshape(3, 3, -1))
        rC.append(y[sC])
    return y, p, h, R, rC


def angular_velocity(R, h, i):
    """w = R I_b^-1 R^T h for body i; R (3, 3, K), h (3, K) -> (3, K)."""
    hb = np.einsum("abk,ak->bk", R, h) / IB[i][:, None]
    return np.einsum("abk,bk->ak", R, hb)


_KT = np.array([K_T[n] for n in TRANS])  # (6,) in TRANS order J1..J5, drive
_RT = np.array([R_T[n] for n in TRANS])
_KR = np.array([K_R[n] for n in ROT])  # (3,) J1..J3
_RR = np.array([R_R[n] for n in ROT])
_HALF_L = 0.5 * L[:, None, None]
_MG = (M[:, None] * G[None, :])[:, :, None]  # (4, 3, 1)


def _cross1(a, b):
    """Cross product over axis 1 of arrays (n, 3, ...)."""
    c = np.empty(np.broadcast_shapes(a.shape, b.shape))
    c[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    c[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    c[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return c


def rhs(t, y, scene, segment=None):
    """Time derivative of the hand-written compliant model (see the module docstring).

    y: (NSTATE,) or (NSTATE, K) (vectorised for the finite-difference Jacobian).
    ``segment`` fixes the path segment of v_d (see ``p_desired``).

    The couplings are those of ``TRANS_JOINTS`` / ``ROT_JOINTS``, written out for all
    bodies at once for speed (``rhs_loop`` is the same model written joint by joint).
    """
    squeeze = np.ndim(y) == 1
    y = y[:, None] if squeeze else y
    K = y.shape[1]
    B = y[:72].reshape(NBODY, 18, K)
    p, h, R = B[:, 0:3], B[:, 3:6], B[:, 6:15].reshape(NBODY, 3, 3, K)
    d = y[72:90].reshape(6, 3, K)  # J1..J5, drive
    s = y[90:96].reshape(3, 2, K)  # J1..J3

    # angular velocity w = R Ib^-1 R^T h, CM velocity, half-levers to the link ends
    hb = np.einsum("iabk,iak->ibk", R, h) / IB[:, :, None]
    w = np.einsum("iabk,ibk->iak", R, hb)
    v = p / M[:, None, None]
    hl = _HALF_L * R[:, :, 0]  # rC -> distal point; proximal point is -hl
    wxhl = _cross1(w, hl)
    v_prox = v - wxhl
    v_dist = v + wxhl

    # translational couplings, d' = v_A - v_B, force f on B, -f on A
    dd = np.empty_like(d)
    dd[0] = -v_prox[0]  # J1: ground - link 1 proximal (Q1)
    dd[1:4] = v_dist[0:3] - v_prox[1:4]  # J2, J3, J4
    dd[4] = v_dist[3]  # J5: link 4 distal (P4) - ground
    dd[5] = v_desired_scalar(scene, t, segment)[:, None] - v_dist[2]  # drive: Sf - P3 of link 3
    f = _KT[:, None, None] * d + _RT[:, None, None] * dd
    F_prox = f[0:4]  # J1..J4 act on the proximal end of links 1..4 (their B side)
    F_dist = -f[1:5]  # J2..J5 act on the distal end of links 1..4 (their A side)
    F_dist[2] += f[5]  # the drive acts on P3 of link 3
    force = F_prox + F_dist + _MG
    torque = _cross1(hl, F_dist - F_prox)

    # rotational couplings: s' = P R_B^T (w_B - w_A), torque T on A, -T on B
    w_rel = w[0:3].copy()
    w_rel[1:3] -= w[0:2]
    ds = np.einsum("jabk,jak->jbk", R[0:3], w_rel)[:, :2]
    m = _KR[:, None, None] * s + _RR[:, None, None] * ds
    tau = np.einsum("jabk,jbk->jak", R[0:3, :, :2], m)
    torque[0:3] -= tau
    torque[0:2] += tau[1:3]

    # R' = [w x] R (column by column)
    dR = _cross1(w[:, :, None, :], R)

    dy = np.empty_like(y)
    dB = dy[:72].reshape(NBODY, 18, K)
    dB[:, 0:3] = force
    dB[:, 3:6] = torque
    dB[:, 6:15] = dR.reshape(NBODY, 9, K)
    dB[:, 15:18] = v
    dy[72:90] = dd.reshape(18, K)
    dy[90:96] = ds.reshape(6, K)
    return dy[:, 0] if squeeze else dy


def rhs_loop(t, y, scene, segment=None):
    """The same model as ``rhs``, written joint by joint (slower, easier to read).

    Follows ``TRANS_JOINTS`` / ``ROT_JOINTS`` literally; the self-check tests compare the
    two.  y: (NSTATE,) or (NSTATE, K).
    """
    squeeze = np.ndim(y) == 1
    y, p, h, R, rC = unpack(y)
    K = y.shape[1]
    dy = np.empty_like(y)
    w = [angular_velocity(R[i], h[i], i) for i in range(NBODY)]
    v = [p[i] / M[i] for i in range(NBODY)]
    F = [np.tile((M[i] * G)[:, None], (1, K)) for i in range(NBODY)]  # gravity
    T = [np.zeros((3, K)) for _ in range(NBODY)]

    def lever(i, end):
        return end * 0.5 * L[i] * R[i][:, 0]

    def point_velocity(i, end):
        if i is None:
            return np.zeros((3, K))
        return v[i] + _cross(w[i], lever(i, end))

    def apply_force(i, end, f):
        if i is None:
            return
        F[i] += f
        T[i] += _cross(lever(i, end), f)

    # translational couplings of the joints
    for name, ((a, ea), (b, eb)) in TRANS_JOINTS.items():
        s = TRANS[name]
        dd = point_velocity(a, ea) - point_velocity(b, eb)
        f = K_T[name] * y[s] + R_T[name] * dd
        apply_force(b, eb, f)
        apply_force(a, ea, -f)
        dy[s] = dd

    # drive coupling: flow source v_d on the tip P3 of link 3
    s = TRANS["drive"]
    vd = v_desired(scene, t, segment)[:, None]
    dd = vd - point_velocity(2, +1)
    f = K_T["drive"] * y[s] + R_T["drive"] * dd
    apply_force(2, +1, f)
    dy[s] = dd

    # rotational couplings of the revolute joints
    for name, (a, b) in ROT_JOINTS.items():
        s = ROT[name]
        wrel = w[b] if a is None else w[b] - w[a]
        ds = np.einsum("abk,ak->bk", R[b], wrel)[:2]
        m = K_R[name] * y[s] + R_R[name] * ds
        tau = np.einsum("abk,bk->ak", R[b][:, :2], m)
        T[b] -= tau
        if a is not None:
            T[a] += tau
        dy[s] = ds

    for i in range(NBODY):
        sp, sh, sR, sC = body_slices(i)
        dy[sp] = F[i]
        dy[sh] = T[i]
        dR = np.stack([_cross(w[i], R[i][:, j]) for j in range(3)], axis=1)
        dy[sR] = dR.reshape(9, K)
        dy[sC] = v[i]
    return dy[:, 0] if squeeze else dy


def energy(y, t, scene):
    """Total stored energy (spec "Outputs": energy) for states y (NSTATE,) or (NSTATE, N).

    Kinetic (|p|^2/2m + h.w/2) + every coupling spring (k|d|^2/2, k|s|^2/2, the drive's
    included) + sum m g z_CM with datum z = 0.  ``t``/``scene`` are unused (kept so that
    the signature matches the other outputs); the drive deflection is its state.
    Returns a dict of the parts and their sum under 'total'.
    """
    squeeze = np.ndim(y) == 1
    y, p, h, R, rC = unpack(y)
    kin = sum(np.sum(p[i] ** 2, axis=0) / (2 * M[i])
              + 0.5 * np.sum(h[i] * angular_velocity(R[i], h[i], i), axis=0) for i in range(NBODY))
    grav = sum(-M[i] * np.dot(G, rC[i]) for i in range(NBODY))
    spring_t = sum(0.5 * K_T[n] * np.sum(y[s] ** 2, axis=0) for n, s in TRANS.items())
    spring_r = sum(0.5 * K_R[n] * np.sum(y[s] ** 2, axis=0) for n, s in ROT.items())
    parts = {"kinetic": kin, "gravity": grav, "spring_trans": spring_t, "spring_rot": spring_r}
    parts["total"] = kin + grav + spring_t + spring_r
    if squeeze:
        parts = {k: float(v[0]) for k, v in parts.items()}
    return parts


def outputs(t, y, scene):
    """The spec's outputs (section "Outputs") from times t (N,) and states y (NSTATE, N).

    Returns a dict: theta1..theta4 (N,), p3, p3_desired, p3_projected (3, N), R4 (3, 3, N),
    energy (N,).
    """
    t = np.atleast_1d(np.asarray(t, float))
    y, p, h, R, rC = unpack(y)
    x = [R[i][:, 0] for i in range(NBODY)]
    z = [R[i][:, 2] for i in range(NBODY)]
    pd = p_desired(scene, t)
    return {
        "theta1": np.arctan2(x[0][1], x[0][0]),
        "theta2": signed_angle(x[0], x[1], z[1]),
        "theta3": signed_angle(x[1], x[2], z[2]),
        "theta4": signed_angle(x[2], x[3], z[2]),
        "p3": rC[2] + 0.5 * L[2] * x[2],
        "p3_desired": pd,
        "p3_projected": p_projected(pd),
        "R4": R[3],
        "energy": energy(y, t, scene)["total"],
    }


def simulate(scene, t_eval=None, rtol=1e-6, atol=1e-8, t_end=None, y0=None, max_step=np.inf):
    """Integrate the compliant model with scipy's Radau (finite-difference Jacobian).

    The run restarts at every segment boundary of the scene (``BREAKS``) so that the jumps
    of v_d fall between steps (spec "Scenes": one-sided values).  t_eval: output times
    (default: 1 ms grid); t_end defaults to the scene's duration.

    Returns a dict with 't', 'y' (NSTATE, N), the outputs of ``outputs`` and 'nfev',
    'wall' (seconds).

    Accuracy/cost of the circle scene (6 s, 1 ms output grid), against rtol 1e-8/atol 1e-11:
    rtol 1e-6, atol 1e-6: 3 s, angles within 1e-5 rad, p3 within 3e-7 m;
    rtol 1e-6, atol 1e-8 (default): 16 s, angles within 1.3e-7 rad, p3 within 3e-9 m.
    """
    t_end = T_END[scene] if t_end is None else t_end
    if t_eval is None:
        t_eval = np.linspace(0.0, t_end, int(round(t_end * 1000)) + 1)
    t_eval = np.asarray(t_eval, float)
    y = initial_state() if y0 is None else np.asarray(y0, float)
    b = BREAKS[scene]
    edges = np.concatenate([[0.0], b[(b > 0) & (b < t_end)], [t_end]])
    ts, ys, nfev = [], [], 0
    wall = time.perf_counter()
    for k in range(len(edges) - 1):
        t0, t1 = edges[k], edges[k + 1]
        seg = int(segment_index(scene, t0))
        last = k == len(edges) - 2
        mask = (t_eval >= t0) & ((t_eval <= t1) if last else (t_eval < t1))
        te = np.union1d(t_eval[mask], [t1])  # always stop exactly on t1 to restart there
        sol = solve_ivp(rhs, (t0, t1), y, method="Radau", t_eval=te, rtol=rtol, atol=atol,
                        vectorized=True, args=(scene, seg), max_step=max_step)
        if not sol.success:
            raise RuntimeError(f"{scene}: {sol.message}")
        nfev += sol.nfev
        keep = np.isin(sol.t, t_eval[mask])
        ts.append(sol.t[keep])
        ys.append(sol.y[:, keep])
        y = sol.y[:, -1]
    wall = time.perf_counter() - wall
    t_all = np.concatenate(ts)
    y_all = np.concatenate(ys, axis=1)
    res = {"t": t_all, "y": y_all, "nfev": nfev, "wall": wall}
    res.update(outputs(t_all, y_all, scene))
    return res

