"""SCAP: causal strokes checked against hand-assigned causality of textbook graphs."""
from __future__ import annotations

import pytest

from bgc.base.errors import ModelError
from bgc.core.causality import assign_causality
from bgc.core.graph import build_graph
from bgc.format.parse import parse_text


def caus(text):
    bg = build_graph(parse_text(text, "t.yaml"))
    return bg, assign_causality(bg)


HEAD = "bgc: 1\nname: m\nparameters: {a: 1.0, b: 2.0}\n"


def test_mass_spring_damper_is_integral():
    bg, c = caus(HEAD + """
elements:
  F: {type: Se, effort: a}
  v: {type: "1"}
  m: {type: I, inertia: a}
  k: {type: C, stiffness: b}
  r: {type: R, resistance: a}
bonds: [[F, v], [v, m], [v, k], [v, r]]
""")
    # by hand: the I sets the common flow; every other element sets its effort
    assert c.effort_by == {"b1": "F", "b2": "v", "b3": "k", "b4": "r"}
    assert not c.derivative and not c.arbitrary


def test_two_inertias_on_one_junction_name_both():
    with pytest.raises(ModelError) as e:
        caus(HEAD + """
elements:
  F: {type: Se, effort: a}
  v: {type: "1"}
  m1: {type: I, inertia: a}
  m2: {type: I, inertia: b}
bonds: [[F, v], [v, m1], [v, m2]]
""")
    assert "'m1'" in e.value.message and "'m2'" in e.value.message
    assert "derivative causality" in e.value.message
    assert e.value.coord.line == 9  # m2 line


def test_transformer_passes_causality_through():
    # Sf -> TF -> 1 with an I: the source's flow crosses the TF, so the I is derivative
    with pytest.raises(ModelError, match="derivative causality"):
        caus(HEAD + """
elements:
  S: {type: Sf, flow: a}
  T: {type: TF, ratio: b}
  v: {type: "1"}
  m: {type: I, inertia: a}
bonds: [[S, T], [T, v], [v, m]]
""")


def test_gyrator_turns_flow_into_effort():
    # Sf -> GY -> 0 with a C: the GY turns the imposed flow into an effort on the 0-junction,
    # which then imposes the C's effort: derivative C.
    with pytest.raises(ModelError, match="'c'"):
        caus(HEAD + """
elements:
  S: {type: Sf, flow: a}
  G: {type: GY, ratio: b}
  j: {type: "0"}
  c: {type: C, stiffness: a}
  r: {type: R, resistance: a}
bonds: [[S, G], [G, j], [j, c], [j, r]]
""")
    # and with a 1-junction and an I it is integral: the GY's effort feeds the I
    bg, c = caus(HEAD + """
elements:
  S: {type: Sf, flow: a}
  G: {type: GY, ratio: b}
  v: {type: "1"}
  m: {type: I, inertia: a}
bonds: [[S, G], [G, v], [v, m]]
""")
    assert not c.derivative
    assert c.effort_by["b2"] == "G"  # the gyrator sets the effort on its output bond


def test_resistor_loop_is_reported_as_arbitrary():
    bg, c = caus(HEAD + """
elements:
  E: {type: Se, effort: a}
  s: {type: "1"}
  r1: {type: R, resistance: a}
  n: {type: "0"}
  r2: {type: R, resistance: b}
  s2: {type: "1"}
  r3: {type: R, resistance: a}
  cap: {type: C, compliance: b}
bonds: [[E, s], [s, r1], [s, n], [n, r2], [n, s2], [s2, r3], [s2, cap]]
""")
    assert not c.derivative


def test_two_effort_sources_on_a_zero_junction_conflict():
    with pytest.raises(ModelError, match="causal conflict"):
        caus(HEAD + """
elements:
  E1: {type: Se, effort: a}
  E2: {type: Se, effort: b}
  j: {type: "0"}
  r: {type: R, resistance: a}
bonds: [[E1, j], [E2, j], [j, r]]
""")


def test_3r2s_is_all_integral():
    from pathlib import Path

    bg = build_graph(__import__("bgc.format.parse", fromlist=["parse_file"]).parse_file(
        Path(__file__).resolve().parents[1] / "models" / "3r2s.yaml"))
    c = assign_causality(bg)
    assert not c.derivative and not c.arbitrary and not c.open_bonds
    # every rigid-body MTF carries omega forward (its modulus [r x] is singular)
    for el in bg.elements:
        if el.type == "MTF":
            assert c.form(bg, el) == "flow forward", el.id
