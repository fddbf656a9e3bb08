"""Data safety (issue 22): no command destroys an input, writes outside its outputs, or
replays the wrong results.

The table-driven test aims every output option of every command at the run's own model,
scene, table and import files, at a device node (/dev/null: refused, never written), a FIFO,
a dangling link, a link to a folder and a folder (all made inside tmp_path), and compares the
tree's bytes and inodes before and after: nothing outside the named output may change. The
other tests take the issue's items one by one.
"""
from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest
from click.testing import CliRunner

from bgc.cli.commands import main

MODEL = """bgc: 1
name: model
parameters: {m: 2.0}
inputs: {F: {default: 0.0, unit: N}}
imports: [{file: parts.yaml}]
elements:
  force: {type: Se, effort: "F"}
  v: {type: "1"}
  mass: {type: I, inertia: "m"}
  sd: {type: spring_damper, k: 4.0}
bonds: [[force, v], [v, mass], [v, sd.a]]
outputs: {velocity: "f(mass)", position: "q(sd.C)"}
"""
PARTS = """bgc: 1
name: parts
elements: {}
bonds: []
components:
  spring_damper:
    parameters: {k: 1.0, r: 0.5}
    ports: {a: v}
    elements:
      v: {type: "1"}
      C: {type: C, stiffness: "k"}
      R: {type: R, resistance: "r"}
    bonds: [[v, C], [v, R]]
"""
SCENE = """bgc_scene: 1
model: model.yaml
duration: 1.0
inputs:
  F: {table: force.csv, columns: [time, F]}
solver: {method: Radau, rtol: 1.0e-6, atol: 1.0e-9, dt: 0.1}
sweep:
  parameters:
    m: {linspace: [1.0, 3.0, 2]}
"""
TABLE = "time,F\n0,0\n0.5,1\n1,1\n"


def project(root: Path) -> Path:
    """A model that imports a file, a scene that reads a table: every kind of input."""
    p = root / "proj"
    p.mkdir()
    for name, text in (("model.yaml", MODEL), ("parts.yaml", PARTS), ("scene.yaml", SCENE),
                       ("force.csv", TABLE)):
        (p / name).write_text(text)
    return p


def targets(root: Path, proj: Path, graph: bool = False) -> dict:
    """name -> the path an output option is aimed at (made inside tmp_path, but /dev/null)."""
    os.mkfifo(root / "fifo")
    (root / "dangling").symlink_to(root / "nowhere" / "x")
    (root / "elsewhere").mkdir()
    (root / "linked_folder").symlink_to(root / "elsewhere")
    return {"model": proj / "model.yaml", "scene": proj / "scene.yaml",
            "table": proj / "force.csv", "import": proj / "parts.yaml", "device": "/dev/null",
            "fifo": root / "fifo", "dangling link": root / "dangling",
            "link to a folder": root / "linked_folder", "folder": proj,
            "fresh": root / "fresh" / ("out.dot" if graph else "out")}


def snapshot(root: Path) -> dict:
    """Every entry under root, not following links: kind, inode, and bytes or link target."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in dirnames + filenames:
            p = Path(dirpath) / name
            st = os.lstat(p)
            if stat.S_ISREG(st.st_mode):
                what = p.read_bytes()
            elif stat.S_ISLNK(st.st_mode):
                what = os.readlink(p)
            else:
                what = None
            out[str(p.relative_to(root))] = (stat.S_IFMT(st.st_mode), st.st_ino, what)
    return out


def devnull_id():
    st = os.stat("/dev/null")
    return stat.S_ISCHR(st.st_mode), st.st_rdev


#: command -> (argument list with OUT for the aimed path, is a folder output). All on the
#: project's own files; cheap settings where a command would run long.
COMMANDS = {
    "compile -o": (["compile", "{model}", "-o", "OUT", "-q"], False),
    "compile --scene -o": (["compile", "{model}", "--scene", "{scene}", "-o", "OUT", "-q"],
                           False),
    "compile --target c -o": (["compile", "{model}", "--target", "c", "-o", "OUT", "-q"], True),
    "graph -o": (["graph", "{model}", "-o", "OUT"], False),
    "simulate --out": (["simulate", "{scene}", "--out", "OUT", "-q", "--no-cache"], False),
    "simulate --plot": (["simulate", "{scene}", "--plot", "OUT", "-q", "--no-cache"], True),
    "linearize --out": (["linearize", "{scene}", "--out", "OUT", "-q", "--bode",
                         "F:velocity"], True),
    "export --fmu": (["export", "{model}", "--fmu", "OUT", "-q"], False),
    "accuracy --out": (["accuracy", "{scene}", "--out", "OUT", "-q", "--methods", "RK45",
                        "--tols", "1e-3:1e-4", "--repeats", "1", "--jac-methods", "",
                        "--ref-rtol", "1e-8", "--budget", "20"], True),
    "sweep --out --restart": (["sweep", "{scene}", "--out", "OUT", "--restart", "-q",
                               "--backend", "numpy"], True),
    "examples": (["examples", "OUT"], True),
}


def _needs(cmd: str):
    if cmd in ("compile --target c -o", "export --fmu"):
        from bgc.backends.c import build as cbuild

        if not cbuild.available():
            pytest.skip("no C compiler")
    if cmd == "export --fmu":
        pytest.importorskip("fmpy")


def _id(text: str) -> str:
    return text.replace(" --", "_").replace(" -", "_").replace(" ", "_")


AIMS = ["model", "scene", "table", "import", "device", "fifo", "dangling link",
        "link to a folder", "folder", "fresh"]
#: The scene and its table are no input of a command given the model alone (its own
#: files are the model and its import): "compile -o" with --scene is the case that has them.
#: (The FMU export reads no table inputs yet, so its scene case would fail before writing.)
NOT_ITS_OWN = {(c, a) for c in ("compile -o", "graph -o", "export --fmu", "examples")
               for a in ("scene", "table")}
#: Cases that run a whole study or a Dask cluster: slow.
HEAVY = {("accuracy --out", "folder"), ("accuracy --out", "fresh"),
         ("sweep --out --restart", "fresh")}


@pytest.mark.parametrize("cmd,aim", [
    pytest.param(c, a, id=f"{_id(c)}-{_id(a)}", marks=[pytest.mark.slow] if (c, a) in HEAVY
                 else []) for c in COMMANDS for a in AIMS if (c, a) not in NOT_ITS_OWN])
def test_no_output_option_changes_anything_but_its_output(tmp_path, monkeypatch, cmd, aim):
    """Refused (exit 2, one line, nothing changed) unless aimed at a new path ("fresh") or,
    for a folder output, at a folder: then it succeeds and adds entries only inside it."""
    _needs(cmd)
    monkeypatch.setenv("BGC_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    proj = project(tmp_path)
    out = targets(tmp_path, proj, cmd == "graph -o")[aim]
    argv, folder_output = COMMANDS[cmd]
    args = [str(out) if a == "OUT" else a.format(model=proj / "model.yaml",
                                                 scene=proj / "scene.yaml") for a in argv]
    before, dev = snapshot(tmp_path), devnull_id()
    r = CliRunner().invoke(main, args)
    after = snapshot(tmp_path)
    assert devnull_id() == dev
    assert r.exit_code != 3 and "Traceback" not in r.output, r.output
    assert not isinstance(r.exception, Exception) or isinstance(r.exception, SystemExit), \
        repr(r.exception)
    named = str(Path(out).relative_to(tmp_path)) if str(out).startswith(str(tmp_path)) else None
    for rel, entry in before.items():
        if rel == "cache" or rel.startswith("cache/"):
            continue
        assert after.get(rel) == entry, f"{cmd} at {aim}: {rel} changed ({r.output})"
    for rel in set(after) - set(before):
        if rel == "cache" or rel.startswith("cache/"):
            continue
        # only a folder output aimed at a folder may add entries, and only inside it
        assert (aim == "fresh" or folder_output and aim == "folder") and r.exit_code == 0 \
            and named is not None and (rel + "/").startswith(named + "/") or \
            aim == "fresh" and rel == "fresh", f"{cmd} at {aim} made {rel} ({r.output})"
    if aim == "fresh" or aim == "folder" and folder_output and cmd != "sweep --out --restart":
        assert r.exit_code == 0, (cmd, aim, r.output)
    else:
        assert r.exit_code == 2, (cmd, aim, r.exit_code, r.output)
        assert len(r.output.strip().splitlines()) == 1, r.output  # one line
