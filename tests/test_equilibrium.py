"""equilibrium(): Newton with the analytic Jacobian, least-squares steps where it is singular;
checked against closed-form static deflections and by runs that stay put."""
from __future__ import annotations

import numpy as np
import pytest

QC = dict(m_s=250.0, m_u=35.0, k_s=16000.0, c_s=1000.0, k_t=160000.0, g=9.81)


def test_quarter_car_static_deflections(gen):
    m = gen("quarter_car")
    x, info = m.equilibrium()
    assert info.converged and info.rank == 4 and info.free == []
    # suspension carries the body: k_s q_s = -m_s g; the tyre carries both masses
    np.testing.assert_allclose(x[2], -QC["m_s"] * QC["g"] / QC["k_s"], rtol=1e-12)
    np.testing.assert_allclose(x[3], -(QC["m_s"] + QC["m_u"]) * QC["g"] / QC["k_t"], rtol=1e-12)
    assert np.all(np.abs(x[:2]) < 1e-9)
    # a raised road (input held at its value at t) lifts the wheel by the same height
    x2, _ = m.equilibrium(u={"zr": 0.05})
    np.testing.assert_allclose(x2[3] - x[3], 0.05, rtol=1e-12)
    np.testing.assert_allclose(x2[2], x[2], rtol=1e-12)


def test_batched_over_parameters(gen):
    m = gen("quarter_car")
    ms = np.array([200.0, 250.0, 400.0])
    x, info = m.equilibrium(p={"m_s": ms})
    assert x.shape == (4, 3) and np.all(info.converged)
    np.testing.assert_allclose(x[2], -ms * QC["g"] / QC["k_s"], rtol=1e-12)
    np.testing.assert_allclose(x[3], -(ms + QC["m_u"]) * QC["g"] / QC["k_t"], rtol=1e-12)


def test_free_position_is_reported_and_kept(gen):
    """Two masses with no wall spring (k1 = 0) and no force: the chain's position is free.
    From a state at rest Newton's least-squares steps keep it where x0 put it and name it;
    from a moving state the chain comes to rest where the wall damper's impulse says: the
    position plus the total momentum over c1 is invariant (dq/dt = v1, dP/dt = -c1 v1), so it
    rests at q0 + P0 / c1."""
    m = gen("two_mass_chain")
    names = m.STATE_NAMES
    i = names.index("wall_spring.q")
    p = {"k1": 0.0, "F0": 0.0}
    for x0 in (np.array([0.0, 0.0, 0.7, 1e-4]), np.array([0.3, -0.2, 0.7, 1e-4])):
        x, info = m.equilibrium(p=p, x0=x0)
        assert info.converged and info.rank == 3
        (free,) = info.free
        (name, comp), = free.items()
        assert name == "wall_spring.q" and abs(abs(comp) - 1) < 1e-12
        p0 = x0[names.index("mass1.p")] + x0[names.index("mass2.p")]
        assert x[i] == pytest.approx(x0[i] + p0 / m.PARAM_DEFAULTS["c1"], abs=1e-9)
        rest = [k for k in range(4) if k != i]
        assert np.all(np.abs(x[rest]) < 1e-9)  # momenta and stretch (k2 = 1e8: conditioning)
        assert np.max(np.abs(m.rhs(0.0, x, p))) < 1e-8


def test_settle_per_batch_instance(gen):
    """A batch over the wall damper c1: each moving instance comes to rest at its own
    q0 + P0 / c1; without the damper (c1 = 0) nothing dissipates the momentum, the settle
    gives up (settled None) and Newton's answer keeps x0's position."""
    m = gen("two_mass_chain")
    c1 = np.array([0.1, 0.2, 0.0])
    x0 = np.array([0.3, -0.2, 0.7, 1e-4])
    x, info = m.equilibrium(p={"k1": 0.0, "F0": 0.0, "c1": c1}, x0=x0)
    assert x.shape == (4, 3) and np.all(info.converged)
    i = m.STATE_NAMES.index("wall_spring.q")
    np.testing.assert_allclose(x[i], [0.7 + 0.1 / 0.1, 0.7 + 0.1 / 0.2, 0.7], atol=1e-9)
    assert info.settled[0] > 0 and info.settled[1] > 0 and info.settled[2] is None


def test_no_equilibrium_is_not_converged(gen):
    """A steady force on a chain held by nothing accelerates it for ever."""
    m = gen("two_mass_chain")
    x, info = m.equilibrium(p={"k1": 0.0})
    assert not info.converged and info.residual > 1.0


def _slender_estimate(m):
    """Fastest joint mode of the 3R2S: a translational joint spring k_t between the ends of
    two slender rods; each rod's end point has effective mass m/4 (1/m + (l/2)^2 / (m l^2/12))
    across the rod, so omega = sqrt(k_t (4/m_a + 4/m_b)) for the stiffest-feeling joint."""
    k = m.PARAM_DEFAULTS["k_t"]
    masses = [m.PARAM_DEFAULTS[f"m{i}"] for i in range(1, 5)]
    pairs = [4 / masses[0]] + [4 / a + 4 / b for a, b in zip(masses, masses[1:])]
    return np.sqrt(k * max(pairs))


@pytest.mark.slow  # ~6 s on the shared 2 cores: two 3R2S runs
def test_3r2s_hangs_at_its_equilibrium(gen):
    m = gen("mech3r2s")
    x, info = m.equilibrium()
    assert info.converged
    mom = [i for i, n in enumerate(m.STATE_NAMES) if ".p[" in n]
    assert len(mom) == 24
    # a run from the equilibrium stays put (two steps over 0.05 s); one from the initial pose
    # does not. That one rings in its joint modes (1247 Radau steps in its first 5 ms, 8431
    # over 0.05 s: 4.4 against 31 CPU s), and 5 ms suffice to show it moving: its largest
    # momentum is 1.1e-2 there (7.6e-3 at 0.05 s), a hundred times the bound
    r = m.simulate((0.0, 0.05), x0=x, rtol=1e-8, atol=1e-12, dt=0.01)
    still = np.max(np.abs(r.x[mom]))
    r0 = m.simulate((0.0, 0.005), rtol=1e-8, atol=1e-12, dt=0.001)
    moving = np.max(np.abs(r0.x[mom]))
    assert still < 1e-9 and moving > 1e-4
    # the fastest modes: the joint springs against the links' end-point masses
    lam = np.linalg.eigvals(m.linearize(0.0, x)[0])
    w_fast = np.max(np.abs(lam.imag))
    est = _slender_estimate(m)
    assert 0.7 < w_fast / est < 1.5, (w_fast, est)


def _qc_scene(tmp_path, initial: str):
    import os

    qc = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "models",
                      "quarter_car.yaml")
    path = tmp_path / "s.yaml"
    path.write_text(f"bgc_scene: 1\nmodel: {qc}\nduration: 0.5\ninitial: {initial}\n"
                    "solver: {method: Radau, rtol: 1.0e-8, atol: 1.0e-10, dt: 0.05}\n")
    return path


def test_scene_initial_equilibrium_stays_put(tmp_path):
    from bgc.run.runner import run_scene

    r = run_scene(_qc_scene(tmp_path, "equilibrium"))
    np.testing.assert_allclose(r.y["suspension_travel"], -QC["m_s"] * QC["g"] / QC["k_s"],
                               rtol=1e-9)
    assert np.max(np.abs(r.y["body_velocity"])) < 1e-9


def test_scene_initial_values_by_state_and_element(tmp_path):
    from bgc.run.runner import run_scene

    r = run_scene(_qc_scene(tmp_path, "{spring.q: -0.1, tyre: -0.02, sprung.p: 25.0}"))
    assert r.y["suspension_travel"][0] == -0.1 and r.y["wheel_height"][0] == -0.02
    assert r.y["body_velocity"][0] == pytest.approx(25.0 / QC["m_s"])


@pytest.mark.parametrize("initial, message", [
    ("{sprung.x: 1.0}", "no state 'sprung.x'"),
    ("{spring: [1.0, 2.0]}", "2 value(s) for 1 state(s)"),
    ("somewhere", "write 'equilibrium'"),
])
def test_scene_initial_errors_are_located(tmp_path, initial, message):
    from bgc.base.errors import ModelError
    from bgc.run.runner import run_scene

    with pytest.raises(ModelError) as ei:
        run_scene(_qc_scene(tmp_path, initial))
    assert message in ei.value.message and ei.value.coord.line == 4
