"""Issue 26, dimensional analysis: unit strings to SI dimensions, and each bond's effort and
flow inferred and checked through junctions, two-ports and laws; a disagreement is one located
error naming the element or name at fault and both dimensions."""
from __future__ import annotations

import subprocess
import sys
from fractions import Fraction
from pathlib import Path

import pytest

from bgc.base.errors import ModelError
from bgc.core.graph import build_graph
from bgc.core.units import check_units
from bgc.format.parse import parse_text
from bgc.format.units import UnitError, dim, parse_unit, show

ROOT = Path(__file__).resolve().parents[1]
MODELS = sorted((ROOT / "models").glob("*.yaml"))
N = dim(kg=1, m=1, s=-2)


# ---------------------------------------------------------------------------------------------
# The unit parser

@pytest.mark.parametrize("text, want", [
    ("N", N), ("N*s/m", dim(kg=1, s=-1)), ("N s/m", dim(kg=1, s=-1)),
    ("kg*m^2", dim(kg=1, m=2)), ("m/s", dim(m=1, s=-1)), ("rad", dim()), ("1", dim()), ("-", dim()),
    ("Pa", dim(kg=1, m=-1, s=-2)), ("m^3/s", dim(m=3, s=-1)), ("V", dim(kg=1, m=2, s=-3, A=-1)),
    ("A", dim(A=1)), ("Ohm", dim(kg=1, m=2, s=-3, A=-2)), ("ohm", dim(kg=1, m=2, s=-3, A=-2)),
    ("F", dim(kg=-1, m=-2, s=4, A=2)), ("H", dim(kg=1, m=2, s=-2, A=-2)),
    ("S", dim(kg=-1, m=-2, s=3, A=2)), ("W", dim(kg=1, m=2, s=-3)), ("J", dim(kg=1, m=2, s=-2)),
    ("K", dim(K=1)), ("W/K", dim(kg=1, m=2, s=-3, K=-1)), ("J/K", dim(kg=1, m=2, s=-2, K=-1)),
    ("1/K", dim(K=-1)), ("K/W", dim(kg=-1, m=-2, s=3, K=1)), ("N m s/rad", dim(kg=1, m=2, s=-1)),
    ("N*m/A", dim(kg=1, m=2, s=-2, A=-1)), ("m/s^2", dim(m=1, s=-2)), ("1/s", dim(s=-1)),
    ("kg/m^3", dim(kg=1, m=-3)), ("m^3/s/Pa^0.5", dim(m=Fraction(7, 2), kg=Fraction(-1, 2))),
    ("(m/s)^2", dim(m=2, s=-2)), ("m^(1/2)", dim(m=Fraction(1, 2))), ("m**-1", dim(m=-1)),
    ("N·m", dim(kg=1, m=2, s=-2)), ("mol", dim(mol=1)), ("cd", dim(cd=1)),
])
def test_units_as_written_in_models_parse_to_si_dimensions(text, want):
    assert parse_unit(text) == (1.0, want)


def test_prefixes_and_non_si_units_report_their_scale():
    assert parse_unit("kN") == (1000.0, N)
    assert parse_unit("mm")[0] == pytest.approx(1e-3) and parse_unit("mm")[1] == dim(m=1)
    assert parse_unit("ms")[1] == dim(s=1)  # milli-second, not m*s
    assert parse_unit("g")[0] == pytest.approx(1e-3)
    assert parse_unit("rpm")[1] == dim(s=-1)


@pytest.mark.parametrize("text, words", [
    ("Nm", "unknown unit 'Nm'"), ("kgs", "unknown unit 'kgs'"), ("", "empty unit"),
    ("kg<&>", "unexpected '<'"), ('x"""\nimport os', "unexpected '\"'"), ("nul\0byte", "unexpected"),
    ("m^", "ends too early"), ("m^1000", "bad exponent"), ("m^13", "out of range"),
    ("2*m", "must be 1"), ("((((((m))))))", "nested too deeply"), ("(m", "ends too early"),
    ("m)", "unexpected ')'"), ("m" * 101, "longer than 100"), ("m^(1/0)", "bad exponent"),
    ("m^1.5.5", "unexpected '.'"), ("-m", "unexpected '-'"),
])
def test_bad_units_are_refused_with_the_reason(text, words):
    with pytest.raises(UnitError, match=None) as exc:
        parse_unit(text)
    assert words in str(exc.value)


def test_dimensions_are_shown_by_name_or_in_base_units():
    assert show(N) == "N"
    assert show(dim(kg=1, s=-1)) == "N*s/m"
    assert show(dim(kg=1, m=2)) == "kg*m^2"
    assert show(dim(kg=1, m=-1, s=-2)) == "Pa"
    assert show(dim(m=Fraction(1, 2), s=-1)) == "m^(1/2)/s"
    assert show(dim()) == "1"


# ---------------------------------------------------------------------------------------------
# Mistakes in models: each a located error with both dimensions

MSD = """\
bgc: 1
name: msd
parameters:
  m:  {value: 2.0, unit: kg}
  k:  {value: 200.0, unit: N/m}
  c:  {value: 4.0, unit: N*s/m}
  F0: {value: 10.0, unit: N}
inputs:
  F: {default: "F0", unit: N}
elements:
  force:  {type: Se, effort: "F"}
  mass:   {type: I, inertia: "m"}
  spring: {type: C, stiffness: "k"}
  damper: {type: R, resistance: "c"}
  v:      {type: "1"}
bonds: [[force, v], [v, mass], [v, spring], [v, damper]]
outputs:
  position: {expr: "q(spring)", unit: m}
  velocity: {expr: "f(mass)", unit: m/s}
"""


def check_text(text: str):
    return check_units(build_graph(parse_text(text, "m.yaml")))


def error_of(text: str) -> ModelError:
    with pytest.raises(ModelError) as exc:
        check_text(text)
    return exc.value


def test_the_msd_as_written_checks_clean():
    rep = check_text(MSD)
    assert [b.domain for b in rep.bonds] == ["mechanical translation"] * 4
    assert {(show(b.effort), show(b.flow)) for b in rep.bonds} == {("N", "m/s")}


def test_a_damper_coefficient_in_newton_per_metre():
    err = error_of(MSD.replace("c:  {value: 4.0, unit: N*s/m}", "c:  {value: 4.0, unit: N/m}"))
    assert err.coord.line == 14
    assert err.message == ("R 'damper': resistance 'c' is N/m, but effort/flow on its bond is "
                           "N*s/m")


def test_a_law_adding_kilograms_to_newtons():
    err = error_of(MSD.replace('spring: {type: C, stiffness: "k"}',
                               'spring: {type: C, effort: "k*q + m"}'))
    assert (err.coord.line, err.coord.column) == (13, 36)  # at the 'm'
    assert err.message == "C 'spring' (effort): cannot add N and kg (in 'k*q + m')"


def test_a_velocity_output_labelled_metre():
    err = error_of(MSD.replace('{expr: "f(mass)", unit: m/s}', '{expr: "f(mass)", unit: m}'))
    assert err.coord.line == 19
    assert err.message == "output 'velocity' is declared m, but its expression 'f(mass)' is m/s"


def test_a_force_input_labelled_newton_metre():
    err = error_of(MSD.replace('F: {default: "F0", unit: N}', 'F: {default: "F0", unit: N*m}'))
    assert err.coord.line == 9
    assert err.message == "input 'F' is N*m, but its default 'F0' is N"


RACK = """\
bgc: 1
name: rack
parameters:
  Jp:  {value: 0.01, unit: kg*m^2}
  r:   {value: 0.05, unit: m}
  m:   {value: 3.0, unit: kg}
  c:   {value: 2.0, unit: N*s/m}
  tau: {value: 1.0, unit: N*m}
elements:
  motor:  {type: Se, effort: "tau"}
  w:      {type: "1"}
  pinion: {type: I, inertia: "Jp"}
  rack:   {type: TF, ratio: "r"}
  v:      {type: "1"}
  slide:  {type: I, inertia: "m"}
  fric:   {type: R, resistance: "c"}
bonds: [[motor, w], [w, pinion], [w, rack], [rack, v], [v, slide], [v, fric]]
"""


def test_a_rack_and_pinion_checks_clean_across_its_transformer():
    rep = check_text(RACK)
    assert [b.domain for b in rep.bonds] == ["mechanical rotation"] * 3 + [
        "mechanical translation"] * 3


def test_a_transformer_modulus_in_the_wrong_unit():
    err = error_of(RACK.replace("r:   {value: 0.05, unit: m}", "r:   {value: 0.05, unit: kg}"))
    assert err.coord.line == 13
    assert err.message == "TF 'rack': ratio 'r' is kg, but its bonds need m"


def test_a_gyrator_modulus_in_the_wrong_unit():
    text = (ROOT / "models" / "dc_motor.yaml").read_text(encoding="utf-8")
    assert text.count("unit: N*m/A,") == 1
    err = error_of(text.replace("unit: N*m/A,", "unit: N*m,"))
    motor = text.splitlines().index('  motor:     {type: GY, ratio: "K"}                # '
                                    'torque = K i, back-EMF = K w') + 1
    assert err.coord.line == motor  # the GY's ratio
    assert err.message == "GY 'motor': ratio 'K' is N*m, but its bonds need N*m/A"


def test_a_scene_input_in_the_wrong_unit(tmp_path):
    from bgc.format.scene import parse_scene, scene_model

    (tmp_path / "msd.yaml").write_text(MSD, encoding="utf-8")
    scene = tmp_path / "s.yaml"
    scene.write_text("bgc_scene: 1\nmodel: msd.yaml\nduration: 1.0\n"
                     "inputs: {F: \"where(t < 0.5, 0, m)\"}\n", encoding="utf-8")
    with pytest.raises(ModelError) as exc:
        build_graph(scene_model(parse_scene(scene)))
    assert exc.value.message == "input 'F' is N, but its default 'where(t < 0.5, 0, m)' is kg"


def test_exp_of_a_dimensional_argument():
    err = error_of(MSD.replace('spring: {type: C, stiffness: "k"}',
                               'spring: {type: C, effort: "k*q*exp(q)"}'))
    assert (err.coord.line, err.coord.column) == (13, 38)  # at exp's argument
    assert err.message == ("C 'spring' (effort): exp() needs a dimensionless argument, not m "
                           "(in 'k*q*exp(q)')")


def test_an_unknown_unit_is_located_at_its_parameter():
    err = error_of(MSD.replace("unit: N*s/m", "unit: Nsm"))
    assert err.coord.line == 6
    assert err.message == "parameter 'c': unit 'Nsm': unknown unit 'Nsm'"


@pytest.mark.parametrize("old, new, line, message", [
    ('spring: {type: C, stiffness: "k"}', 'spring: {type: C, stiffness: "k", initial: "F0"}', 13,
     "C 'spring': initial value 'F0' is N, but its displacement is m"),
    ("c:  {value: 4.0, unit: N*s/m}", 'c:  {value: "m * k", unit: N*s/m}', 6,
     "parameter 'c' is declared N*s/m, but its value 'm * k' is kg^2/s^2"),
    ("outputs:", 'states:\n  W: {derivative: "f(mass)", unit: J}\noutputs:', 18,
     "state 'W': derivative 'f(mass)' is m/s, but the state's rate of change is W"),
    ('force:  {type: Se, effort: "F"}', 'force:  {type: Se, effort: "where(t < 1, F, m)"}', 11,
     "Se 'force' (effort): where() chooses between N and kg (in 'where(t < 1, F, m)')"),
])
def test_initial_values_derived_parameters_states_and_branches(old, new, line, message):
    assert old in MSD
    err = error_of(MSD.replace(old, new))
    assert err.coord.line == line and err.message == message


def test_a_component_parameter_bound_at_an_instance_in_the_wrong_unit():
    text = MSD.replace("elements:", """\
components:
  sd:
    parameters: {kk: {value: 1.0, unit: N/m}}
    ports: {a: s}
    elements: {s: {type: C, stiffness: "kk"}}
    bonds: []
elements:
  extra: {type: sd, kk: "m"}
  extra2: {type: sd, kk: 5.0}""").replace("bonds: [[force, v],", "bonds: [[v, extra.a], [v, extra2.a], [force, v],")
    err = error_of(text)
    assert err.message == ("instance 'extra': parameter 'kk': component 'sd' declares N/m, "
                           "but 'm' is kg")


def test_numbers_take_the_unit_their_place_needs():
    """A number alone is in its place's unit (stiffness: 200 is N/m); a number in a sum,
    comparison or product of a signal takes the other side's (t < 1 is 1 s, sin(2*t) 2 rad/s);
    zero agrees with everything."""
    text = MSD.replace('spring: {type: C, stiffness: "k"}', 'spring: {type: C, stiffness: "200"}')
    text = text.replace('F: {default: "F0", unit: N}',
                        'F: {default: "where(t < 1, 0, F0 * sin(2 * t) + 3 * F0)", unit: N}')
    text = text.replace('damper: {type: R, resistance: "c"}',
                        'damper: {type: R, effort: "c * f + 0.5 * c * f**3 / 1.0"}')
    assert check_text(text).bonds[0].domain == "mechanical translation"


def test_a_model_without_units_is_not_checked_and_compiles():
    """No unit anywhere: dimensions are all unknown, even where the structure disagrees
    (a stiffness equal to a mass), and the model compiles as it did."""
    import re

    bare = re.sub(r", unit: [^}]*\}", "}", MSD).replace(
        'spring: {type: C, stiffness: "k"}', 'spring: {type: C, stiffness: "where(t < 1, k, m)"}')
    assert "unit" not in bare
    rep = check_text(bare)
    assert all(b.effort is None and b.flow is None and b.domain == "unknown" for b in rep.bonds)
    from bgc.run.driver import compile_model

    c = compile_model(parse_text(bare, "bare.yaml"))
    assert "def rhs(" in c.source


def test_units_strict_wants_a_unit_on_every_parameter():
    strict = MSD.replace("name: msd\n", "name: msd\nunits: strict\n")
    assert check_text(strict).bonds  # all have units: fine
    err = error_of(strict.replace("c:  {value: 4.0, unit: N*s/m}", "c:  {value: 4.0}"))
    assert err.coord.line == 7
    assert err.message == ("parameter 'c' has no unit (the model says 'units: strict': every "
                           "parameter needs one)")
    with pytest.raises(ModelError, match="units: 'loose' is not one of"):
        parse_text(MSD.replace("name: msd\n", "name: msd\nunits: loose\n"), "m.yaml")


# ---------------------------------------------------------------------------------------------
# The example models, the compile paths and the command line

@pytest.mark.parametrize("path", MODELS, ids=lambda p: p.stem)
def test_every_example_model_checks_clean_with_every_bond_known(path):
    from bgc.format.parse import parse_file

    rep = check_units(build_graph(parse_file(path)))
    unknown = [b.id for b in rep.bonds if b.domain in ("unknown", "other")]
    assert not unknown, unknown


def test_domains_of_the_example_models():
    from bgc.format.parse import parse_file

    def domains(name):
        return {b.domain for b in check_units(build_graph(parse_file(ROOT / "models" / name))).bonds}

    assert domains("dc_motor.yaml") == {"electrical", "mechanical rotation"}
    assert domains("two_tanks.yaml") == {"hydraulic"}
    assert "thermal (temperature, heat flow)" in domains("motor_thermal.yaml")
    assert domains("3r2s.yaml") == {"mechanical translation", "mechanical rotation"}


def test_every_compile_path_checks_units(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(MSD.replace("unit: N*s/m", "unit: N/m"), encoding="utf-8")
    import bgc
    from bgc.run.driver import compile_file

    for run in (compile_file, bgc.check, bgc.compile):
        with pytest.raises(ModelError, match="R 'damper': resistance 'c' is N/m"):
            run(bad)


def test_cli_check_shows_units_and_refuses_a_mistake_in_one_line(tmp_path):
    def bgc(*args):
        return subprocess.run([sys.executable, "-m", "bgc", *map(str, args)],
                              capture_output=True, text=True, timeout=600)

    r = bgc("check", ROOT / "models" / "dc_motor.yaml", "--units")
    assert r.returncode == 0, r.stderr
    assert "b1  supply -> armature: electrical; effort V, flow A" in r.stdout
    assert "b5  motor -> shaft: mechanical rotation; effort N*m, flow 1/s" in r.stdout
    assert "units (" not in bgc("check", ROOT / "models" / "dc_motor.yaml").stdout
    bad = tmp_path / "bad.yaml"
    bad.write_text(MSD.replace('{expr: "f(mass)", unit: m/s}', '{expr: "f(mass)", unit: m}'))
    r = bgc("check", bad)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [
        f"{bad}:19:3: output 'velocity' is declared m, but its expression 'f(mass)' is m/s"]
