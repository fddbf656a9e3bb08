"""What a newcomer's first runs trip over (issue 23): max_steps from a scene and from the
command line, `bgc equations` on every model, `bgc simulate MODEL.yaml`, --t-end.

References: the C step loop's own step count (a budget of 5 steps cannot cover a 5 s run that
takes hundreds), the compiled modules' state lists (the equations must have the same states as
the module `bgc compile` writes), and the closed form of the mass-spring-damper's static
deflection (the run of the model alone must settle there).
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bgc.backends.c import build as cbuild
from bgc.format.scene import MODEL_T_END, is_model_file, model_scene, parse_scene

ROOT = Path(__file__).resolve().parents[1]
MODELS = sorted((ROOT / "models").glob("*.yaml"))
HAS_C = cbuild.available() and bool(cbuild.runtime_sources())


def _bgc(*args, cache_dir, timeout=600):
    env = {"BGC_CACHE_DIR": str(cache_dir), "PYTHONPATH": str(ROOT / "src"),
           "PATH": "/usr/bin:/bin"}
    import os

    env = {**os.environ, **env}
    return subprocess.run([sys.executable, "-m", "bgc", *map(str, args)], capture_output=True,
                          text=True, env=env, timeout=timeout, cwd=ROOT)


def _scene(tmp_path, solver: str, model="msd.yaml") -> Path:
    path = tmp_path / "s.yaml"
    path.write_text(f"bgc_scene: 1\nmodel: {ROOT / 'models' / model}\nduration: 5.0\n"
                    f"solver: {solver}\n")
    return path


def test_scene_max_steps_is_read_and_checked(tmp_path):
    sc = parse_scene(_scene(tmp_path, "{method: Radau, max_steps: 123}"))
    assert sc.max_steps == 123
    assert parse_scene(_scene(tmp_path, "{method: Radau}")).max_steps == 50_000
    for bad, what in (("0", "outside"), ("2.5", "whole number"), ("10000000000", "outside")):
        from bgc.base.errors import ModelError

        with pytest.raises(ModelError, match=what) as e:
            parse_scene(_scene(tmp_path, f"{{max_steps: {bad}}}"))
        assert e.value.coord.line == 4


@pytest.mark.skipif(not HAS_C, reason="no C compiler")
def test_max_steps_from_scene_and_command_line(tmp_path):
    """The C step loop counts step attempts: 5 cannot cover the run (exit 1, the message says
    max_steps), --max-steps 1000 on the command line overrides the scene and the run completes;
    the record of that run replays only with the same option."""
    scene = _scene(tmp_path, "{method: Radau, max_steps: 5, backend: c}")
    cache = tmp_path / "cache"
    few = _bgc("simulate", scene, cache_dir=cache)
    assert few.returncode == 1 and "max_steps = 5" in few.stderr, few.stderr
    many = _bgc("simulate", scene, "--max-steps", "1000", "--out", tmp_path / "a.npz",
                cache_dir=cache)
    assert many.returncode == 0, many.stderr
    again = _bgc("simulate", scene, "--max-steps", "1000", "--out", tmp_path / "b.npz",
                 cache_dir=cache)
    assert again.returncode == 0 and "run record" in again.stderr
    a, b = np.load(tmp_path / "a.npz"), np.load(tmp_path / "b.npz")
    np.testing.assert_array_equal(a["position"], b["position"])
    plain = _bgc("simulate", scene, cache_dir=cache)  # not the record of --max-steps 1000
    assert plain.returncode == 1 and "max_steps = 5" in plain.stderr
    bad = _bgc("simulate", scene, "--max-steps", "0", cache_dir=cache)
    assert bad.returncode == 2 and bad.stderr.strip().count("\n") == 0
    assert "--max-steps 0" in bad.stderr


@pytest.mark.parametrize("path", MODELS, ids=[p.stem for p in MODELS])
def test_equations_on_every_model(path):
    """bgc.equations (what `bgc equations` prints) accepts every model in models/, rigid
    connections included, with the states of the compiled golden module."""
    import bgc

    eq = bgc.equations(str(path))
    assert len(eq.derivatives) == len(eq.states) > 0
    golden = {}
    for g in (ROOT / "generated").glob("*.py"):
        text = g.read_text()
        if f"Source: {path.name} (" in text[:500]:
            golden = {"n": int(text.split("\nN_STATES = ", 1)[1].split("\n", 1)[0])}
    if golden:
        assert len(eq.states) == golden["n"]


def test_equations_cli_on_a_rigid_model(tmp_path):
    r = _bgc("equations", ROOT / "models" / "double_pendulum_rigid.yaml", cache_dir=tmp_path)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    # four independent states (the rotational momenta and the angles); the translational
    # inertias are eliminated, so they have no derivative line
    assert sum(1 for ln in lines if ln.startswith("d") and "/dt = " in ln) == 4
    assert not any(ln.startswith("dp_rod1__It") for ln in lines)


def test_model_file_is_a_scene_of_its_defaults():
    msd = ROOT / "models" / "msd.yaml"
    assert is_model_file(msd) and not is_model_file(ROOT / "models" / "scenes" / "msd_step.yaml")
    sc = model_scene(msd)
    assert sc.t_span == (0.0, MODEL_T_END) and sc.model_path == str(msd) and not sc.inputs


def test_simulate_a_model_file(tmp_path):
    """`bgc simulate MODEL.yaml` says it is a model and runs its defaults (10 s, or --t-end):
    the mass-spring-damper under its default force settles at F/k."""
    import yaml

    model = ROOT / "models" / "msd.yaml"
    r = _bgc("simulate", model, "--out", tmp_path / "m.npz", cache_dir=tmp_path / "c")
    assert r.returncode == 0, r.stderr
    assert "is a model" in r.stderr and "10 s" in r.stderr
    d = np.load(tmp_path / "m.npz")
    assert d["t"][0] == 0.0 and d["t"][-1] == pytest.approx(10.0)
    r2 = _bgc("simulate", model, "--t-end", "60", "--out", tmp_path / "n.npz",
              cache_dir=tmp_path / "c")
    assert r2.returncode == 0, r2.stderr
    d = np.load(tmp_path / "n.npz")
    assert d["t"][-1] == pytest.approx(60.0)
    p = {k: v["value"] for k, v in yaml.safe_load(model.read_text())["parameters"].items()}
    assert d["position"][-1] == pytest.approx(p["F0"] / p["k"], rel=1e-3)
    bad = _bgc("simulate", model, "--t-end", "-1", cache_dir=tmp_path / "c")
    assert bad.returncode == 2 and "--t-end" in bad.stderr
