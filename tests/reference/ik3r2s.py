"""Closed-form inverse kinematics of the rigid 3R2S arm, from ``/work/shared/spec/3r2s.md``.

Written from the spec alone (nothing from ``bgc``); ``tests/test_closed_loop_refs.py`` checks
it against the spec's forward-kinematics numbers and by round trips through ``forward``.

The rigid arm (spec "Bodies, joints and points", "Body frames"): J1 turns link 1 about Z0,
so with the radial unit vector e_r = (cos th1, sin th1, 0) and the vertical e_z = (0, 0, 1)
link 1 runs from Q1 = 0 to P1 = l1 e_r; the axes of J2 and J3 are both
a = Rz(th1) (0, -1, 0) = (sin th1, -cos th1, 0), horizontal and normal to the vertical plane
spanned by e_r and e_z, in which links 2 and 3 move:

    P2 = P1 + l2 (cos phi2 e_r + sin phi2 e_z),  P3 = P2 + l3 (cos phi3 e_r + sin phi3 e_z),
    phi2 = th2, phi3 = th2 + th3.

(The spec's signed angle from x1 to x2 about a2 is +phi2 with this a: at t = 0 it gives
(x1 x x2) . a2 = sin 30 deg > 0.) So th1 = atan2(p3_y, p3_x), and in that plane the tip sits
at the radial offset X = sqrt(p3_x^2 + p3_y^2) - l1 and height Z = p3_z; the two-link
solution on the elbow branch of the spec's initial pose (th3 = -pi/2 < 0) is

    cos th3 = (X^2 + Z^2 - l2^2 - l3^2) / (2 l2 l3),  th3 = -acos(cos th3),
    th2 = atan2(Z, X) - atan2(l3 sin th3, l2 + l3 cos th3).

Link 4 runs from P3 to the fixed pivot P4: x4 = (P4 - p3) / |P4 - p3|, and th4 is the spec's
signed angle from x3 to x4 about a3 = a: atan2((x3 x x4) . a, x3 . x4), the angle of x4's
projection on link 3's plane of motion.
"""

from __future__ import annotations

import numpy as np

#: spec "Bodies, joints and points": lengths l1..l4 [m]
L = (0.07, 0.06, 0.05, 0.05)
#: spec Table 1: initial relative angles
TH0 = (0.0, np.pi / 6, -np.pi / 2, -np.pi / 6)
#: spec: the points at t = 0, as the spec prints them (8 digits)
P_SPEC = {"P1": (0.07, 0.0, 0.0), "P2": (0.12196152, 0.0, 0.03),
          "P3": (0.14696152, 0.0, -0.01330127), "P4": (0.14696152, 0.0, -0.06330127)}


def _dvec(th1, phi):
    """cos(phi) e_r + sin(phi) e_z in frame {0}, shape (3, ...)."""
    return np.array([np.cos(phi) * np.cos(th1), np.cos(phi) * np.sin(th1),
                     np.sin(phi) * np.ones_like(th1)])


def axis(th1):
    """The axis a of J2 and J3 (= z2 = z3) for the base angle th1."""
    th1 = np.asarray(th1, float)
    return np.array([np.sin(th1), -np.cos(th1), np.zeros_like(th1)])


def forward(th1, th2, th3, l=L):
    """The points P1, P2, P3 (each (3, ...)) and link 3's direction x3 of the rigid arm."""
    th1, th2, th3 = (np.asarray(a, float) for a in (th1, th2, th3))
    l1, l2, l3 = l[:3]
    p1 = l1 * _dvec(th1, 0.0 * th1)
    x2 = _dvec(th1, th2)
    x3 = _dvec(th1, th2 + th3)
    p2 = p1 + l2 * x2
    return {"P1": p1, "P2": p2, "P3": p2 + l3 * x3, "x2": x2, "x3": x3}


def pivot(l=L, th=TH0):
    """P4 (the fixed spherical joint) from the initial pose: P3(0) + l4 d(th2 + th3 + th4)."""
    f = forward(*th[:3], l=l)
    return f["P3"] + l[3] * _dvec(th[0], th[1] + th[2] + th[3])


P4 = pivot()


def ik(p3, P4=P4, l=L):
    """(th1, th2, th3, th4) of the rigid arm whose tip is p3 ((3,) or (3, N)); link 4 from
    p3 to the pivot P4. Raises ValueError where p3 is out of the 2R sub-arm's reach."""
    p3 = np.asarray(p3, float)
    P4 = np.asarray(P4, float).reshape((3,) + (1,) * (p3.ndim - 1))
    l1, l2, l3 = l[:3]
    th1 = np.arctan2(p3[1], p3[0])
    X = np.hypot(p3[0], p3[1]) - l1
    Z = p3[2]
    c3 = (X**2 + Z**2 - l2**2 - l3**2) / (2 * l2 * l3)
    if np.any(np.abs(c3) > 1 + 1e-12):
        raise ValueError("p3 is out of the arm's reach")
    th3 = -np.arccos(np.clip(c3, -1.0, 1.0))
    th2 = np.arctan2(Z, X) - np.arctan2(l3 * np.sin(th3), l2 + l3 * np.cos(th3))
    th2 = (th2 + np.pi) % (2 * np.pi) - np.pi
    x3 = _dvec(th1, th2 + th3)
    x4 = P4 - p3
    x4 = x4 / np.linalg.norm(x4, axis=0)
    a = axis(th1)
    th4 = np.arctan2(np.sum(np.cross(x3, x4, axis=0) * a, axis=0), np.sum(x3 * x4, axis=0))
    return th1, th2, th3, th4
