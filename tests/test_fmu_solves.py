"""FMUs of models that solve equations numerically (issue 23, item 9): the half-wave
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


def test_table_inputs_are_still_refused_with_one_line(tmp_path):
    from bgc.base.errors import ModelError
    from bgc.run.fmu import export_fmu

    with pytest.raises(ModelError, match="table inputs"):
        export_fmu(ROOT / "models" / "quarter_car.yaml", tmp_path / "q.fmu",
                   scene_path=ROOT / "models" / "scenes" / "quarter_car_bump.yaml")
