"""The compile cache: hits, misses, invalidation by an imported file, concurrent writers, an
unsafe directory refused, --no-cache, `bgc cache info/clear`, and a warm `bgc simulate` that
imports neither sympy nor matplotlib."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import bgc_in_process, seed_c_runtime

from bgc.base.errors import ModelError
from bgc.run import cache as cache_mod
from bgc.run.cache import Cache, UnsafeCache

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "models" / "scenes" / "msd_step.yaml"


def _bgc(*args, cache_dir, extra_env=None):
    """bgc ARGS; a simulate that names no backend runs numpy's (these tests count the numpy
    entries; the default backend's choice is tested in tests/test_c_backend.py)."""
    if args and args[0] == "simulate" and "--backend" not in args:
        args = (*args, "--backend", "numpy")
    env = {**os.environ, "BGC_CACHE_DIR": str(cache_dir), **(extra_env or {})}
    return subprocess.run([sys.executable, "-m", "bgc", *map(str, args)], capture_output=True,
                          text=True, env=env, timeout=600)


def _bgc_here(*args, cache_dir):
    """:func:`_bgc` in this process (conftest's bgc_in_process: `python -m bgc`'s own front
    door), for the tests whose property is the cache on disk, not a process's imports or its
    compiler probes."""
    if args and args[0] == "simulate" and "--backend" not in args:
        args = (*args, "--backend", "numpy")
    return bgc_in_process(*args, env={"BGC_CACHE_DIR": cache_dir})


def _entries(d: Path, target="numpy"):
    return sorted(p for p in (d / target).glob("*/*") if p.is_dir() and not p.name.startswith("."))


def test_miss_then_hit_gives_the_same_results(tmp_path):
    cdir = tmp_path / "cache"
    a = _bgc_here("simulate", SCENE, "--out", tmp_path / "a.npz", cache_dir=cdir)
    assert a.returncode == 0, a.stderr
    assert "cache hit" not in a.stderr and "deriving equations" in a.stderr
    assert len(_entries(cdir)) == 1
    b = _bgc_here("simulate", SCENE, "--out", tmp_path / "b.npz", cache_dir=cdir)
    assert b.returncode == 0, b.stderr
    assert "cache hit" in b.stderr and "deriving equations" not in b.stderr
    ra, rb = np.load(tmp_path / "a.npz"), np.load(tmp_path / "b.npz")
    for k in ra.files:
        np.testing.assert_array_equal(ra[k], rb[k])
    # --no-cache compiles afresh and adds nothing
    c = _bgc_here("simulate", SCENE, "--no-cache", cache_dir=tmp_path / "other")
    assert c.returncode == 0 and "deriving equations" in c.stderr
    assert not (tmp_path / "other").exists()
    # the key follows the scene: another scene is another entry
    d = _bgc_here("simulate", ROOT / "models/scenes/dc_motor_load_step.yaml", cache_dir=cdir)
    assert d.returncode == 0, d.stderr
    assert len(_entries(cdir)) == 2
    info = _bgc_here("cache", "info", cache_dir=cdir)
    assert info.returncode == 0 and "numpy 2" in info.stdout and str(cdir) in info.stdout
    assert "run 2" in info.stdout  # each scene's run record (bgc.run.record)
    clr = _bgc_here("cache", "clear", cache_dir=cdir)
    assert clr.returncode == 0 and "removed 4" in clr.stdout  # 2 modules, 2 records
    assert _entries(cdir) == [] and not list((cdir / "run").glob("*/*"))


def _model_with_import(d: Path, gain: str):
    d.mkdir(parents=True, exist_ok=True)
    (d / "part.yaml").write_text(f"bgc: 1\nname: part\nparameters:\n  g: {{value: {gain}}}\n")
    (d / "main.yaml").write_text("bgc: 1\nname: main\nimports:\n  - {file: part.yaml}\n")
    return d / "main.yaml"


def test_key_changes_with_an_imported_file_and_nothing_else(tmp_path):
    main = _model_with_import(tmp_path / "m", "1.0")
    k1 = cache_mod.key("numpy", main)
    assert k1 == cache_mod.key("numpy", main)  # deterministic
    (tmp_path / "m" / "unrelated.yaml").write_text("x: 1\n")
    assert cache_mod.key("numpy", main) == k1
    _model_with_import(tmp_path / "m", "2.0")  # only the imported file changes
    k2 = cache_mod.key("numpy", main)
    assert k2 != k1
    assert cache_mod.key("numpy", main, scene_path=SCENE) != k2
    files = [Path(p).name for p, _ in cache_mod.model_files(main)]
    assert files == ["main.yaml", "part.yaml"]


def test_key_follows_the_tables_a_model_or_scene_reads(tmp_path):
    """A table input (CSV) is compiled into the module: its bytes are part of the key, for a
    table named by the scene or by the model (they were not, and a changed table replayed the
    old module)."""
    work = tmp_path / "models"
    shutil.copytree(ROOT / "models", work)
    scene = work / "scenes" / "quarter_car_bump.yaml"
    model = work / "quarter_car.yaml"
    k1 = cache_mod.key("numpy", model, scene)
    names = [Path(p).name for p, _ in cache_mod.model_files(model, scene)]
    assert names == ["quarter_car.yaml", "road_bump.csv"]
    csv = work / "scenes" / "road_bump.csv"
    csv.write_text(csv.read_text() + "# a comment\n")
    k2 = cache_mod.key("numpy", model, scene)
    assert k2 != k1
    # a table named by the model itself
    (work / "m").mkdir()
    (work / "m" / "road.csv").write_text("t,v\n0,0\n1,1\n")
    m = work / "m" / "with_table.yaml"
    m.write_text("bgc: 1\nname: t\ninputs:\n  zr: {table: road.csv, columns: [t, v]}\n")
    k3 = cache_mod.key("numpy", m)
    (work / "m" / "road.csv").write_text("t,v\n0,0\n1,2\n")
    assert cache_mod.key("numpy", m) != k3
    csv.unlink()  # an unreadable table: no key (the compile reports the error, uncached)
    assert cache_mod.key("numpy", model, scene) is None


def test_editing_an_imported_file_recompiles(tmp_path):
    """A model split over two files (the scene's model imports its components): changing the
    imported file's text is a miss, restoring it a hit again."""
    src = ROOT / "models"
    work = tmp_path / "models"
    shutil.copytree(src / "scenes", work / "scenes")
    for f in src.glob("*.yaml"):
        shutil.copy(f, work / f.name)
    # an extra imported file that the msd model pulls in (a component nobody uses)
    (work / "extra.yaml").write_text("bgc: 1\nname: extra\nelements: {}\nbonds: []\n")
    text = (work / "msd.yaml").read_text()
    (work / "msd.yaml").write_text(text + "\nimports:\n  - {file: extra.yaml}\n")
    scene = work / "scenes" / "msd_step.yaml"
    cdir = tmp_path / "cache"
    k1 = cache_mod.key("numpy", work / "msd.yaml", scene)
    (work / "extra.yaml").write_text("bgc: 1\nname: extra\nelements: {}\nbonds: []\n# edited\n")
    k2 = cache_mod.key("numpy", work / "msd.yaml", scene)
    assert k1 != k2
    r = _bgc_here("simulate", scene, cache_dir=cdir)
    assert r.returncode == 0, r.stderr
    assert "cache hit" not in r.stderr
    assert "cache hit" in _bgc_here("simulate", scene, cache_dir=cdir).stderr
    (work / "extra.yaml").write_text("bgc: 1\nname: extra\nelements: {}\nbonds: []\n# edited again\n")
    assert "cache hit" not in _bgc_here("simulate", scene, cache_dir=cdir).stderr


def test_concurrent_writers(tmp_path):
    """Two processes run the same scene on an empty cache at once: both succeed, exactly one
    of them compiles (the other waits on the entry's lock, bgc.base.store, and loads what the
    first built, or comes late and hits), the cache holds one complete entry and no lock
    file, and both give the same results."""
    cdir = tmp_path / "cache"
    env = {**os.environ, "BGC_CACHE_DIR": str(cdir)}
    procs = [subprocess.Popen([sys.executable, "-m", "bgc", "simulate", str(SCENE), "--out",
                               str(tmp_path / f"{k}.npz"), "--backend", "numpy"], env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for k in range(2)]
    outs = [p.communicate(timeout=600) for p in procs]
    for p, (o, e) in zip(procs, outs):
        assert p.returncode == 0, e
    assert sorted("deriving equations" in e for _, e in outs) == [False, True]
    assert all("cache hit" in e for _, e in outs if "deriving equations" not in e)
    ents = _entries(cdir)
    assert len(ents) == 1
    assert (ents[0] / "module.py").is_file()
    leftovers = [p for p in (cdir / "numpy").rglob(".*")]
    assert leftovers == []  # no temporary directory, no lock file left
    a, b = np.load(tmp_path / "0.npz"), np.load(tmp_path / "1.npz")
    np.testing.assert_array_equal(a["position"], b["position"])


def test_get_or_build_race_in_process(tmp_path):
    """The rename protocol itself: a build that finds its entry made meanwhile keeps that one."""
    c = Cache(tmp_path / "c")

    def build_a(tmp):
        (tmp / "f").write_text("a")
        # another writer finishes first
        c.get_or_build("numpy", "k" * 64, lambda t2: (t2 / "f").write_text("b"))

    d = c.get_or_build("numpy", "k" * 64, build_a)
    assert (d / "f").read_text() == "b"
    assert [p.name for p in d.parent.iterdir()] == ["k" * 64]


@pytest.mark.skipif(not hasattr(os, "getuid"), reason="POSIX permissions")
def test_unsafe_cache_directory_is_refused(tmp_path):
    cdir = tmp_path / "cache"
    cdir.mkdir()
    os.chmod(cdir, 0o777)
    with pytest.raises(UnsafeCache) as exc:
        Cache(cdir).get("numpy", "0" * 64)
    assert str(cdir) in str(exc.value) and "writable by others" in str(exc.value)
    r = _bgc("simulate", SCENE, cache_dir=cdir)
    assert r.returncode == 2
    assert "writable by others" in r.stderr and "Traceback" not in r.stderr
    assert r.stderr.strip().splitlines()[-1].startswith("error:")
    assert list(cdir.iterdir()) == []  # nothing written into it
    # an entry directory inside a safe cache that others can write to is refused too
    os.chmod(cdir, 0o700)
    ok = _bgc("simulate", SCENE, cache_dir=cdir)
    assert ok.returncode == 0, ok.stderr
    entry = _entries(cdir)[0]
    os.chmod(entry, 0o777)
    bad = _bgc("simulate", SCENE, cache_dir=cdir)
    assert bad.returncode == 2 and "writable by others" in bad.stderr


def test_cache_owned_by_another_user_is_refused(tmp_path, monkeypatch):
    cdir = tmp_path / "cache"
    cdir.mkdir(mode=0o700)
    monkeypatch.setattr(os, "getuid", lambda: os.stat(cdir).st_uid + 1)
    with pytest.raises(ModelError) as exc:
        Cache(cdir).get("numpy", "0" * 64)
    assert "another user" in str(exc.value)


def test_cache_root_honours_the_environment(monkeypatch, tmp_path):
    monkeypatch.delenv("BGC_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_mod.root() == tmp_path / "xdg" / "bgc"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert cache_mod.root() == tmp_path / "home" / ".cache" / "bgc"
    monkeypatch.setenv("BGC_CACHE_DIR", str(tmp_path / "mine"))
    assert cache_mod.root() == tmp_path / "mine"


_WARM = r"""
import sys, json
from bgc.cli.commands import main
try:
    main(sys.argv[1:])
except SystemExit as e:
    code = e.code
heavy = ["sympy", "matplotlib", "jinja2", "networkx", "dask", "xarray", "zarr", "bgc.studies.sweep",
         "bgc.studies.accuracy"]
if "c" in sys.argv:  # the C backend's run needs neither scipy nor what it brings
    heavy += ["scipy", "numpy.ma", "concurrent.futures"]
print(json.dumps(sorted(m for m in heavy if m in sys.modules)))
"""


@pytest.mark.parametrize("backend", ["numpy", "c"])
def test_warm_simulate_imports_only_what_it_needs(tmp_path, backend):
    from bgc.backends.c import build as cbuild

    if backend == "c" and not (cbuild.available() and cbuild.runtime_sources()):
        pytest.skip("no C compiler or C runtime")
    cdir = tmp_path / "cache"
    if backend == "c":  # the runtime's objects built (their build is not what is tested here)
        seed_c_runtime(cdir)
    args = ["simulate", str(SCENE), "--backend", backend, "--out", str(tmp_path / "r.npz")]
    first = _bgc(*args, cache_dir=cdir)
    assert first.returncode == 0, first.stderr
    env = {**os.environ, "BGC_CACHE_DIR": str(cdir)}
    warm = subprocess.run([sys.executable, "-c", _WARM, *args], capture_output=True, text=True,
                          env=env, timeout=600)
    assert warm.returncode == 0, warm.stderr
    assert "cache hit" in warm.stderr
    assert json.loads(warm.stdout.strip().splitlines()[-1]) == []


def test_warm_c_run_starts_no_compiler(tmp_path):
    """The compiler's identity (part of every C cache key) is kept in the cache under the
    executable's path, size and times: a warm run starts no compiler, and a changed compiler
    (here: its script rewritten) is asked again."""
    from bgc.backends.c import build as cbuild

    real = shutil.which("cc") or shutil.which("gcc")
    if real is None or not (cbuild.available() and cbuild.runtime_sources()):
        pytest.skip("no C compiler or C runtime")
    log = tmp_path / "calls.log"
    fake = tmp_path / "bin" / "mycc"
    fake.parent.mkdir()

    def write_fake(tag):
        fake.write_text(f'#!/bin/sh\necho "$@" >> {log}\n'
                        f'if [ "$1" = "--version" ]; then echo "mycc {tag}"; exit 0; fi\n'
                        f'exec {real} "$@"\n')
        fake.chmod(0o755)

    write_fake("1")
    cdir = tmp_path / "cache"
    args = ["simulate", str(SCENE), "--backend", "c", "--out", str(tmp_path / "r.npz")]
    env = {"CC": str(fake)}
    assert _bgc(*args, cache_dir=cdir, extra_env=env).returncode == 0
    calls = log.read_text().splitlines()
    assert calls.count("--version") == 1 and len(calls) > 1  # asked once, then compiled
    log.write_text("")
    warm = _bgc(*args, cache_dir=cdir, extra_env=env)
    assert warm.returncode == 0 and "cache hit" in warm.stderr
    assert log.read_text() == ""  # nothing started
    write_fake("2 (upgraded)")  # same path, new contents: size and times change
    os.utime(fake, ns=(1, 1))   # even with an old mtime, the size/ctime differ
    again = _bgc(*args, cache_dir=cdir, extra_env=env)
    assert again.returncode == 0, again.stderr
    assert "--version" in log.read_text().splitlines()
    assert "cache hit" not in again.stderr  # a new identity is a new key: rebuilt
