"""The Python builder (bgc.builder): models built in Python are their YAML twins (the same
generated module), write themselves out as YAML the reader takes back, and report every
mistake the reader reports, at the line of this file that made it."""
from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import pytest

import bgc
from bgc.base.errors import Coord
from bgc.format.parse import parse_file, parse_text
from bgc.run.driver import compile_source

ROOT = Path(__file__).resolve().parent.parent
HERE = str(Path(__file__).resolve())


def here(offset: int = 1) -> int:
    """The line of this file ``offset`` lines below the caller's."""
    return sys._getframe(1).f_lineno + offset


def msd_builder() -> bgc.Builder:
    """models/msd.yaml, written as calls."""
    b = bgc.Builder("msd", description="mass-spring-damper under a force step", units="strict")
    b.parameter("m", 2.0, unit="kg", min=0, description="moving mass")
    b.parameter("k", 200.0, unit="N/m", min=0, description="spring stiffness")
    b.parameter("c", 4.0, unit="N*s/m", min=0, description="viscous damping coefficient")
    b.parameter("F0", 10.0, unit="N", description="step force amplitude")
    b.input("F", "F0", shape=[], unit="N")
    b.element("force", "Se", effort="F")
    b.element("mass", "I", inertia="m")
    b.element("spring", "C", stiffness="k")
    b.element("damper", "R", resistance="c")
    b.element("v", "1")
    b.bond("force", "v")
    for other in ("mass", "spring", "damper"):
        b.bond("v", other)
    b.output("position", "q(spring)", unit="m")
    b.output("velocity", "f(mass)", unit="m/s")
    b.output("spring_force", "e(spring)", unit="N")
    return b


def dc_motor_builder() -> bgc.Builder:
    """models/dc_motor.yaml, written as calls: a gyrator between two junctions."""
    b = bgc.Builder("dc_motor", description="DC motor with inertia, viscous friction and a "
                                            "constant load torque", units="strict")
    for name, value, unit, lo, text in (
            ("V0", 12.0, "V", None, "supply voltage"),
            ("R_a", 2.0, "ohm", 0, "armature resistance"),
            ("L_a", 5.0e-3, "H", 0, "armature inductance"),
            ("K", 0.05, "N*m/A", 0, "motor constant (= V*s/rad)"),
            ("J_r", 1.0e-4, "kg*m^2", 0, "rotor + load inertia"),
            ("b", 1.0e-5, "N*m*s/rad", 0, "viscous friction"),
            ("tau_L", 0.02, "N*m", None, "load torque (opposes the rotation)")):
        b.parameter(name, value, unit=unit, min=lo, description=text)
    b.input("V", "V0", shape=[], unit="V")
    b.input("TL", "tau_L", shape=[], unit="N*m")
    b.element("supply", "Se", effort="V")
    b.element("armature", "1")
    b.element("winding_R", "R", resistance="R_a")
    b.element("winding_L", "I", inertia="L_a")
    b.element("motor", "GY", ratio="K")
    b.element("shaft", "1")
    b.element("rotor", "I", inertia="J_r")
    b.element("bearing", "R", resistance="b")
    b.element("load", "Se", effort="TL")
    for src, dst in (("supply", "armature"), ("armature", "winding_R"),
                     ("armature", "winding_L"), ("armature", "motor"), ("motor", "shaft"),
                     ("shaft", "rotor"), ("shaft", "bearing"), ("shaft", "load")):
        b.bond(src, dst)
    b.output("current", "f(armature)", unit="A")
    b.output("speed", "f(shaft)", unit="rad/s")
    b.output("back_emf", "e(b4)", unit="V")
    b.output("torque", "e(b5)", unit="N*m")
    b.output("power_in", "power(supply)", unit="W")
    return b


def module_text(model) -> str:
    """The generated numpy module without the two lines that name its source (file, hash)."""
    src = compile_source(model).source
    return "\n".join(line for line in src.splitlines()
                     if not line.startswith(("Source: ", "MODEL_HASH = ")))


def no_places(obj):
    """A model's data with every place (Coord), file name and source hash left out."""
    if isinstance(obj, Coord):
        return None
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return (type(obj).__name__,) + tuple(
            (f.name, no_places(getattr(obj, f.name))) for f in dataclasses.fields(obj)
            if f.name not in ("file", "source_hash"))
    if isinstance(obj, (tuple, list)):
        return tuple(no_places(x) for x in obj)
    return obj


@pytest.mark.parametrize("make, yaml_file", [(msd_builder, "msd.yaml"),
                                             (dc_motor_builder, "dc_motor.yaml")])
def test_a_model_built_in_python_is_its_yaml_twin(make, yaml_file):
    built = make().build()
    from_yaml = parse_file(ROOT / "models" / yaml_file)
    assert no_places(built) == no_places(from_yaml)
    assert module_text(built) == module_text(from_yaml)


@pytest.mark.parametrize("make", [msd_builder, dc_motor_builder])
def test_the_yaml_a_builder_writes_reads_back_as_the_same_model(make):
    b = make()
    again = parse_text(b.to_yaml(), "<twin>")
    built = b.build()
    assert no_places(again) == no_places(built)
    assert again.source_hash == built.source_hash  # the hash is the written text's


def test_places_are_the_calls_in_this_file():
    b = bgc.Builder("placed")
    line = here()
    b.element("mass", "I", inertia="2.0")
    b.element("v", "1")
    b.bond("v", "mass")
    m = b.build()
    assert m.body.elements[0].coord == Coord(HERE, line, 5)
    assert m.body.bonds[0].coord.line == line + 2
    assert m.coord.line == line - 2 and m.file == HERE


def test_compile_and_check_take_a_builder():
    msd = bgc.compile(msd_builder())
    t, x, y = msd.simulate((0.0, 20.0), dt=0.5)
    assert abs(float(y["position"][-1]) - 10.0 / 200.0) < 1e-4  # the static deflection F0/k
    assert bgc.check(dc_motor_builder()).states == ("winding_L.p", "rotor.p")


def located(b, check=False) -> bgc.BgcError:
    with pytest.raises(bgc.BgcError) as info:
        bgc.check(b) if check else b.build()
    err = info.value
    assert str(err).startswith(f"{err.coord.file}:{err.coord.line}:{err.coord.column}: ")
    return err


def test_an_invalid_expression_is_located_at_its_call():
    b = msd_builder()
    line = here()
    b.element("extra", "I", inertia="m*")
    err = located(b)
    assert (err.coord.file, err.coord.line) == (HERE, line)
    assert err.message == "element 'extra' (inertia): invalid expression 'm*': invalid syntax"


def test_a_duplicate_name_is_located_at_the_second_call():
    b = msd_builder()
    line = here()
    b.element("mass", "C", stiffness="k")
    err = located(b)
    assert (err.coord.file, err.coord.line) == (HERE, line)
    assert "duplicate key 'mass'" in err.message


def test_a_bond_to_nothing_is_located_at_the_bond():
    b = msd_builder()
    line = here()
    b.bond("v", "nowhere")
    err = located(b, check=True)
    assert (err.coord.file, err.coord.line) == (HERE, line)
    assert "nowhere" in err.message


def test_a_unit_mistake_is_located_at_the_parameter():
    b = bgc.Builder("wrong_unit")
    b.parameter("m", 2.0, unit="kg")
    line = here()
    b.parameter("c", 4.0, unit="N/m")  # a damper's coefficient is N*s/m
    b.parameter("k", 200.0, unit="N/m")
    b.element("mass", "I", inertia="m")
    b.element("spring", "C", stiffness="k")
    b.element("damper", "R", resistance="c")
    b.element("v", "1")
    for other in ("mass", "spring", "damper"):
        b.bond("v", other)
    err = located(b, check=True)
    assert err.coord.file == HERE and err.coord.line in (line, line + 4)
    assert "N/m" in err.message and "N*s/m" in err.message


def test_strict_units_want_a_unit_on_every_parameter():
    b = bgc.Builder("strict", units="strict")
    line = here()
    b.parameter("m", 2.0)
    b.element("mass", "I", inertia="m")
    b.element("spring", "C", stiffness="3.0")
    b.element("v", "1")
    b.bond("v", "mass")
    b.bond("v", "spring")
    err = located(b, check=True)
    assert (err.coord.file, err.coord.line) == (HERE, line)
    assert "'m'" in err.message and "unit" in err.message


@pytest.mark.parametrize("what, name", [
    ("parameter", "__import__"), ("parameter", "class"), ("parameter", "x; import os"),
    ("parameter", "a\n"), ("parameter", "t"), ("element", "a__b"), ("element", "1abc"),
    ("output", "print"), ("model", "os.system")])
def test_hostile_names_are_refused_as_the_reader_refuses_them(what, name):
    b = bgc.Builder(name if what == "model" else "hostile")
    b.element("v", "1")
    b.element("mass", "I", inertia="1.0")
    b.bond("v", "mass")
    if what == "parameter":
        b.parameter(name, 1.0)
    elif what == "element":
        b.element(name, "C", stiffness="1.0")
    elif what == "output":
        b.output(name, "f(mass)")
    err = located(b)
    assert err.coord.file == HERE
    with pytest.raises(bgc.BgcError) as twin:  # the same model as YAML: the same message
        parse_text(b.to_yaml(), "<twin>")
    assert err.message == twin.value.message
    assert "invalid" in err.message and repr(name) in err.message


def test_a_value_that_is_not_data_is_refused_at_its_call():
    b = bgc.Builder("objects")
    line = here()
    b.parameter("m", object())
    err = located(b)
    assert err.coord.line == line and "cannot be part of a model" in err.message
    with pytest.raises(bgc.BgcError) as info:  # nor can it be written out
        b.to_yaml()
    assert info.value.coord.line == line


def test_numpy_values_are_numbers():
    import numpy as np

    b = bgc.Builder("arrays")
    b.parameter("K", np.array([[2.0, 1.0], [1.0, 3.0]]), unit="N/m")
    b.parameter("m", np.float64(2.5), unit="kg")
    b.parameter("n", np.int64(3), unit="1")
    b.element("mass", "I", inertia="m")
    b.element("spring", "C", stiffness="K")
    b.element("v", "1")
    b.bond("v", "mass", n=2)
    b.bond("v", "spring", n=2)
    params = {p.name: p.value for p in b.build().body.params}
    assert params == {"K": ((2.0, 1.0), (1.0, 3.0)), "m": 2.5, "n": 3.0}
    again = parse_text(b.to_yaml(), "<twin>")
    assert no_places(again) == no_places(b.build())


COMPONENT_YAML = """\
bgc: 1
name: chain
parameters:
  k: {value: 100.0, unit: N/m}
components:
  cell:
    parameters:
      m: {value: 1.0, unit: kg}
    ports: {left: j, right: s}
    elements:
      j: {type: "1"}
      mass: {type: I, inertia: "m", initial: "0.5 * m"}
      s: {type: "0"}
    bonds:
      - [j, mass]
      - [j, s]
elements:
  wall: {type: Sf, flow: "0"}
  c1: {type: cell, m: "2.0"}
  c2: {type: cell}
  spring: {type: C, stiffness: "k"}
  end: {type: C, stiffness: "k"}
bonds:
  - [wall, c1.left]
  - [c1.right, spring]
  - {from: c1.right, to: c2.left, name: link}
  - [c2.right, end]
outputs:
  v2: {expr: "f(c2.mass)", unit: m/s}
"""


def chain_builder(cell=None) -> bgc.Builder:
    b = bgc.Builder("chain")
    b.parameter("k", 100.0, unit="N/m")
    if cell is None:
        cell = bgc.Component({"left": "j", "right": "s"})
        cell.parameter("m", 1.0, unit="kg")
        cell.element("j", "1")
        cell.element("mass", "I", inertia="m", initial="0.5 * m")
        cell.element("s", "0")
        cell.bond("j", "mass")
        cell.bond("j", "s")
        b.component("cell", cell)
    b.element("wall", "Sf", flow="0")
    b.element("c1", "cell", m="2.0")
    b.element("c2", "cell")
    b.element("spring", "C", stiffness="k")
    b.element("end", "C", stiffness="k")
    b.bond("wall", "c1.left")
    b.bond("c1.right", "spring")
    assert b.bond("c1.right", "c2.left", name="link") == "link"
    assert b.bond("c2.right", "end") == "b4"
    b.output("v2", "f(c2.mass)", unit="m/s")
    return b


def test_components_built_in_python_are_their_yaml_twin():
    b = chain_builder()
    twin = parse_text(COMPONENT_YAML, "<twin>")
    assert no_places(b.build()) == no_places(twin)
    assert module_text(b.build()) == module_text(twin)
    assert no_places(parse_text(b.to_yaml(), "<again>")) == no_places(twin)


def test_components_imported_from_a_file(tmp_path):
    lib = tmp_path / "cells.yaml"
    lib.write_text(COMPONENT_YAML)  # its component `cell`
    b = bgc.Builder("chain")
    b.imports(str(lib))
    b.parameter("k", 100.0, unit="N/m")
    b.element("wall", "Sf", flow="0")
    b.element("c1", "cell", m="2.0")
    b.element("c2", "cell")
    b.element("spring", "C", stiffness="k")
    b.element("end", "C", stiffness="k")
    b.bond("wall", "c1.left")
    b.bond("c1.right", "spring")
    b.bond("c1.right", "c2.left", name="link")
    b.bond("c2.right", "end")
    b.output("v2", "f(c2.mass)", unit="m/s")
    assert module_text(b.build()) == module_text(parse_text(COMPONENT_YAML, "<twin>"))
    line = here()
    b.imports(str(tmp_path / "missing.yaml"))
    err = located(b)
    assert (err.coord.file, err.coord.line) == (HERE, line)


def test_events_and_modes_built_in_python_are_the_bouncing_balls_twin():
    b = bgc.Builder("bouncing_ball", description="a ball bouncing on a rigid floor (an impact "
                                                 "event with restitution)", units="strict")
    b.parameter("m", 0.1, unit="kg", min=0, description="mass of the ball")
    b.parameter("g", 9.81, unit="m/s^2", description="gravitational acceleration")
    b.parameter("h0", 1.0, unit="m", description="initial height")
    b.parameter("e_r", 0.8, unit="1", min=0, max=1, description="coefficient of restitution")
    b.element("gravity", "Se", effort="-m*g")
    b.element("ball", "I", inertia="m")
    b.element("v", "1")
    b.bond("gravity", "v")
    b.bond("v", "ball")
    b.state("h", "f(ball)", initial="h0", unit="m")
    b.event("impact", when="h", direction="falling", do={"p(ball)": "-e_r*p(ball)"})
    b.output("height", "h", unit="m")
    b.output("velocity", "f(ball)", unit="m/s")
    built = b.build()
    assert no_places(built) == no_places(parse_file(ROOT / "models" / "bouncing_ball.yaml"))
    assert no_places(parse_text(b.to_yaml(), "<twin>")) == no_places(built)
    b.mode("latched", 0)
    assert parse_text(b.to_yaml(), "<twin>").modes == ("latched",) == b.build().modes
