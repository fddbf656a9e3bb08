"""Independent reference for the planar crank-rocker four-bar of ``models/fourbar_rigid.yaml``.

Nothing here comes from ``bgc``: the equations of motion are written from first principles
(Lagrange's equations of three uniform rods joined in a closed loop) and integrated with
scipy's ``solve_ivp``. Only the base parameters' *values* are read from the model file, with
plain ``yaml.safe_load``; the assembly, the torque's form and everything else is derived here.

Geometry and coordinates
------------------------
Rod i (crank 1, coupler 2, rocker 3) of length L_i, mass m_i, centroidal inertia
J_i = m_i L_i^2 / 12 runs from its end A to its end B at the angle th_i from X (counter-
clockwise): u_i = (cos th_i, sin th_i), u_i' = (-sin th_i, cos th_i). The crank's A is at
O1 = (0, 0); the rocker's B at O2 = (d, 0). Centres of mass:

    C1 = L1/2 u1,   C2 = L1 u1 + L2/2 u2,   C3 = L1 u1 + L2 u2 + L3/2 u3,

i.e. C_k = sum_j r[k, j] u_j with the coefficient matrix r below. Loop closure (two equations):

    Phi(th) = L1 u1 + L2 u2 + L3 u3 - (d, 0) = 0.

Kinetic energy T = 1/2 w^T M(th) w with M_ij = sum_k m_k r_ki r_kj cos(th_i - th_j) + J_i d_ij;
potential V = g sum_k m_k (C_k)_y. Lagrange's equations (no constraint yet):

    M(th) w' + N(th) w^2 + dV/dth = Q,   N_ij = sum_k m_k r_ki r_kj sin(th_i - th_j),
    (dV/dth)_i = g cos th_i sum_k m_k r_ki,

with the generalised forces Q = (tau, 0, 0) - dD/dw from the Rayleigh function of the joint
friction D = 1/2 [c1 w1^2 + c2 (w2 - w1)^2 + c3 (w3 - w2)^2 + c4 w3^2].

Two formulations, which share only the expressions above:

* ``reduced``: one degree of freedom, the crank angle. The closed-form assembly gives th2, th3
  from th1 (the open branch); the velocity constraint  L2 u2' w2 + L3 u3' w3 = -L1 u1' w1  gives
  w = K w1 and the acceleration constraint gives w' = K w1' + s (s from the centripetal terms);
  projecting Lagrange's equations on K:  (K^T M K) w1' = K^T (Q - N w^2 - dV/dth - M s).
* ``multiplier``: the three angles with two Lagrange multipliers,
      [M  G^T] [w' ]   [Q - N w^2 - dV/dth]
      [G   0 ] [-lam] = [L1 w1^2 u1 + L2 w2^2 u2 + L3 w3^2 u3],   G = [L1 u1', L2 u2', L3 u3'],
  integrated as an index-1 ODE from a consistent start (its drift is a measured result).

Both integrate the work of the torque and the dissipated energy as extra states.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import yaml
from scipy.integrate import solve_ivp

MODEL = Path(__file__).resolve().parents[2] / "models" / "fourbar_rigid.yaml"
#: the base parameters this reference takes from the model (their numbers only)
NAMES = ("g", "d", "l1", "l2", "l3", "m1", "m2", "m3", "c1", "c2", "c3", "c4", "tau0", "w_tau",
         "th1_0")


def model_params(path=MODEL) -> dict:
    """The base parameters' values from a model file (plain YAML, nothing evaluated)."""
    doc = yaml.safe_load(Path(path).read_text())
    return {n: float(doc["parameters"][n]["value"]) for n in NAMES}


def torque(t, p):
    """The crank torque: the model's input default ``tau0 * sin(w_tau * t)``."""
    return p["tau0"] * np.sin(p["w_tau"] * t)


class FourBar:
    """The four-bar's kinematics and Lagrange terms for one parameter set."""

    def __init__(self, params=None):
        p = model_params()
        p.update(params or {})
        self.p = p
        self.L = np.array([p["l1"], p["l2"], p["l3"]])
        self.m = np.array([p["m1"], p["m2"], p["m3"]])
        self.J = self.m * self.L**2 / 12
        L1, L2, L3 = self.L
        self.r = np.array([[L1 / 2, 0, 0], [L1, L2 / 2, 0], [L1, L2, L3 / 2]])
        # mass-weighted products of the coefficients: P_ij = sum_k m_k r_ki r_kj
        self.P = np.einsum("k,ki,kj->ij", self.m, self.r, self.r)
        self.gm = p["g"] * (self.m @ self.r)   # (dV/dth)_i = gm_i cos th_i
        self.c = np.array([p["c1"], p["c2"], p["c3"], p["c4"]])

    # -- closed-form assembly (open branch: the coupler-rocker pin above the line P1 O2) --
    def assemble(self, th1):
        L1, L2, L3 = self.L
        d = self.p["d"]
        p1 = L1 * np.array([math.cos(th1), math.sin(th1)])
        ev = np.array([d, 0.0]) - p1
        e = math.hypot(*ev)
        cos_a = (L2**2 + e**2 - L3**2) / (2 * L2 * e)
        if not -1 <= cos_a <= 1:
            raise ValueError(f"the four-bar does not assemble at th1 = {th1}")
        th2 = math.atan2(ev[1], ev[0]) + math.acos(cos_a)
        p2 = p1 + L2 * np.array([math.cos(th2), math.sin(th2)])
        th3 = math.atan2(-p2[1], d - p2[0])
        return np.array([th1, th2, th3])

    def closure(self, th):
        """Phi(th): the rocker's end B minus O2 (m); th of shape (3, ...)."""
        th = np.asarray(th, float)
        x = np.tensordot(self.L, np.cos(th), axes=1) - self.p["d"]
        y = np.tensordot(self.L, np.sin(th), axes=1)
        return np.array([x, y])

    # -- Lagrange terms --
    def mass(self, th):
        return self.P * np.cos(th[:, None] - th[None, :]) + np.diag(self.J)

    def forces(self, t, th, w):
        """Q - N w^2 - dV/dth: everything but the inertia and the constraint."""
        N = self.P * np.sin(th[:, None] - th[None, :])
        c1, c2, c3, c4 = self.c
        w1, w2, w3 = w
        fric = np.array([-c1 * w1 + c2 * (w2 - w1),
                         -c2 * (w2 - w1) + c3 * (w3 - w2),
                         -c3 * (w3 - w2) - c4 * w3])
        drive = np.array([torque(t, self.p), 0.0, 0.0])
        return drive + fric - N @ w**2 - self.gm * np.cos(th)

    def power_in(self, t, w):
        return torque(t, self.p) * w[0]

    def power_diss(self, w):
        c1, c2, c3, c4 = self.c
        w1, w2, w3 = w
        return c1 * w1**2 + c2 * (w2 - w1)**2 + c3 * (w3 - w2)**2 + c4 * w3**2

    def energy(self, th, w):
        """Kinetic + gravity potential (datum y = 0); th, w of shape (3, n)."""
        th, w = np.atleast_2d(th), np.atleast_2d(w)
        out = np.empty(th.shape[1])
        for k in range(th.shape[1]):
            M = self.mass(th[:, k])
            out[k] = 0.5 * w[:, k] @ M @ w[:, k]
        yc = self.r @ np.sin(th)
        return out + self.p["g"] * (self.m @ yc)

    # -- constraint Jacobian and the velocity/acceleration coefficients --
    def G(self, th):
        return np.array([-self.L * np.sin(th), self.L * np.cos(th)])

    def centripetal(self, th, w):
        """L1 w1^2 u1 + L2 w2^2 u2 + L3 w3^2 u3: the right side of G w' at acceleration level."""
        return np.array([self.L @ (w**2 * np.cos(th)), self.L @ (w**2 * np.sin(th))])

    def coefficients(self, th, w1):
        """K (w = K w1) and s (w' = K w1' + s) at the assembled angles th."""
        G = self.G(th)
        A = G[:, 1:]
        K = np.concatenate([[1.0], np.linalg.solve(A, -G[:, 0])])
        w = K * w1
        s = np.concatenate([[0.0], np.linalg.solve(A, self.centripetal(th, w))])
        return K, s

    # -- the two right-hand sides --
    def rhs_reduced(self, t, y):
        """y = (th1, w1, W_in, W_diss)."""
        th1, w1 = y[0], y[1]
        th = self.assemble(th1)
        K, s = self.coefficients(th, w1)
        w = K * w1
        M = self.mass(th)
        dw1 = K @ (self.forces(t, th, w) - M @ s) / (K @ M @ K)
        return np.array([w1, dw1, self.power_in(t, w), self.power_diss(w)])

    def rhs_multiplier(self, t, y):
        """y = (th1, th2, th3, w1, w2, w3, W_in, W_diss)."""
        th, w = y[:3], y[3:6]
        M, G = self.mass(th), self.G(th)
        A = np.zeros((5, 5))
        A[:3, :3], A[:3, 3:], A[3:, :3] = M, G.T, G
        b = np.concatenate([self.forces(t, th, w), self.centripetal(th, w)])
        dw = np.linalg.solve(A, b)[:3]
        return np.concatenate([w, dw, [self.power_in(t, w), self.power_diss(w)]])


def simulate(t_eval, rtol=1e-12, params=None, form="reduced", w1_0=0.0, atol=None):
    """Integrate the four-bar from the assembled pose at th1_0 (crank rate w1_0, default at
    rest, as the model) over [0, t_eval[-1]]; return t and th1..th3, w1..w3, energy,
    work_in, dissipated and the closure residual ``tip_gap`` (B - O2, shape (2, n))."""
    fb = FourBar(params)
    t_eval = np.asarray(t_eval, float)
    th0 = fb.assemble(fb.p["th1_0"])
    K, _ = fb.coefficients(th0, w1_0)
    atol = rtol * 1e-2 if atol is None else atol
    span = (0.0, float(t_eval[-1]))
    if form == "reduced":
        sol = solve_ivp(fb.rhs_reduced, span, [th0[0], w1_0, 0.0, 0.0], method="DOP853",
                        t_eval=t_eval, rtol=rtol, atol=atol)
        assert sol.success, sol.message
        th = np.array([fb.assemble(a) for a in sol.y[0]]).T
        w = np.array([fb.coefficients(th[:, k], sol.y[1, k])[0] * sol.y[1, k]
                      for k in range(len(sol.t))]).T
        W_in, W_diss = sol.y[2], sol.y[3]
    elif form == "multiplier":
        sol = solve_ivp(fb.rhs_multiplier, span, np.concatenate([th0, K * w1_0, [0.0, 0.0]]),
                        method="DOP853", t_eval=t_eval, rtol=rtol, atol=atol)
        assert sol.success, sol.message
        th, w, W_in, W_diss = sol.y[:3], sol.y[3:6], sol.y[6], sol.y[7]
    else:
        raise ValueError(form)
    return {"t": sol.t, "th1": th[0], "th2": th[1], "th3": th[2],
            "w1": w[0], "w2": w[1], "w3": w[2], "energy": fb.energy(th, w),
            "work_in": W_in, "dissipated": W_diss, "tip_gap": fb.closure(th)}
