"""Projection of a start state onto closed loops' constraints, numerically (issue 24).

numpy only, so that both the compile (bgc.core.assembly, the model's own `initial: project`)
and a run's start (bgc.run.consistency, a scene's `initial: project`, from the generated module
alone) use the same steps:

- positions: Newton's method on the closures Phi(x) = 0 over the states they read, each step
  the minimum-norm correction (least squares; the Jacobian by central differences where the
  caller has no analytic one);
- velocities: the velocity constraints are affine in the momenta p at fixed positions,
  r(p) = r0 + G_p (p - p0), and the kinetic energy is quadratic, with Hessian H = M^-1 in p.
  The projected momenta are those of least kinetic-energy distance, min 1/2 (p - p0)^T H
  (p - p0) subject to r(p) = 0: p = p0 - M G_p^T lambda with (G_p M G_p^T) lambda = r0, i.e.
  p0 - G^T lambda with G = G_p M the constraints' rows in velocity coordinates: a physical
  impulse (the reaction's), not the minimum-norm change of the momenta.
"""
from __future__ import annotations

import numpy as np

NEWTON_ITER = 50


def affine_rows(fun, p0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(r0, G) of an affine function r(p) = r0 + G (p - p0): unit steps, exact for an affine
    function (up to rounding)."""
    r0 = np.asarray(fun(p0), dtype=float)
    cols = []
    for j in range(len(p0)):
        trial = p0.copy()
        trial[j] += 1.0
        cols.append(np.asarray(fun(trial), dtype=float) - r0)
    return r0, np.array(cols).T.reshape(len(r0), len(p0))


def quadratic_hessian(energy, p0: np.ndarray) -> np.ndarray:
    """The Hessian of a quadratic function of p (the kinetic energy at fixed positions), by
    polarisation about p = 0: H_ij = E(e_i + e_j) - E(e_i) - E(e_j) + E(0), exact for a
    quadratic (up to rounding)."""
    n = len(p0)
    z = np.zeros(n)
    e0 = float(energy(z))
    ei = []
    for i in range(n):
        t = z.copy()
        t[i] = 1.0
        ei.append(float(energy(t)))
    h = np.empty((n, n))
    for i in range(n):
        for j in range(i, n):
            t = z.copy()
            t[i] += 1.0
            t[j] += 1.0
            h[i, j] = h[j, i] = float(energy(t)) - ei[i] - ei[j] + e0
    return h


def kinetic_projection(r0: np.ndarray, g: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, bool]:
    """(dp, metric): the change of the momenta of least kinetic-energy distance that makes
    r0 + g dp = 0 (least squares where the rows are redundant). ``metric`` is False where the
    Hessian h is not positive definite (no kinetic energy known): then the minimum-norm change."""
    n = h.shape[0]
    try:
        np.linalg.cholesky(h)
        m = np.linalg.inv(h)
        metric = True
    except np.linalg.LinAlgError:
        m, metric = np.eye(n), False
    mg = m @ g.T
    lam = np.linalg.lstsq(g @ mg, r0, rcond=None)[0]
    return -mg @ lam, metric


def newton_positions(phi, x0: np.ndarray, jac=None) -> tuple[np.ndarray, np.ndarray]:
    """(x, residual): Newton's method on phi(x) = 0 from x0, each step the minimum-norm
    correction; ``jac(x)``, else central differences."""
    x = np.array(x0, dtype=float)
    for _ in range(NEWTON_ITER):
        r = np.asarray(phi(x), dtype=float)
        a = np.asarray(jac(x), dtype=float) if jac is not None else _differences(phi, x)
        dx = np.linalg.lstsq(a, -r, rcond=None)[0]
        x = x + dx
        if np.abs(dx).max(initial=0.0) <= 1e-15 * max(1.0, np.abs(x).max(initial=0.0)):
            break
    return x, np.asarray(phi(x), dtype=float)


def _differences(phi, x: np.ndarray) -> np.ndarray:
    cols = []
    for j in range(len(x)):
        h = 1e-6 * max(1.0, abs(x[j]))
        a, b = x.copy(), x.copy()
        a[j] += h
        b[j] -= h
        cols.append((np.asarray(phi(a), dtype=float) - np.asarray(phi(b), dtype=float)) / (2 * h))
    return np.array(cols).T


def changes(names, old, new) -> str:
    """``name old -> new`` for each value that changed (beyond rounding), comma-separated."""
    return ", ".join(f"{n} {a:.10g} -> {b:.10g}" for n, a, b in zip(names, old, new)
                     if abs(a - b) > 1e-13 * max(1.0, abs(a)))
