"""Plot axes carry units from the checked dimensions: an output's declared unit, else the one
inferred from the bonds (a flow on a mechanical bond is m/s), time in s. The labels are read
from the figures' matplotlib objects; the expected units are written by hand."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("matplotlib")

import bgc  # noqa: E402
from bgc.run.plots import figure_path3d, figure_time, pyplot  # noqa: E402

OSCILLATOR = """\
bgc: 1
name: labelled
parameters:
  m: {value: 2.0, unit: kg}
  k: {value: 200.0, unit: N/m}
elements:
  mass: {type: I, inertia: m, initial: "m * 0.1"}
  spring: {type: C, stiffness: k}
  v: {type: "1"}
bonds: [[v, mass], [v, spring]]
outputs:
  speed: "f(mass)"
  stretch: "q(spring)"
  force: {expr: "e(spring)", unit: kN}
  energy: "e(spring) * q(spring) / 2"
"""


@pytest.fixture(scope="module")
def oscillator():
    return bgc.compile(OSCILLATOR)


def test_output_units_are_declared_or_inferred(oscillator):
    assert dict(oscillator.OUTPUT_UNITS) == {"speed": "m/s", "stretch": "m", "force": "kN",
                                             "energy": "N*m"}


def test_time_figure_labels_carry_the_units(oscillator):
    t, x, y = oscillator.simulate((0.0, 1.0), dt=0.1)
    names = ["speed", "stretch", "force", "energy"]
    fig = figure_time(t, y, names, units=oscillator.OUTPUT_UNITS)
    try:
        axes = fig.get_axes()
        assert [ax.get_ylabel() for ax in axes] == ["speed [m/s]", "stretch [m]", "force [kN]",
                                                    "energy [N*m]"]
        assert axes[-1].get_xlabel() == "t [s]"
    finally:
        pyplot().close(fig)


def test_path3d_axes_carry_the_paths_unit():
    model = bgc.compile("""\
bgc: 1
name: spatial
parameters:
  m: {value: 1.0, unit: kg}
  k: {value: 4.0, unit: N/m}
  v0: {value: 1.0, unit: m/s}
elements:
  mass: {type: I, inertia: m, initial: "m * v0 * [0, 1, 0.5]"}
  spring: {type: C, stiffness: k}
  v: {type: "1"}
bonds:
  - {from: v, to: mass, n: 3}
  - {from: v, to: spring, n: 3}
outputs: {place: "q(spring)"}
""")
    assert dict(model.OUTPUT_UNITS) == {"place": "m"}
    t, x, y = model.simulate((0.0, 1.0), dt=0.1)
    assert np.shape(y["place"])[0] == 3
    fig = figure_path3d(t, y, ["place"], units=model.OUTPUT_UNITS)
    try:
        view, top = fig.get_axes()[:2]
        assert (view.get_xlabel(), view.get_ylabel(), view.get_zlabel()) == (
            "X0 [m]", "Y0 [m]", "Z0 [m]")
        assert (top.get_xlabel(), top.get_ylabel()) == ("X0 [m]", "Y0 [m]")
    finally:
        pyplot().close(fig)


def test_an_output_the_model_leaves_open_has_no_unit():
    """No unit anywhere: nothing is inferred (the model is not checked), the label is bare."""
    model = bgc.compile(OSCILLATOR.replace("{value: 2.0, unit: kg}", "2.0")
                        .replace("{value: 200.0, unit: N/m}", "200.0")
                        .replace('{expr: "e(spring)", unit: kN}', '"e(spring)"'))
    assert set(model.OUTPUT_UNITS.values()) == {""}
    t, x, y = model.simulate((0.0, 1.0), dt=0.5)
    fig = figure_time(t, y, ["speed"], units=model.OUTPUT_UNITS)
    try:
        assert fig.get_axes()[0].get_ylabel() == "speed"
    finally:
        pyplot().close(fig)
