"""Where bgc linearises (issue 23, item 7): an initial guess for the equilibrium (API x0,
`bgc linearize --x0`, a scene's `initial:`), a warning with the residual at a point that is not
an equilibrium, and a warning when the equilibrium lands far from its guess on an
ill-conditioned Jacobian.

References: a mass on a very soft spring under gravity, whose equilibrium deflection is the
closed form q = -m g / k (k = 1e-8 N/m: nine hundred million metres from the start, with a
Jacobian of condition number about 2e8); the mass-spring-damper at rest at t = 0, where
dp/dt = F0 = 10 N exactly."""
from __future__ import annotations

import warnings
from pathlib import Path

import click
import numpy as np
import pytest
from click.testing import CliRunner

import bgc
from bgc.cli.scene_cmds import linearize_cmd

ROOT = Path(__file__).resolve().parents[1]
M, G, K = 1.0, 9.81, 1.0e-8
SOFT = f"""bgc: 1
name: soft
parameters: {{m: {M}, g: {G}, k: {K}, c: 1.0}}
elements:
  grav: {{type: Se, effort: "-m*g"}}
  mass: {{type: I, inertia: "m"}}
  spring: {{type: C, stiffness: "k"}}
  damper: {{type: R, resistance: "c"}}
  v: {{type: "1"}}
bonds: [[grav, v], [v, mass], [v, spring], [v, damper]]
"""
Q_EQ = -M * G / K


@pytest.fixture(scope="module")
def soft_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("soft") / "soft.yaml"
    path.write_text(SOFT)
    return path


def test_far_equilibrium_on_an_ill_conditioned_jacobian_warns(soft_file):
    with pytest.warns(RuntimeWarning, match="far from its initial guess") as rec:
        lin = bgc.linearize(str(soft_file))
    assert "spring.q" in str(rec[0].message) and "condition number" in str(rec[0].message)
    i = lin.states.index("spring.q")
    assert lin.x[i] == pytest.approx(Q_EQ, rel=1e-9)


def test_a_guess_at_the_equilibrium_is_taken_and_quiet(soft_file):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        lin = bgc.linearize(str(soft_file), x0=[0.0, Q_EQ])
    assert lin.x[lin.states.index("spring.q")] == pytest.approx(Q_EQ, rel=1e-9)


def test_not_an_equilibrium_warns_with_its_residual():
    with pytest.warns(RuntimeWarning, match=r"t = 0 s is not an equilibrium: max \|dx/dt\| = "
                                            r"10 \(in mass.p\)"):
        bgc.linearize(str(ROOT / "models" / "msd.yaml"), at=0.0)
    with warnings.catch_warnings():  # its equilibrium is one: no warning
        warnings.simplefilter("error")
        lin = bgc.linearize(str(ROOT / "models" / "msd.yaml"))
    assert lin.x[lin.states.index("spring.q")] == pytest.approx(10.0 / 200.0)


def _cli(*args):
    group = click.Group()
    group.add_command(linearize_cmd)
    return CliRunner().invoke(group, ["linearize", *map(str, args)])


def test_cli_x0_and_the_scene_initial_are_the_guess(soft_file, tmp_path):
    plain = _cli(soft_file)
    assert plain.exit_code == 0 and "far from its initial guess" in plain.output
    given = _cli(soft_file, "--x0", f"spring.q={Q_EQ!r}")
    assert given.exit_code == 0, given.output
    assert "far from its initial guess" not in given.output
    scene = tmp_path / "s.yaml"
    scene.write_text(f"bgc_scene: 1\nmodel: {soft_file}\nduration: 1.0\n"
                     f"initial: {{spring: {Q_EQ!r}}}\n")
    sc = _cli(scene)
    assert sc.exit_code == 0, sc.output
    assert "far from its initial guess" not in sc.output


def test_cli_bad_x0_is_one_user_error(soft_file):
    r = _cli(soft_file, "--x0", "nothere=1")
    assert r.exit_code != 0 and isinstance(r.exception, bgc.BgcError)
    assert "--x0 'nothere=1'" in str(r.exception) and "spring.q" in str(r.exception)
