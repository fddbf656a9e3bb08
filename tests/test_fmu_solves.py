"""FMUs of what the C backend handles beyond plain rhs code (issue 23, item 9): a table input
(the quarter car's measured road bump), and models that solve equations numerically: the half-wave
rectifier's Newton loop (a Shockley diode against a resistor) and the rigid double pendulum's
linear solves (derivative causality), under FMPy's Model Exchange (CVode), against the C
backend's own run of the same model (Radau at rtol 1e-10, the step bounded as the rectifier's
scene bounds it: its diode conducts for a millisecond of each cycle)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bgc.backends.c import build as cbuild

fmpy = pytest.importorskip("fmpy")
pytestmark = pytest.mark.skipif(not (cbuild.available() and cbuild.runtime_sources()),
                                reason="no C compiler")

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("model, t1", [("rectifier", 0.1),
                                       pytest.param("double_pendulum_rigid", 1.0,
                                                    marks=pytest.mark.slow)])
def test_model_exchange_agrees_with_the_c_backend(tmp_path, model, t1):
    from bgc.format.parse import parse_file
    from bgc.run.driver import build
    from bgc.run.fmu import export_fmu

    path = export_fmu(ROOT / "models" / f"{model}.yaml", tmp_path / f"{model}.fmu")
    b = build(model=parse_file(ROOT / "models" / f"{model}.yaml"), backend="c")
    assert b.backend == "c"
    mod = b.module
    rtol = 1e-8
    r = fmpy.simulate_fmu(str(path), fmi_type="ModelExchange", stop_time=t1,
                          output_interval=t1 / 200, relative_tolerance=rtol,
                          output=list(mod.STATE_NAMES))
    ref = mod.simulate((0.0, t1), t_eval=r["time"], method="Radau", rtol=1e-10, atol=1e-13,
                       max_step=1e-4)
    for i, s in enumerate(mod.STATE_NAMES):
        scale = float(np.max(np.abs(ref.x[i])))
        assert scale > 0
        assert np.max(np.abs(r[s] - ref.x[i])) <= 100 * rtol * scale, s
    if model == "rectifier":  # the capacitor charged through the diode: the loop ran
        assert float(np.max(r["cap.q"])) > 5e-3


def test_a_table_input_is_carried_into_the_unit(tmp_path):
    """The quarter car over its scene's measured bump (models/scenes/road_bump.csv, pchip):
    the unit holds the table, and its Model Exchange run under FMPy agrees with the C
    backend's run of the same scene; without the road (zr = 0) the C run is far off, so the
    agreement is the table's."""
    from bgc.format.scene import parse_scene
    from bgc.run.fmu import export_fmu
    from bgc.run.runner import scene_module

    scene = ROOT / "models" / "scenes" / "quarter_car_bump.yaml"
    sc = parse_scene(scene)
    path = export_fmu(ROOT / "models" / "quarter_car.yaml", tmp_path / "q.fmu",
                      scene_path=scene)
    backend, mod = scene_module(sc, None, "c")
    assert backend == "c"
    t1 = sc.t_span[1]
    rtol = 1e-8
    r = fmpy.simulate_fmu(str(path), fmi_type="ModelExchange", stop_time=t1,
                          output_interval=t1 / 400, relative_tolerance=rtol,
                          output=list(mod.STATE_NAMES))
    ref = mod.simulate(sc.t_span, t_eval=r["time"], method="Radau", rtol=1e-10, atol=1e-13,
                       max_step=1e-3)
    flat = mod.simulate(sc.t_span, t_eval=r["time"], method="Radau", rtol=1e-10, atol=1e-13,
                        max_step=1e-3, u={"zr": lambda t: 0.0 * np.asarray(t)})
    for i, s in enumerate(mod.STATE_NAMES):
        scale = float(np.max(np.abs(ref.x[i])))
        assert np.max(np.abs(r[s] - ref.x[i])) <= 100 * rtol * scale, s
    i = list(mod.STATE_NAMES).index("tyre.q")
    assert np.max(np.abs(flat.x[i] - ref.x[i])) > 1e3 * np.max(np.abs(r["tyre.q"] - ref.x[i]))
