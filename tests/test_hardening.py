"""Issue 21, the parts that are not command lines of the corpus (tests/fuzz/cases_issue21.py):
the Python API's text input, the study's tolerance bounds, a compiler that runs but fails (and
the fall-back of simulate), renamed C names that would collide, a diverging run on the numpy
backend's implicit methods, and a parameter power that overflows."""
from __future__ import annotations

import os
import shutil
import stat
from pathlib import Path

import numpy as np
import pytest

import bgc
from bgc.backends.load import load_module
from bgc.base.errors import ModelError
from bgc.format.parse import parse_text
from bgc.run.driver import compile_model
from bgc.studies.accuracy import parse_tols

ROOT = Path(__file__).resolve().parents[1]
MSD = (ROOT / "models" / "msd.yaml").read_text(encoding="utf-8")
HAVE_CC = shutil.which("cc") is not None or bool(os.environ.get("CC"))


def test_lone_surrogate_in_model_text_is_a_located_bgc_error():
    text = MSD.replace("mass-spring-damper", "mass\ud800spring")
    line = text[:text.index("\ud800")].count("\n") + 1
    with pytest.raises(bgc.BgcError) as err:
        bgc.compile(text)
    assert err.value.coord.line == line and "surrogate" in err.value.message


@pytest.mark.parametrize("text", ["1e-3:1e-300", "1e-3,1e-15", "1e-16"])
def test_tols_below_double_precision_are_refused(text):
    with pytest.raises(ModelError, match="1e-14"):
        parse_tols(text)


def test_tols_at_the_bound_are_accepted():
    assert parse_tols("1e-3:1e-14")[-1] == pytest.approx(1e-14)
    assert len(parse_tols("1e-3:1e-14")) == 12


BALL = """bgc: 1
name: ball
parameters: {m: 1.0, k: 1.0e6, g: 9.81}
elements:
  grav: {type: Se, effort: "-m*g"}
  mass: {type: I, inertia: "m"}
  floor: {type: C, effort: "k*max(-q(floor), 0)", initial: 0.01}
  v: {type: "1"}
bonds:
  - [grav, v]
  - [v, mass]
  - [v, floor]
"""


@pytest.mark.parametrize("method", ["Radau", "BDF"])
def test_diverging_run_is_a_nonfinite_error_before_any_linear_solve(method):
    """The floor's sign is wrong: below q = 0 the 'restoring' force pushes down, q grows like
    exp(1000 t) (k/m = 1e6) and leaves the double range near t = 0.05 + 709/1000 s. The run
    ends in the module's NonFiniteError naming a state, never scipy's ValueError."""
    mod = load_module(compile_model(parse_text(BALL, "ball.yaml")).source, f"ball_{method}")
    with pytest.raises(mod.NonFiniteError) as err:
        mod.simulate((0.0, 1.0), method=method, rtol=1e-2, atol=1e-2)
    assert 0.5 < err.value.t < 1.0
    assert "mass.p" in str(err.value) or "floor.q" in str(err.value)


def test_a_power_that_overflows_is_inf_not_overflow_error():
    """k**900 with k = 200 is beyond the double range: the module's functions give inf (and
    bgc compile's start check a located error), never Python's OverflowError."""
    text = MSD.replace('spring_force: {expr: "e(spring)", unit: N}',
                       'spring_force: {expr: "k**900*q(spring)"}')  # no unit: kg^900...
    mod = load_module(compile_model(parse_text(text, "m.yaml")).source, "pow900")
    with np.errstate(all="ignore"):
        y = mod.outputs(0.0, np.array([0.0, 0.1]))
    assert np.isinf(y["spring_force"])
    with np.errstate(all="ignore"):
        assert np.isinf(mod.outputs(0.0, np.array([0.0, 0.1]), {"k": 300.0})["spring_force"])


BAD_CC = "#!/bin/sh\n[ \"$1\" = --version ] && { echo badcc 1.0; exit 0; }\necho 'error: no' >&2\nexit 1\n"


@pytest.fixture
def bad_cc(tmp_path, monkeypatch):
    cc = tmp_path / "badcc"
    cc.write_text(BAD_CC)
    cc.chmod(cc.stat().st_mode | stat.S_IXUSR)
    monkeypatch.setenv("CC", str(cc))
    monkeypatch.setenv("BGC_CACHE_DIR", str(tmp_path / "cache"))
    from bgc.backends.c import build as cbuild

    cbuild._identity.cache_clear()
    yield cc
    cbuild._identity.cache_clear()


def test_compiler_that_fails_is_one_line_and_writes_nothing(bad_cc, tmp_path):
    from bgc.backends.c.build import CompilerFailed
    from bgc.backends.load import write_c

    c = compile_model(parse_text(MSD, "msd.yaml"))
    out = tmp_path / "msd_c"
    with pytest.raises(CompilerFailed) as err:
        write_c(c, out)
    assert "\n" not in err.value.message and "badcc" in err.value.message
    assert not out.exists()


def test_simulate_falls_back_to_numpy_when_the_compiler_fails(bad_cc, tmp_path):
    from bgc.format.scene import parse_scene
    from bgc.run.runner import scene_module

    scene = tmp_path / "s.yaml"
    scene.write_text(f"bgc_scene: 1\nmodel: {ROOT / 'models' / 'msd.yaml'}\nduration: 0.1\n")
    said = []
    backend, mod = scene_module(parse_scene(scene), said.append, backend="c", use_cache=False)
    assert backend == "numpy" and any("badcc" in s for s in said)
    assert np.isfinite(mod.rhs(0.0, mod.X0)).all()


@pytest.mark.skipif(not HAVE_CC, reason="no C compiler")
def test_c_names_that_would_collide_after_renaming(tmp_path):
    """main (a C library name, renamed) beside m_main and bgcu_main: three distinct C names,
    and the C library's rhs equals the numpy module's."""
    from bgc.backends.load import write_c

    text = (MSD.replace("m:  {value: 2.0", "main: {value: 2.0").replace('inertia: "m"', 'inertia: "main"')
            .replace("k:  {value: 200.0", "m_main: {value: 200.0").replace('stiffness: "k"', 'stiffness: "m_main"')
            .replace("c:  {value: 4.0", "bgcu_main: {value: 4.0").replace('resistance: "c"', 'resistance: "bgcu_main"'))
    c = compile_model(parse_text(text, "collide.yaml"))
    path = write_c(c, tmp_path / "out")
    cmod = load_module_file(path)
    npmod = load_module(c.source, "collide_np")
    x = np.array([0.4, -0.1])
    np.testing.assert_allclose(cmod.rhs(0.0, x), npmod.rhs(0.0, x), rtol=1e-14)
    r = cmod.simulate((0.0, 0.5), method="Radau")
    q = npmod.simulate((0.0, 0.5), method="Radau", t_eval=r.t)
    np.testing.assert_allclose(r.x, q.x, atol=1e-5)


def load_module_file(path):
    import importlib.util

    spec = importlib.util.spec_from_file_location(f"m_{abs(hash(str(path)))}", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_power_chain_is_a_located_error_naming_the_exponent():
    """((k**2)**2)... 150 deep: sympy merges it into k**(2**150); refused where it is written
    (a model without units, so that no dimension check answers first)."""
    law = "k"
    for _ in range(150):
        law = f"({law})**2"
    text = BALL.replace('effort: "k*max(-q(floor), 0)"', f'effort: "{law}*q(floor)"')
    with pytest.raises(ModelError) as err:
        compile_model(parse_text(text, "chain.yaml"))
    assert "chain of powers" in err.value.message and err.value.coord.line == 7
