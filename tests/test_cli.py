"""The command line end to end on the mass-spring-damper: compile, check, graph, simulate."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def bgc(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "bgc", *map(str, args)], capture_output=True,
                          text=True, cwd=cwd, timeout=600)


def test_compile_writes_an_importable_module(tmp_path):
    out = tmp_path / "msd_mod.py"
    r = bgc("compile", ROOT / "models" / "msd.yaml", "-o", out)
    assert r.returncode == 0, r.stderr
    assert "wrote" in r.stderr  # progress on stderr
    assert out.read_text() == (ROOT / "generated" / "msd.py").read_text()
    assert [p.name for p in tmp_path.iterdir()] == ["msd_mod.py"]  # no temporary left


def test_check_lists_causality_and_states():
    r = bgc("check", ROOT / "models" / "3r2s.yaml")
    assert r.returncode == 0, r.stderr
    assert "all storage elements integral" in r.stdout
    assert "states (101 scalars)" in r.stdout
    assert "link1.R [3, 3]" in r.stdout


def test_graph_dot_has_strokes_and_multibonds(tmp_path):
    out = tmp_path / "g.dot"
    r = bgc("graph", ROOT / "models" / "point_mass_3d.yaml", "-o", out)
    assert r.returncode == 0, r.stderr
    dot = out.read_text()
    assert dot.startswith("digraph") and "tee" in dot and "penwidth=2.5" in dot


def test_simulate_writes_npz_and_plots(tmp_path):
    scene = ROOT / "models" / "scenes" / "msd_step.yaml"
    r = bgc("simulate", scene, "--out", tmp_path / "r.npz", "--plot", tmp_path / "plots")
    assert r.returncode == 0, r.stderr
    d = np.load(tmp_path / "r.npz")
    assert "t" in d.files and len(d.files) > 1
    for k in d.files:
        assert d[k].shape[-1] == d["t"].shape[0]
    pngs = list((tmp_path / "plots").glob("*.png"))
    assert pngs and all(p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for p in pngs)


def test_user_error_exit_2_without_traceback(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("bgc: 1\nname: m\nelements:\n  a: {type: Q}\nbonds: []\n")
    r = bgc("compile", bad, "-o", tmp_path / "out.py")
    assert r.returncode == 2
    assert r.stderr.strip().splitlines()[-1].startswith(f"{bad}:4:")
    assert "Traceback" not in r.stderr
    assert not (tmp_path / "out.py").exists()


def test_simulate_options_are_checked_and_errors_have_a_place(tmp_path):
    """--method is one of the runtime's methods (an unknown one: a usage error, exit 2, no
    traceback); --max-wall turns a long run into a located failed run (exit 1), nothing
    written."""
    scene = ROOT / "models" / "scenes" / "msd_step.yaml"
    r = bgc("simulate", scene, "--method", "Euler")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "'Euler' is not one of" in r.stderr and "'Rodas4'" in r.stderr
    out = tmp_path / "r.npz"
    r = bgc("simulate", ROOT / "models" / "scenes" / "3r2s_circle.yaml", "--max-wall", "0.2",
            "--out", out, "-q")
    assert r.returncode == 1 and "Traceback" not in r.stderr
    last = r.stderr.strip().splitlines()[-1]
    assert last.startswith(f"{ROOT / 'models' / 'scenes' / '3r2s_circle.yaml'}:")
    assert "simulation failed: Radau stopped at t = " in last and "max_wall = 0.2 s" in last
    assert not out.exists()


def test_simulate_with_the_modules_own_rosenbrock_method(tmp_path):
    """--method Rodas4 on the step response: the same answer as the scene's Radau run, to
    the tolerances (rtol 1e-6: both within 1e-5 of the peak displacement)."""
    scene = ROOT / "models" / "scenes" / "msd_step.yaml"
    runs = {}
    for m in ("Radau", "Rodas4"):
        r = bgc("simulate", scene, "--method", m, "--out", tmp_path / f"{m}.npz")
        assert r.returncode == 0, r.stderr
        assert f"{m} rtol=" in r.stdout
        runs[m] = np.load(tmp_path / f"{m}.npz")
    a, b = runs["Radau"], runs["Rodas4"]
    np.testing.assert_array_equal(a["t"], b["t"])
    x = a["position"]
    assert np.max(np.abs(b["position"] - x)) < 1e-5 * np.max(np.abs(x))
