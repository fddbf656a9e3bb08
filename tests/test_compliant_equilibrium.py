"""The equilibrium of the spring-closed four-bar (models/fourbar_compliant.yaml), issue 23's
item 7: its equilibria form a continuum (the pivot spring's deflection is an integral of the
rocker's velocity, so any deflection with any angles that balance it is at rest); the one
meant is on the invariant leaf through the initial state, where the deflection equals the
angles' closure gap. bgc settles the damped dynamics there, then polishes by Newton.

References, outside bgc: the rigid four-bar's Lagrange model (tests/reference/fourbar_lagrange.py,
reduced to the crank angle), its static equilibrium (the root of its crank acceleration at
rest) and its small-oscillation eigenvalues (its 2x2 Jacobian by central differences); the
geometric closure computed here from the angles and the rod lengths.
"""
from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import scipy.optimize as so

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bgc  # noqa: E402
from reference import fourbar_lagrange as fl  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "models" / "fourbar_compliant.yaml"


def _rigid_equilibrium():
    """(th, eigenvalues) of the rigid four-bar at rest, torque held at its t = 0 value (zero):
    the stable root of the reduced model's crank acceleration, found on a grid then by brentq."""
    fb = fl.FourBar(fl.model_params(MODEL))

    def acc(th1, w1=0.0):
        return fb.rhs_reduced(0.0, np.array([th1, w1, 0.0, 0.0]))[1]

    grid = np.linspace(-np.pi, np.pi, 721)
    vals = [acc(a) for a in grid]
    roots = [so.brentq(acc, a, b, xtol=1e-14) for a, b, va, vb
             in zip(grid, grid[1:], vals, vals[1:]) if va > 0 > vb]  # restoring: stable
    assert len(roots) == 1
    th1, h = roots[0], 1e-6
    J = np.array([[0.0, 1.0],
                  [(acc(th1 + h) - acc(th1 - h)) / (2 * h), (acc(th1, h) - acc(th1, -h)) / (2 * h)]])
    return fb.assemble(th1), np.linalg.eigvals(J), fb


@pytest.mark.slow  # the settle: about 10 s of numpy Radau on 2 shared cores
def test_spring_closed_fourbar_equilibrium_is_geometric_and_stable():
    th_ref, lam_ref, fb = _rigid_equilibrium()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning: no unstable mode, no far-guess warning
        lin = bgc.linearize(MODEL)
    names = list(lin.states)
    x = np.asarray(lin.x)
    th = x[[names.index(f"{r}.th") for r in ("crank", "coupler", "rocker")]]
    gap = x[[names.index("pin_C.q[0]"), names.index("pin_C.q[1]")]]
    # the deflection is the angles' closure gap (the rocker's end B minus O2)
    closure = fb.closure(th)
    assert np.max(np.abs(gap)) > 1e-6  # the pivot carries load: a real deflection
    np.testing.assert_allclose(gap, closure, rtol=0, atol=1e-3 * np.max(np.abs(gap)))
    # the angles: the rigid equilibrium's, up to the compliance (|gap| ~ 1e-5 m on 0.3..0.9 m)
    np.testing.assert_allclose(th, th_ref, atol=1e-3)
    # no unstable mode; the slowest oscillation is the rigid four-bar's small oscillation
    lam = np.linalg.eigvals(lin.A)
    assert np.max(lam.real) < 1e-6
    osc = lam[(np.abs(lam.imag) > 1e-6) & (np.abs(lam) < 100)]
    (w_ref,) = lam_ref[lam_ref.imag > 0]
    (w,) = osc[osc.imag > 0]
    assert abs(w - w_ref) < 2e-3 * abs(w_ref), (w, w_ref)


def test_undamped_continuum_keeps_newton_answer():
    """Without dissipation of the total momentum (no wall damper) a moving chain never comes
    to rest: the settle gives up (no time run) and Newton's own answer, with its free direction,
    stands (the position where x0 put it)."""
    mod = bgc.compile(ROOT / "models" / "two_mass_chain.yaml")
    x0 = np.array([0.3, -0.2, 0.7, 1e-4])
    x, info = mod.equilibrium(p={"k1": 0.0, "F0": 0.0, "c1": 0.0}, x0=x0)
    assert info.converged and info.settled is None and info.rank == 3
    assert x[mod.STATE_NAMES.index("wall_spring.q")] == pytest.approx(0.7, abs=1e-12)


@pytest.mark.slow  # a compile and the settle: about 20 s on 2 shared cores
def test_linearize_cli_on_the_spring_closed_fourbar(bgc_cli):
    """`bgc linearize MODEL` at its defaults: no unstable-mode or far-guess warning, the
    settle said, and the slow oscillation printed is the rigid four-bar's (within 0.2 %)."""
    _, lam_ref, _ = _rigid_equilibrium()
    (w_ref,) = lam_ref[lam_ref.imag > 0]
    r = bgc_cli("linearize", str(MODEL))
    assert r.returncode == 0, r.stderr
    assert "unstable" not in r.stderr and "far from its initial guess" not in r.stderr
    assert "reached by letting the damped dynamics come to rest" in r.stderr
    rows = [ln.split() for ln in r.stdout.splitlines() if "+/-" in ln]
    slow = [(float(w[0]), float(w[2].rstrip("j"))) for w in rows if float(w[3]) < 100]
    assert len(slow) == 1, r.stdout
    re_, im = slow[0]
    assert abs(complex(re_, im) - w_ref) < 2e-3 * abs(w_ref), (slow, w_ref)
