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
    # (numpy: the C step loop finishes the circle within 0.2 s)
    r = bgc("simulate", ROOT / "models" / "scenes" / "3r2s_circle.yaml", "--max-wall", "0.2",
            "--out", out, "-q", "--backend", "numpy")
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


def test_exit_statuses_follow_the_readme_table(tmp_path):
    """The README's table of exit statuses, each one produced: 0 a compiled model; 1 a run
    that fails numerically (the orifice at equal levels: infinite slope at t = 0); 2 a model
    error and an output that would replace the model; 3 a planted bug (an internal error)."""
    import os
    import re

    readme = (ROOT / "README.md").read_text()
    table = dict(re.findall(r"^\| ([0-3]) \| (.+?) \|$", readme, flags=re.M))
    assert sorted(table) == ["0", "1", "2", "3"]
    assert "simulation failed" in table["1"] and "usage error" in table["2"]
    assert "internal error" in table["3"]
    here = ROOT / "tests" / "outputs_safety"
    assert bgc("compile", ROOT / "models" / "msd.yaml", "-o", tmp_path / "m.py").returncode == 0
    r = bgc("simulate", here / "orifice_equal.yaml", "-q")
    assert r.returncode == 1 and "regularise" in r.stderr and "Traceback" not in r.stderr
    model = ROOT / "models" / "msd.yaml"
    before = model.read_bytes()
    r = bgc("compile", model, "-o", model)
    assert r.returncode == 2 and "is an input of this run" in r.stderr
    assert model.read_bytes() == before
    boom = ("import sys, bgc.cli.commands, bgc.core.graph\n"
            "bgc.core.graph.build_graph = lambda *a: {}['planted']\n"
            "sys.argv = ['bgc', 'check', sys.argv[1]]\nbgc.cli.commands.main()\n")
    r = subprocess.run([sys.executable, "-c", boom, str(model)], capture_output=True,
                       text=True, env={**os.environ, "BGC_DEBUG": "0"})
    assert r.returncode == 3 and "Traceback" not in r.stderr
    assert r.stderr.strip().splitlines() == [
        "bgc: internal error (KeyError: 'planted'); this is a bug in bgc, please report it "
        "with the command and its input files (BGC_DEBUG=1 shows the traceback)"]


def test_rtol_inf_and_unwritable_outputs_are_one_line(tmp_path):
    """Malformed invocations, each with its message: exit 2, no traceback, nothing written."""
    model = ROOT / "models" / "msd.yaml"
    scene = ROOT / "models" / "scenes" / "msd_step.yaml"
    cases = [
        (("simulate", scene, "--rtol", "inf"),
         "error: --rtol inf is outside [1e-14, 1] (the limit of tolerances: doubles carry "
         "about 16 digits)"),
        (("compile", model, "-o", ""), "error: -o '': the path is empty"),
        (("compile", model, "-o", "/dev/null"),
         "error: -o '/dev/null': is a character device, not a regular file; bgc replaces "
         "only regular files"),
        (("graph", model, "-o", tmp_path / "g.txt"),
         f"error: -o '{tmp_path / 'g.txt'}': unknown drawing format '.txt': use .dot, .svg or "
         ".png"),
    ]
    for args, msg in cases:
        r = bgc(*args)
        assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
        assert r.stderr.strip().splitlines()[-1] == msg
    assert list(tmp_path.iterdir()) == []
