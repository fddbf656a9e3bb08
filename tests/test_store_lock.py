"""One build per compile-cache entry, across processes (bgc.base.store's per-entry lock).

Real processes (not threads) miss one entry at once; each build appends its process id to a
log, so the number of builds is counted outside the code under test. The same run with the
lock switched off (as on a system without fcntl) is the control: there both processes build.
A holder killed with SIGKILL leaves a lock the system has dropped; a hit takes no lock; the
wait is bounded; the lock file is never part of an entry, and is made and checked like the
cache's own folders.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from bgc.base import store
from bgc.base.store import Cache, UnsafeCache

pytestmark = pytest.mark.skipif(store._fcntl() is None, reason="no fcntl (Windows)")

KEY = "ab" + "c" * 62

# A child: waits for the go file, looks up the entry, then get_or_build with a build that
# logs its pid. Each child marks its entry into the lock's acquire (``acq-PID``), and a build
# finishes only once both children have entered it (or after ``hold`` seconds): so both
# missed the entry at once, whatever the machine's load, and the build was still running
# when the other child asked for it.
_CHILD = r"""
import json, os, sys, time
from pathlib import Path
from bgc.base import store

cache_dir, key, log, marks, go, hold, mode = sys.argv[1:8]
marks = Path(marks)
if mode == "nolock":  # as on a system without fcntl
    store._fcntl = lambda: None
_acquire = store._EntryLock.acquire

def acquire(self, *a):
    (marks / f"acq-{os.getpid()}").write_text("")
    return _acquire(self, *a)
store._EntryLock.acquire = acquire

def build(tmp):
    with open(log, "a") as fh:
        fh.write(f"{os.getpid()}\n")
    (tmp / "who").write_text(str(os.getpid()))
    end = time.monotonic() + float(hold)
    while len(list(marks.glob("acq-*"))) < 2 and time.monotonic() < end:
        time.sleep(0.01)
    time.sleep(0.2)

c = store.Cache(Path(cache_dir))
print("ready", flush=True)
while not os.path.exists(go):
    time.sleep(0.002)
missed = c.get("numpy", key) is None
d = c.get_or_build("numpy", key, build)
print(json.dumps({"pid": os.getpid(), "missed": missed, "entry": str(d),
                  "who": (d / "who").read_text()}), flush=True)
"""


def _child(tmp_path: Path, mode: str = "lock", hold: float = 60.0) -> subprocess.Popen:
    marks = tmp_path / "marks"
    marks.mkdir(exist_ok=True)
    p = subprocess.Popen([sys.executable, "-c", _CHILD, str(tmp_path / "cache"), KEY,
                          str(tmp_path / "builds.log"), str(marks), str(tmp_path / "go"),
                          str(hold), mode], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True)
    assert p.stdout.readline().strip() == "ready", p.stderr.read()
    return p


def _builds(tmp_path: Path) -> list[int]:
    log = tmp_path / "builds.log"
    return [int(s) for s in log.read_text().split()] if log.exists() else []


def _race(tmp_path: Path, mode: str) -> list[dict]:
    procs = [_child(tmp_path, mode) for _ in range(2)]
    (tmp_path / "go").write_text("")
    out = []
    for p in procs:
        o, e = p.communicate(timeout=300)
        assert p.returncode == 0, e
        out.append(json.loads(o.strip().splitlines()[-1]))
    return out


def test_two_processes_missing_one_entry_build_it_once(tmp_path):
    got = _race(tmp_path, "lock")
    assert all(g["missed"] for g in got)  # both looked before the entry existed
    builds = _builds(tmp_path)
    assert len(builds) == 1  # one build
    assert got[0]["entry"] == got[1]["entry"]  # the same entry, the builder's
    assert got[0]["who"] == got[1]["who"] == str(builds[0])
    parent = Path(got[0]["entry"]).parent
    assert [p.name for p in parent.iterdir()] == [KEY]  # no lock file, no temporary left


def test_without_the_lock_both_build(tmp_path):
    """The control (a system without fcntl: today's rename protocol alone): both processes
    build, one rename wins, and both still get one whole entry."""
    got = _race(tmp_path, "nolock")
    assert sorted(_builds(tmp_path)) == sorted(g["pid"] for g in got)
    assert got[0]["entry"] == got[1]["entry"] and got[0]["who"] == got[1]["who"]
    parent = Path(got[0]["entry"]).parent
    assert [p.name for p in parent.iterdir()] == [KEY]


def _holder(tmp_path: Path) -> subprocess.Popen:
    """A child that has taken the entry's lock and is building (it logged its pid)."""
    p = _child(tmp_path, "lock", hold=120.0)
    (tmp_path / "go").write_text("")
    end = time.monotonic() + 120
    while p.pid not in _builds(tmp_path):
        assert p.poll() is None and time.monotonic() < end, p.stderr.read()
        time.sleep(0.01)
    return p


def _build_here(tmp):
    (tmp / "who").write_text(str(os.getpid()))


def test_a_killed_holder_does_not_block_the_next_build(tmp_path, capsys):
    p = _holder(tmp_path)
    lock = Cache(tmp_path / "cache").entry("numpy", KEY).parent / f".{KEY}.lock"
    assert lock.is_file()  # held, beside the entry that is not there yet
    os.kill(p.pid, signal.SIGKILL)
    p.communicate(timeout=60)
    fcntl = store._fcntl()
    fd = os.open(lock, os.O_RDWR)
    try:  # the system dropped the dead holder's lock
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)
    c = Cache(tmp_path / "cache")
    c.lock_wait = 60.0
    d = c.get_or_build("numpy", KEY, _build_here)
    assert (d / "who").read_text() == str(os.getpid())  # built here, taking the lock
    assert "note: waited" not in capsys.readouterr().err
    assert not lock.exists()  # the dead holder's lock file taken over, then removed
    assert c.info()["entries"]["numpy"] == 1  # (its temporary folder is not an entry)


def test_the_wait_is_bounded_then_it_builds_with_a_note(tmp_path, capsys):
    p = _holder(tmp_path)
    try:
        c = Cache(tmp_path / "cache")
        c.lock_wait = 0.3
        d = c.get_or_build("numpy", KEY, _build_here)
        assert (d / "who").read_text() == str(os.getpid())  # no error: built here too
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("note: waited") and "numpy abcccc" in err[0]
    finally:
        p.kill()
        p.communicate(timeout=60)


def test_a_hit_takes_no_lock(tmp_path, monkeypatch):
    c = Cache(tmp_path / "cache")
    d = c.get_or_build("numpy", KEY, _build_here)
    lock = d.parent / f".{KEY}.lock"
    assert not lock.exists()  # removed by its holder

    def no_lock():
        raise AssertionError("a hit asked for the lock")
    monkeypatch.setattr(store, "_fcntl", no_lock)
    calls = []
    assert c.get_or_build("numpy", KEY, calls.append) == d
    assert calls == [] and not lock.exists()  # not even created


def test_threads_of_one_process_build_once(tmp_path):
    """flock holds between two opens of the file in one process too (Dask's threads)."""
    c = Cache(tmp_path / "cache")
    builds, entered = [], threading.Barrier(2, timeout=60)
    inside = []
    real = store._EntryLock.acquire

    def acquire(self, *a):
        inside.append(threading.get_ident())
        return real(self, *a)

    def build(tmp):
        builds.append(threading.get_ident())
        end = time.monotonic() + 60
        while len(inside) < 2 and time.monotonic() < end:
            time.sleep(0.01)
        time.sleep(0.2)
        (tmp / "who").write_text("one")
    got = []

    def run():
        entered.wait()
        got.append(c.get_or_build("numpy", KEY, build))
    store._EntryLock.acquire = acquire
    try:
        ts = [threading.Thread(target=run) for _ in range(2)]
        for t in ts:
            t.start()
        for t in ts:
            t.join(120)
    finally:
        store._EntryLock.acquire = real
    assert len(inside) == 2 and len(builds) == 1 and got[0] == got[1]


def test_the_lock_file_is_made_and_checked_like_the_cache(tmp_path):
    c = Cache(tmp_path / "cache")
    seen = []

    def build(tmp):
        lock = tmp.parent / f".{KEY}.lock"
        st = lock.lstat()
        seen.append((lock.is_file() and not lock.is_symlink(), st.st_mode & 0o777))
        (tmp / "f").write_text("x")
    d = c.get_or_build("numpy", KEY, build)
    assert seen == [(True, 0o600)]
    assert sorted(p.name for p in d.iterdir()) == ["f"]  # not in the entry
    # a link in the lock file's place: refused, nothing followed or made
    other = "ab" + "d" * 62
    target = tmp_path / "elsewhere"
    target.write_text("untouched")
    (d.parent / f".{other}.lock").symlink_to(target)
    with pytest.raises(UnsafeCache, match="link"):
        c.get_or_build("numpy", other, build)
    assert target.read_text() == "untouched" and c.get("numpy", other) is None
    # a lock file others can write to: refused like a folder others can write to
    (d.parent / f".{other}.lock").unlink()
    (d.parent / f".{other}.lock").write_text("")
    os.chmod(d.parent / f".{other}.lock", 0o666)
    with pytest.raises(UnsafeCache, match="others can write"):
        c.get_or_build("numpy", other, build)


def test_info_clear_and_discard_with_lock_files_present(tmp_path):
    """A lock file a killed holder left: not an entry for info, gone with clear; discard
    removes the entry and leaves the build of it to the next miss."""
    c = Cache(tmp_path / "cache")
    d = c.get_or_build("numpy", KEY, _build_here)
    stale = d.parent / f".{'ab' + 'e' * 62}.lock"
    stale.write_text("")
    os.chmod(stale, 0o600)
    (d.parent / f".{KEY}.lock").write_text("")
    assert c.info()["entries"]["numpy"] == 1
    assert c.get("numpy", KEY) == d
    c.discard("numpy", KEY)
    assert c.get("numpy", KEY) is None
    d2 = c.get_or_build("numpy", KEY, _build_here)  # over the stale lock file of its own
    assert d2 == d and not (d.parent / f".{KEY}.lock").exists()
    assert c.clear() == 1
    assert not (tmp_path / "cache" / "numpy").exists()


def test_no_fcntl_builds_as_before(tmp_path, monkeypatch):
    monkeypatch.setattr(store, "_fcntl", lambda: None)
    c = Cache(tmp_path / "cache")
    seen = []
    d = c.get_or_build("numpy", KEY, lambda tmp: seen.append(
        (tmp.parent / f".{KEY}.lock").exists()))
    assert seen == [False] and d.is_dir()  # no lock file ever made


def test_a_stopped_build_ahead_stops_waiting(tmp_path, capsys):
    """A build ahead that is called off (bgc.backends.c.build.stop_runtime's event) while it
    waits for another process's build of its entry ends its wait, and its build refuses."""
    p = _holder(tmp_path)
    try:
        c = Cache(tmp_path / "cache")
        c.lock_wait = 120.0
        stop, got = threading.Event(), []

        def build(tmp):
            got.append("build ran")
            if stop.is_set():
                raise RuntimeError("stopped")

        def run():
            try:
                c.get_or_build("numpy", KEY, build, stop=stop)
            except RuntimeError as exc:
                got.append(str(exc))
        t = threading.Thread(target=run)
        t.start()
        time.sleep(0.3)
        assert t.is_alive() and got == []  # waiting for the holder
        stop.set()
        t.join(60)
        assert not t.is_alive() and got == ["build ran", "stopped"]
        assert "note: waited" not in capsys.readouterr().err
        assert c.get("numpy", KEY) is None  # nothing kept
    finally:
        p.kill()
        p.communicate(timeout=60)
