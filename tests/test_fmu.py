"""FMU export (FMI 2.0, Model Exchange and Co-Simulation), checked by a real importer (FMPy):
its validation, its simulations against the numpy module's (an independent implementation of
the same equations, in Python), bad calls through its low-level API."""
from __future__ import annotations

import subprocess
import sys
import textwrap
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")

from bgc import cbuild  # noqa: E402

pytestmark = pytest.mark.skipif(not cbuild.available(), reason="no C compiler")

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT / "models"


def _export(model, out, scene=None, kind="both"):
    from bgc.fmu import export_fmu

    return export_fmu(MODELS / model, out, scene_path=scene, kind=kind)


def _numpy_module(model):
    from bgc.compiler import compile_model
    from bgc.parse import parse_file
    from bgc.scene import load_module

    c = compile_model(parse_file(MODELS / model))
    return load_module(c.source, f"fmutest_{c.model.name}")


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    d = tmp_path_factory.mktemp("fmu")
    return {m: _export(f"{m}.yaml", d / f"{m}.fmu") for m in ("msd", "dc_motor", "two_tanks")}


def _xml(path):
    with zipfile.ZipFile(path) as zf:
        return zf.read("modelDescription.xml")


# ---------------------------------------------------------------------------------------------
# the unit itself


@pytest.mark.parametrize("model", ["msd", "dc_motor", "two_tanks"])
def test_fmpy_validation_finds_no_problem(fmus, model):
    from fmpy.validation import validate_fmu

    assert validate_fmu(str(fmus[model])) == []


def test_model_description_against_the_module(fmus):
    """Every state with its derivative, parameters with the module's defaults, inputs,
    outputs, the derivatives' dependencies exactly JAC_SPARSITY's rows, units."""
    mod = _numpy_module("dc_motor.yaml")
    md = fmpy.read_model_description(str(fmus["dc_motor"]))
    byname = {v.name: v for v in md.modelVariables}
    n = mod.N_STATES
    states = [byname[s] for s in mod.STATE_NAMES]
    for i, s in enumerate(mod.STATE_NAMES):
        d = byname[f"der({s})"]
        assert d.derivative is states[i]
    for k, v in mod.PARAM_DEFAULTS.items():
        assert byname[k].causality == "parameter" and float(byname[k].start) == v
        assert byname[k].unit == mod.PARAM_UNITS[k] or not mod.PARAM_UNITS[k]
    assert {v.name for v in md.modelVariables if v.causality == "input"} == set(mod.INPUT_NAMES)
    assert {v.name for v in md.modelVariables if v.causality == "output"} == set(mod.OUTPUT_NAMES)
    assert md.numberOfContinuousStates == n
    index = {id(v): k for k, v in enumerate(md.modelVariables)}
    for u in md.derivatives:
        i = mod.STATE_NAMES.index(u.variable.name[4:-1])
        deps = {d.name for d in u.dependencies if d.causality != "input"}
        assert deps == {mod.STATE_NAMES[j] for j in np.flatnonzero(mod.JAC_SPARSITY[i])}
    assert index  # (indices resolved by FMPy's own reader)
    units = {u.name for u in md.unitDefinitions}
    assert {u for u in mod.PARAM_UNITS.values() if u} <= units


def test_export_is_deterministic_and_the_guid_follows_the_model(tmp_path, fmus):
    a = _export("msd.yaml", tmp_path / "a.fmu")
    assert _xml(a) == _xml(fmus["msd"])
    assert a.read_bytes() == fmus["msd"].read_bytes()
    guid = ET.fromstring(_xml(a)).get("guid")
    other = ET.fromstring(_xml(fmus["two_tanks"])).get("guid")
    assert guid != other and len(guid) == 38


def test_sources_are_in_the_unit_and_rebuild(tmp_path, fmus):
    """sources/ holds everything to rebuild the library elsewhere (listed in SourceFiles)."""
    with zipfile.ZipFile(fmus["msd"]) as zf:
        zf.extractall(tmp_path)
    root = ET.fromstring((tmp_path / "modelDescription.xml").read_bytes())
    files = [f.get("name") for f in root.find("CoSimulation/SourceFiles")]
    assert "bgc_fmi2.c" in files and "bgc_fmu_model.c" in files
    cc = cbuild.compiler()
    out = tmp_path / "rebuilt.so"
    r = subprocess.run(cc + ["-O1", "-std=c99", "-fPIC", "-shared", "-o", str(out)]
                       + [str(tmp_path / "sources" / f) for f in files] + ["-lm"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert out.stat().st_size > 0


# ---------------------------------------------------------------------------------------------
# simulations against the numpy module

CASES = {
    # model: (changed parameters, stop time)
    "msd": ({"k": 300.0, "c": 2.5, "F0": 7.0}, 3.0),
    "dc_motor": (None, 0.5),
    "two_tanks": (None, 200.0),
}


def _params(model):
    p, _ = CASES[model]
    if p is not None:
        return p
    mod = _numpy_module(f"{model}.yaml")
    # a change to every parameter (10 %), through the FMI API
    return {k: v * 1.1 for k, v in mod.PARAM_DEFAULTS.items() if np.ndim(v) == 0}


@pytest.mark.parametrize("fmi_type", ["ModelExchange", "CoSimulation"])
@pytest.mark.parametrize("model", ["msd", "dc_motor", "two_tanks"])
def test_simulation_matches_the_numpy_module(fmus, model, fmi_type):
    mod = _numpy_module(f"{model}.yaml")
    p = _params(model)
    t1 = CASES[model][1]
    rtol = 1e-6
    r = fmpy.simulate_fmu(str(fmus[model]), fmi_type=fmi_type, stop_time=t1,
                          output_interval=t1 / 200, relative_tolerance=rtol, start_values=p,
                          output=list(mod.OUTPUT_NAMES))
    ref = mod.simulate((0.0, t1), t_eval=r["time"], method="Radau", rtol=1e-11, atol=1e-14, jac=False,
                       p=p)
    for name in mod.OUTPUT_NAMES:
        y, yr = r[name], ref.y[name]
        scale = np.max(np.abs(yr))
        assert scale > 0
        # the run's tolerance (relative to the signal's size) with room for the global error
        assert np.max(np.abs(y - yr)) <= 50 * rtol * scale, (name, np.max(np.abs(y - yr)))
    # the parameters changed: the reference with the defaults is far off
    dflt = mod.simulate((0.0, t1), t_eval=r["time"], method="Radau", rtol=1e-9, atol=1e-12, jac=False)
    assert any(np.max(np.abs(r[k] - dflt.y[k])) > 1e-3 * np.max(np.abs(dflt.y[k]))
               for k in mod.OUTPUT_NAMES)


@pytest.mark.parametrize("fmi_type", ["ModelExchange", "CoSimulation"])
def test_input_set_through_the_fmi_api(fmus, fmi_type):
    """msd's force F as an input signal: 10 N, then -5 N from t = 0.5 s (a step FMPy passes
    as an input event in Model Exchange and at the communication point in Co-Simulation)."""
    mod = _numpy_module("msd.yaml")
    sig = np.array([(0.0, 10.0), (0.5, 10.0), (0.5, -5.0), (2.0, -5.0)],
                   dtype=[("time", np.float64), ("F", np.float64)])
    r = fmpy.simulate_fmu(str(fmus["msd"]), fmi_type=fmi_type, stop_time=2.0,
                          output_interval=0.005, relative_tolerance=1e-6, input=sig,
                          output=["position", "velocity", "F"])
    r = r[np.r_[np.diff(r["time"]) > 0, True]]  # an event's time is recorded twice: keep after
    ref = mod.simulate((0.0, 2.0), t_eval=r["time"], method="Radau", rtol=1e-11, atol=1e-14, jac=False,
                       u={"F": lambda t: np.where(t < 0.5, 10.0, -5.0)}, breakpoints=[0.5])
    for name in ("position", "velocity"):
        scale = np.max(np.abs(ref.y[name]))
        assert np.max(np.abs(r[name] - ref.y[name])) <= 50e-6 * scale, name
    # and the input is what the FMU reports back
    after = r["time"] > 0.5 + 1e-9
    assert np.all(r["F"][after] == -5.0) and np.all(r["F"][r["time"] < 0.5 - 1e-9] == 10.0)
