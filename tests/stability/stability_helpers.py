"""Shared pieces of the stability suite (tests/stability): scene modules compiled once per
session, state lookup by name, the rotation-matrix invariant, and the independent 3R2S
reference (tests/reference/mech3r2s.py, which imports nothing of bgc)."""
from __future__ import annotations

import sys
from functools import lru_cache
from pathlib import Path

import numpy as np

TESTS = Path(__file__).resolve().parents[1]
ROOT = TESTS.parent
SCENES = ROOT / "models" / "scenes"
if str(TESTS) not in sys.path:
    sys.path.insert(0, str(TESTS))

from reference import mech3r2s as ref  # noqa: E402,F401  (re-exported)


@lru_cache(maxsize=None)
def scene_module(path):
    """(scene, module) for a scene file: its model compiled with the scene's signals, the
    numpy module, through the test session's compile cache (as `bgc simulate --backend numpy`
    builds it): tests/test_3r2s.py compiles the circle scene the same way, so the session
    compiles it once."""
    from bgc.format.scene import parse_scene
    from bgc.run.runner import scene_module as built

    scene = parse_scene(path)
    backend, mod = built(scene, backend="numpy")
    assert backend == "numpy"
    return scene, mod


def scene_run(scene, mod, **overrides):
    """simulate() with the scene's own settings (as `bgc simulate`), overrides on top."""
    from bgc.format.scene import free_values

    kw = dict(dt=scene.dt, method=scene.method, rtol=scene.rtol, atol=scene.atol,
              p=free_values(scene) or None, breakpoints=scene.breakpoints,
              max_step=scene.max_step)
    kw.update(overrides)
    return mod.simulate(scene.t_span, **kw)


def rows(mod, x, base, shape):
    """The rows of x holding the state array `base` (e.g. 'link1.R', (3, 3)) -> (*shape, N)."""
    names = mod.STATE_NAMES
    if len(shape) == 1:
        idx = np.array([names.index(f"{base}[{i}]") for i in range(shape[0])])
    else:
        idx = np.array([[names.index(f"{base}[{i},{j}]") for j in range(shape[1])]
                        for i in range(shape[0])])
    return x[idx]


def orthogonality_error(R):
    """||R^T R - I|| (Frobenius) of rotation matrices R (3, 3, N) -> (N,)."""
    RtR = np.einsum("kin,kjn->ijn", R, R)
    return np.linalg.norm(RtR - np.eye(3)[:, :, None], axis=(0, 1))


def link1_pose(mod, x):
    """Link 1's rotation R1 (3, 3, N) and centre of mass rC1 (3, N) from the state.

    A scene module keeps only the states its outputs need, so link1.rC may be gone. Its
    proximal end Q1 then follows from the joint-1 coupling, whose state is the displacement
    of the ground point minus that of Q1: Q1 = -q(j1.C) (a few 1e-7 m), and
    rC1 = Q1 + R1 [l1/2, 0, 0].
    """
    R1 = rows(mod, x, "link1.R", (3, 3))
    half = 0.5 * ref.L[0] * R1[:, 0]
    names = mod.STATE_NAMES
    if all(f"link1.rC[{i}]" in names for i in range(3)):
        return R1, rows(mod, x, "link1.rC", (3,))
    return R1, -rows(mod, x, "j1.C.q", (3,)) + half


# ---------------------------------------------------------------------------------------
# The stiff two-mass chain (models/two_mass_chain.yaml), written out by hand
# ---------------------------------------------------------------------------------------
CHAIN_STATES = ("mass1.p", "mass2.p", "wall_spring.q", "link_spring.q")


def chain_matrix(P):
    """State matrix A and constant forcing b (force F0 on m2) of the chain, for the state
    (p1, p2, x1, stretch): p1' = -k1 x1 - c1 v1 + k2 s + c2 (v2 - v1), p2' = F - k2 s
    - c2 (v2 - v1), x1' = v1, s' = v2 - v1, with v = p / m. P: parameter values (scalars)."""
    m1, m2, k1, c1, k2, c2 = (float(P[k]) for k in ("m1", "m2", "k1", "c1", "k2", "c2"))
    A = np.array([[-(c1 + c2) / m1, c2 / m2, -k1, k2],
                  [c2 / m1, -c2 / m2, 0.0, -k2],
                  [1 / m1, 0.0, 0.0, 0.0],
                  [-1 / m1, 1 / m2, 0.0, 0.0]])
    return A, np.array([0.0, float(P["F0"]), 0.0, 0.0])


def chain_exact(P, t, t_on=0.0, x0=None):
    """Exact solution at the increasing times t, the force F0 acting from t_on on (nothing
    before), from x0 (default rest): matrix exponentials of the linear system, propagated
    from one output time to the next."""
    from scipy.linalg import expm

    A, b = chain_matrix(P)
    xs = np.linalg.solve(A, -b)  # static deflection under F0
    x = np.zeros(4) if x0 is None else np.asarray(x0, float)
    out = np.empty((4, len(t)))
    tp = 0.0
    for n, tn in enumerate(t):
        if tp < t_on <= tn:  # the force switches on inside this interval (or at its end)
            x = expm(A * (t_on - tp)) @ x
            tp = t_on
        if tn >= t_on:
            x = xs + expm(A * (tn - tp)) @ (x - xs)
        else:
            x = expm(A * (tn - tp)) @ x
        tp = tn
        out[:, n] = x
    return out
