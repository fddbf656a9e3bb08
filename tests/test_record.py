"""Run records (bgc.run.record): a warm `bgc simulate` replays the run the full way recorded.

Checked here: a replay gives the full way's results bit for bit (numpy and C); a replay
imports neither click, PyYAML nor bgc's parser; every input the run read (model, imported
file, table, scene, compiler, options) invalidates it; options it does not know go the full
way; refusals and failures read as the full way's; an unsafe record is ignored."""
from __future__ import annotations

import json
import marshal
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import bgc_in_process, seed_c_runtime

from bgc.run import record
from bgc.run.cache import Cache

ROOT = Path(__file__).resolve().parents[1]
MSD = ROOT / "models" / "scenes" / "msd_step.yaml"


def _bgc(*args, cache_dir, extra_env=None):
    """`bgc ARGS` as the console script runs it (bgc.cli.launch), in a process of its own."""
    if not os.path.lexists(cache_dir):  # a fresh cache: the C runtime's objects built
        seed_c_runtime(cache_dir)        # (no test here is about their build)
    env = {**os.environ, "BGC_CACHE_DIR": str(cache_dir), **(extra_env or {})}
    return subprocess.run([sys.executable, "-m", "bgc"] + [str(a) for a in args],
                          capture_output=True, text=True, env=env, timeout=600)


def _bgc_here(*args, cache_dir):
    """:func:`_bgc` in this process: conftest's bgc_in_process runs what
    `python -m bgc` runs (bgc.cli.launch.main: the replay, then click). For the tests whose
    property is which record a run replays, decided from files on disk; the process's own
    imports and its compiler probes (once per process) keep subprocesses."""
    if not os.path.lexists(cache_dir):
        seed_c_runtime(cache_dir)
    return bgc_in_process(*args, env={"BGC_CACHE_DIR": cache_dir})


def _cli_here(*args, cache_dir):
    """`bgc ARGS` straight into click (bgc.cli.commands.main), in this process: the full way,
    no record replayed."""
    from click.testing import CliRunner

    from bgc.cli.commands import main

    r = CliRunner().invoke(main, [str(a) for a in args], env={"BGC_CACHE_DIR": str(cache_dir)})
    assert r.exception is None or isinstance(r.exception, SystemExit), r.exception
    return subprocess.CompletedProcess(["bgc", *args], r.exit_code, r.stdout, r.stderr)


def _replayed(proc) -> bool:
    return "run record" in proc.stderr


def _same(a: Path, b: Path) -> None:
    ra, rb = np.load(a), np.load(b)
    assert sorted(ra.files) == sorted(rb.files)
    for k in ra.files:
        np.testing.assert_array_equal(ra[k], rb[k])


def _summary(proc) -> str:
    """The summary line without its timings."""
    return re.sub(r"compile [0-9.]+ s, integrate [0-9.]+ s", "", proc.stdout.strip())


def _c_ok() -> bool:
    from bgc.backends.c import build as cbuild

    return cbuild.available() and bool(cbuild.runtime_sources())


def _copy_models(dst: Path) -> Path:
    shutil.copytree(ROOT / "models", dst)
    return dst


@pytest.mark.parametrize("backend", ["numpy", "c"])
def test_replay_equals_the_full_way(tmp_path, backend):
    if backend == "c" and not _c_ok():
        pytest.skip("no C compiler or C runtime")
    cdir = tmp_path / "cache"
    args = ["simulate", MSD, "--backend", backend]
    first = _bgc_here(*args, "--out", tmp_path / "a.npz", cache_dir=cdir)
    assert first.returncode == 0, first.stderr
    assert not _replayed(first) and "deriving equations" in first.stderr
    warm = _bgc_here(*args, "--out", tmp_path / "b.npz", cache_dir=cdir)
    assert warm.returncode == 0, warm.stderr
    assert _replayed(warm) and "deriving equations" not in warm.stderr
    full = _cli_here(*args, "--out", tmp_path / "c.npz", cache_dir=cdir)
    assert full.returncode == 0 and not _replayed(full) and "cache hit" in full.stderr
    _same(tmp_path / "a.npz", tmp_path / "b.npz")
    _same(tmp_path / "a.npz", tmp_path / "c.npz")
    assert _summary(warm) == _summary(first) == _summary(full)
    assert f"({backend} backend)" in warm.stdout
    # the progress lines read as the full way's (after "cache hit ...", its output's name)
    lines = lambda p: [ln.split("] ", 1)[1] for ln in p.stderr.splitlines()][1:]  # noqa: E731
    assert lines(warm) == [ln.replace("c.npz", "b.npz") for ln in lines(full)]


_IMPORTS = r"""
import sys, json
sys.argv = ["bgc"] + sys.argv[1:]
from bgc.cli.launch import main  # what `python -m bgc` runs (before ending the process)
try:
    main()
except SystemExit as e:
    pass
heavy = ["click", "yaml", "bgc.cli.commands", "bgc.format.parse", "bgc.format.scene", "bgc.run.runner", "sympy",
         "matplotlib", "jinja2", "networkx", "scipy", "dask", "numpy.ma"]
print(json.dumps(sorted(m for m in heavy if m in sys.modules)))
"""


def test_replay_imports_neither_click_nor_yaml_nor_the_parser(tmp_path):
    if not _c_ok():
        pytest.skip("no C compiler or C runtime")
    cdir = tmp_path / "cache"
    args = ["simulate", str(MSD), "--backend", "c", "--out", str(tmp_path / "r.npz")]
    assert _bgc(*args, cache_dir=cdir).returncode == 0
    env = {**os.environ, "BGC_CACHE_DIR": str(cdir)}
    warm = subprocess.run([sys.executable, "-c", _IMPORTS, *args], capture_output=True,
                          text=True, env=env, timeout=600)
    assert warm.returncode == 0, warm.stderr
    assert _replayed(warm), warm.stderr
    assert json.loads(warm.stdout.strip().splitlines()[-1]) == []


def test_every_input_invalidates_the_record(tmp_path):
    """Model, imported file, table and scene: a change is never replayed, and the result
    follows it (the quarter car's road is a CSV table beside its scene)."""
    work = _copy_models(tmp_path / "models")
    scene = work / "scenes" / "quarter_car_bump.yaml"
    cdir = tmp_path / "cache"

    def run(name):
        p = _bgc_here("simulate", scene, "--out", tmp_path / f"{name}.npz", cache_dir=cdir)
        assert p.returncode == 0, p.stderr
        return p, np.load(tmp_path / f"{name}.npz")

    _, base = run("base")
    p, again = run("again")
    assert _replayed(p)
    np.testing.assert_array_equal(base["tyre_force"], again["tyre_force"])
    # the table: a 3 cm bump instead of 2 cm
    csv = work / "scenes" / "road_bump.csv"
    csv.write_text(re.sub(r",0\.02$", ",0.03", csv.read_text(), flags=re.M))
    p, bump = run("bump")
    assert not _replayed(p) and "cache hit" not in p.stderr  # a new module: the table is in it
    assert np.max(np.abs(bump["body_height"] - base["body_height"])) > 1e-3
    p, _ = run("bump2")
    assert _replayed(p)
    # an imported file (the model imports a new, unused component file)
    (work / "extra.yaml").write_text("bgc: 1\nname: extra\nelements: {}\nbonds: []\n")
    model = work / "quarter_car.yaml"
    model.write_text(model.read_text() + "\nimports:\n  - {file: extra.yaml}\n")
    p, _ = run("imp")
    assert not _replayed(p)
    assert _replayed(run("imp2")[0])
    (work / "extra.yaml").write_text("bgc: 1\nname: extra\nelements: {}\nbonds: []\n# edit\n")
    assert not _replayed(run("imp3")[0])
    # the model: a softer suspension damper changes the answer
    model.write_text(model.read_text().replace("c_s: {value: 1000.0", "c_s: {value: 500.0"))
    p, soft = run("model")
    assert not _replayed(p)
    assert np.max(np.abs(soft["body_height"] - bump["body_height"])) > 1e-4
    assert _replayed(run("model2")[0])
    # the scene: a comment is a new record (its bytes are in the key) with the same answer
    scene.write_text(scene.read_text() + "\n# edited\n")
    p, same = run("scene")
    assert not _replayed(p)
    np.testing.assert_array_equal(same["tyre_force"], soft["tyre_force"])


def test_options_select_their_own_record(tmp_path):
    cdir = tmp_path / "cache"
    a = _bgc_here("simulate", MSD, "--out", tmp_path / "a.npz", cache_dir=cdir)
    assert a.returncode == 0
    b = _bgc_here("simulate", MSD, "--rtol", "1e-9", "--out", tmp_path / "b.npz",
                  cache_dir=cdir)
    assert b.returncode == 0 and not _replayed(b) and "rtol=1e-09" in b.stdout
    c = _bgc_here("simulate", MSD, "--rtol=1e-9", "-q", "--out", tmp_path / "c.npz",
                  cache_dir=cdir)
    assert c.returncode == 0 and "rtol=1e-09" in c.stdout
    _same(tmp_path / "b.npz", tmp_path / "c.npz")
    d = _bgc_here("simulate", MSD, "--out", tmp_path / "d.npz", cache_dir=cdir)
    assert _replayed(d)
    _same(tmp_path / "a.npz", tmp_path / "d.npz")
    # what a record does not replay goes the full way
    for extra in (["--no-cache"], ["--plot", str(tmp_path / "figs")], ["--method", "BDF"]):
        p = _bgc_here("simulate", MSD, *extra, cache_dir=cdir)
        assert p.returncode == 0, p.stderr
        assert not _replayed(p)
    # a usage error is the full way's, from click
    bad = _bgc_here("simulate", MSD, "--rtol", "abc", cache_dir=cdir)
    assert bad.returncode == 2 and "error:" in bad.stderr and not _replayed(bad)


def test_refusals_and_failures_read_as_the_full_ways(tmp_path):
    cdir = tmp_path / "cache"
    work = _copy_models(tmp_path / "models")
    scene = work / "scenes" / "msd_step.yaml"
    assert _bgc_here("simulate", scene, cache_dir=cdir).returncode == 0
    # --out naming the model: refused before the run, by the full way's message
    model = work / "msd.yaml"
    before = model.read_bytes()
    p = _bgc_here("simulate", scene, "--out", model, cache_dir=cdir)
    assert p.returncode == 2 and "--out" in p.stderr and "input" in p.stderr, p.stderr
    assert model.read_bytes() == before
    # a run that fails under a replay: the record's time limit made tiny (records are the
    # user's own, in the checked cache; this one is edited to fail)
    store = Cache(cdir)
    opts = record.options_text(None, None, None, None, None, False)
    key = record.record_key(str(scene), scene.read_bytes(), opts)
    rec = record.load(store, key)
    assert rec is not None
    rec["run"]["max_wall"] = 1e-12
    assert record.save(store, key, rec)
    f = _bgc_here("simulate", scene, cache_dir=cdir)
    assert f.returncode == 1, f.stderr
    line = f.stderr.strip().splitlines()[-1]
    assert line.startswith(f"{scene}:") and "simulation failed" in line and "Traceback" not in \
        f.stderr


def test_an_unsafe_record_is_ignored(tmp_path):
    cdir = tmp_path / "cache"
    assert _bgc_here("simulate", MSD, cache_dir=cdir).returncode == 0
    recs = [p for p in (cdir / "run").glob("*/*") if p.is_file()]
    assert len(recs) == 1
    assert _replayed(_bgc_here("simulate", MSD, cache_dir=cdir))
    os.chmod(recs[0], 0o666)  # writable by others: not trusted
    p = _bgc_here("simulate", MSD, cache_dir=cdir)
    assert p.returncode == 0 and not _replayed(p)
    # the full way wrote a fresh record in its place
    assert _replayed(_bgc_here("simulate", MSD, cache_dir=cdir))
    # a record that is not marshal data, or of another format: ignored
    recs[0].write_bytes(b"not a record")
    assert not _replayed(_bgc_here("simulate", MSD, cache_dir=cdir))
    recs[0].write_bytes(marshal.dumps({"format": -1}))
    assert not _replayed(_bgc_here("simulate", MSD, cache_dir=cdir))


def test_a_changed_compiler_is_not_replayed(tmp_path):
    if not _c_ok():
        pytest.skip("no C compiler or C runtime")
    real = shutil.which("cc") or shutil.which("gcc")
    fake = tmp_path / "bin" / "mycc"
    fake.parent.mkdir()
    fake.write_text(f'#!/bin/sh\nexec {real} "$@"\n')
    fake.chmod(0o755)
    cdir = tmp_path / "cache"
    env = {"CC": str(fake)}
    args = ["simulate", MSD, "--backend", "c"]
    assert _bgc(*args, cache_dir=cdir, extra_env=env).returncode == 0
    assert _replayed(_bgc(*args, cache_dir=cdir, extra_env=env))
    fake.write_text(f'#!/bin/sh\n# upgraded\nexec {real} "$@"\n')
    p = _bgc(*args, cache_dir=cdir, extra_env=env)
    assert p.returncode == 0 and not _replayed(p)
    # another CC is another record
    assert not _replayed(_bgc(*args, cache_dir=cdir))


def test_parse_accepts_exactly_what_it_replays():
    ok = record._parse(["s.yaml", "--out", "r.npz", "-q", "--backend", "c", "--rtol=1e-6"])
    assert ok == {"scene": "s.yaml", "out": "r.npz", "quiet": True, "backend": "c",
                  "rtol": 1e-6}
    for bad in ([], ["a.yaml", "b.yaml"], ["s.yaml", "--plot", "d"], ["s.yaml", "--no-cache"],
                ["s.yaml", "--out"], ["s.yaml", "-q", "-q"], ["s.yaml", "--rtol", "x"],
                ["s.yaml", "--help"], ["--", "s.yaml"], ["s.yaml", "--out="]):
        assert record._parse(bad) is None, bad
    # one spelling per value: 1e-6 and 0.000001 are the same run
    assert record.options_text(None, 1e-6, None, None, "c", False) == \
        record.options_text(None, float("0.000001"), None, None, "c", False)
