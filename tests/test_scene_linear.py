"""A scene's module (what `bgc simulate` and `bgc compile --scene` compile) leaves out the
linearisation's B, C, D, which its runs never call: its input_jacobian, output_jacobian and
linearize say how to get them, and every way of linearising a scene still does, against the
closed form of an RC circuit. A bare model's module keeps them."""
from __future__ import annotations

import importlib.util
import subprocess
import sys

import numpy as np
import pytest

import bgc

# Vs -> R in series with C: q' = (Vs - q/C) / R, i = (Vs - q/C) / R.
R, C = 2.0, 0.5
RC = f"""bgc: 1
name: rc
parameters:
  R:  {{value: {R}}}
  C:  {{value: {C}}}
inputs:
  Vs: {{default: "3.0"}}
elements:
  src:  {{type: Se, effort: "Vs"}}
  res:  {{type: R, resistance: "R"}}
  cap:  {{type: C, compliance: "C"}}
  loop: {{type: "1"}}
bonds:
  - [src, loop]
  - [loop, res]
  - [loop, cap]
outputs:
  charge: "q(cap)"
  current: "f(res)"
"""
# closed forms: A = -1/(R C), B = 1/R; rows charge, current: C = [1, -1/(R C)], D = [0, 1/R]
A_, B_, C_, D_ = [[-1 / (R * C)]], [[1 / R]], [[1.0], [-1 / (R * C)]], [[0.0], [1 / R]]


def cli(*args):
    return subprocess.run([sys.executable, "-m", "bgc", *map(str, args)], capture_output=True,
                          text=True, timeout=600, check=False)


def load(path, name):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture
def files(tmp_path, monkeypatch):
    monkeypatch.setenv("BGC_CACHE_DIR", str(tmp_path / "cache"))
    model = tmp_path / "rc.yaml"
    model.write_text(RC)
    scene = tmp_path / "run.yaml"
    scene.write_text("bgc_scene: 1\nmodel: rc.yaml\nduration: 5\n")
    return model, scene


def check_closed_form(A, B, Cm, D):
    for got, want in ((A, A_), (B, B_), (Cm, C_), (D, D_)):
        assert np.allclose(np.asarray(got), want, rtol=1e-12, atol=1e-14), (got, want)


def test_a_scene_module_has_no_b_c_d_and_says_how_to_get_them(files, tmp_path):
    model, scene = files
    r = cli("compile", model, "--scene", scene, "-o", tmp_path / "scene_mod.py", "-q")
    assert r.returncode == 0, r.stderr
    text = (tmp_path / "scene_mod.py").read_text()
    for built in ("_B = np.zeros", "_C = np.zeros", "_D = np.zeros"):
        assert built not in text
    mod = load(tmp_path / "scene_mod.py", "scene_mod")
    assert mod.INPUT_LABELS == ("Vs",) and mod.OUTPUT_LABELS == ("charge", "current")
    res = mod.simulate((0.0, 5.0), rtol=1e-10, atol=1e-12)  # the runs work: q -> C Vs
    assert res.y["charge"][-1] == pytest.approx(C * 3.0 * (1 - np.exp(-5.0 / (R * C))),
                                                rel=1e-7)
    for call in (lambda: mod.linearize(0.0, mod.X0), lambda: mod.input_jacobian(0.0, mod.X0),
                 lambda: mod.output_jacobian(0.0, mod.X0)):
        with pytest.raises(NotImplementedError) as exc:
            call()
        msg = str(exc.value)
        assert "bgc linearize SCENE" in msg and "without a scene" in msg


def test_a_bare_model_keeps_them(files, tmp_path):
    model, _ = files
    r = cli("compile", model, "-o", tmp_path / "bare_mod.py", "-q")
    assert r.returncode == 0, r.stderr
    mod = load(tmp_path / "bare_mod.py", "bare_mod")
    check_closed_form(*mod.linearize(0.0, mod.X0))


def test_every_way_of_linearising_a_scene_still_does(files, tmp_path):
    model, scene = files
    sim = cli("simulate", scene, "--backend", "numpy", "-q", "--out", tmp_path / "sim")
    assert sim.returncode == 0, sim.stderr
    r = cli("linearize", scene, "--out", tmp_path / "lin", "-q")
    assert r.returncode == 0, r.stderr
    got = np.load(next((tmp_path / "lin").glob("*.npz")))
    check_closed_form(got["A"], got["B"], got["C"], got["D"])
    for target in (scene, bgc.compile(model, scene=scene)):
        lin = bgc.linearize(target)
        check_closed_form(lin.A, lin.B, lin.C, lin.D)
