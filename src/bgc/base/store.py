"""The safe on-disk store behind the compile cache and the run records.

Location: ``$BGC_CACHE_DIR``, else ``$XDG_CACHE_HOME/bgc``, else ``~/.cache/bgc``. Loading a
cached module runs it, so a cache directory that is not owned by the user or that others can
write to is refused. Entries are written into a temporary directory beside their final place
and renamed into it (``os.replace``): a reader sees a whole entry or none.

One build per entry, across processes: a process that misses an entry takes an advisory lock
on a file beside it (``.KEY.lock``, ``fcntl.flock``; made like the entries: mode 600, never
through a link, the user's own), looks again (another process may have built it meanwhile)
and builds only if it is still missing; the others wait and then find the entry. A hit takes
no lock. The lock cannot wedge: the system drops it when its holder dies, a waiter gives up
after :data:`LOCK_WAIT` seconds and builds anyway (with a one-line note), a build nested in
the same thread's build of the same entry does not wait for itself, and where there is no
``fcntl`` (Windows), or the file system refuses locks, two processes may both build, and one
rename wins. The holder removes the lock file when it is done; a file left by a killed
process is taken over by the next build (lock files are dot-files: never an entry, not
counted, removed with their folder by ``clear``). What goes into a key is the run layer's
business (bgc.run.cache); this module only keeps entries.
"""
from __future__ import annotations

import os
import stat
import sys
import time
from pathlib import Path

from bgc.base.errors import ModelError

#: Entry kinds: generated modules, built C libraries, the C runtime's objects and compiler
#: facts, and run records (bgc.run.record: files, not folders).
TARGETS = ("numpy", "c", "c-runtime", "run")

#: seconds a process waits for another process's build of the same entry before it builds
#: the entry itself (a wedged or very slow holder costs at most this, never an error)
LOCK_WAIT = 300.0
#: the first and the longest pause between two looks at a lock another process holds
_POLL = (0.01, 0.2)


class UnsafeCache(ModelError):
    def __init__(self, message: str):
        super().__init__(None, message)


def root() -> Path:
    env = os.environ.get("BGC_CACHE_DIR")
    if env:
        return Path(env).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg).expanduser() if xdg else Path.home() / ".cache"
    return base / "bgc"


def check_dir(path: Path) -> None:
    """Refuse a directory not owned by the user, or writable by group or others."""
    st = path.lstat()
    if stat.S_ISLNK(st.st_mode) or not stat.S_ISDIR(st.st_mode):
        raise UnsafeCache(f"{path}: the compile cache is not a directory (refusing a link or "
                          "file; remove it, or set BGC_CACHE_DIR, or use --no-cache)")
    if hasattr(os, "getuid") and st.st_uid != os.getuid():
        raise UnsafeCache(f"{path}: the compile cache directory belongs to another user "
                          f"(uid {st.st_uid}); loading a cached module runs it: refusing it "
                          "(set BGC_CACHE_DIR, or use --no-cache)")
    if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        raise UnsafeCache(f"{path}: the compile cache directory is writable by others (mode "
                          f"{stat.S_IMODE(st.st_mode):o}); loading a cached module runs it: "
                          "refusing it (chmod go-w, set BGC_CACHE_DIR, or use --no-cache)")


class Cache:
    def __init__(self, path: Path | None = None):
        self.path = Path(path) if path is not None else root()

    def _ensure(self) -> Path:
        if not self.path.exists():
            self.path.mkdir(parents=True, mode=0o700, exist_ok=True)
        check_dir(self.path)
        return self.path

    def entry(self, target: str, key: str) -> Path:
        return self.path / target / key[:2] / key

    def get(self, target: str, key: str) -> Path | None:
        """The entry's directory if it exists (complete), else None."""
        if not self.path.exists():
            return None
        self._ensure()
        d = self.entry(target, key)
        if d.is_dir():
            for sub in (self.path / target, d.parent, d):
                check_dir(sub)
            return d
        return None

    #: this cache's :data:`LOCK_WAIT` (a test may shorten it)
    lock_wait = LOCK_WAIT

    def get_or_build(self, target: str, key: str, build, stop=None) -> Path:
        """The entry, built by ``build(tmpdir)`` when missing; the rename makes it visible.
        A miss takes the entry's lock first (see the module's docstring): of the processes
        that miss one entry at once, one builds and the others get its entry. ``stop`` (a
        threading.Event, for a build ahead that may be called off): once set, a wait for
        another process's build ends, and ``build`` runs (it is the build's to refuse)."""
        d = self.get(target, key)
        if d is not None:
            return d  # a hit: no lock
        self._ensure()
        parent = self.entry(target, key).parent
        parent.mkdir(parents=True, mode=0o700, exist_ok=True)
        for sub in (self.path / target, parent):
            check_dir(sub)
        lock = _EntryLock(parent / f".{key}.lock", self.entry(target, key))
        try:
            if lock.acquire(self.lock_wait, f"{target} {key[:12]}", stop):
                d = self.get(target, key)  # built by another process while we waited?
                if d is not None:
                    return d
            return self._build(target, key, parent, build)
        finally:
            lock.release()

    def _build(self, target: str, key: str, parent: Path, build) -> Path:
        import shutil
        import tempfile

        tmp = Path(tempfile.mkdtemp(prefix=f".{key[:16]}.", dir=parent))
        try:
            build(tmp)
            os.chmod(tmp, 0o700)
            try:
                os.replace(tmp, self.entry(target, key))
            except OSError:
                if not self.entry(target, key).is_dir():  # not a lost race: a real error
                    raise
        finally:
            if tmp.exists():
                shutil.rmtree(tmp, ignore_errors=True)
        return self.entry(target, key)

    def info(self) -> dict:
        out = {"path": str(self.path), "entries": {}, "bytes": 0}
        if not self.path.exists():
            return out
        self._ensure()
        for t in TARGETS:
            n = 0
            for d in (self.path / t).glob("*/*"):
                if d.name.startswith("."):
                    continue
                if d.is_dir():
                    n += 1
                    out["bytes"] += sum(f.stat().st_size for f in d.rglob("*") if f.is_file())
                elif t == "run" and d.is_file():  # a run record is one file
                    n += 1
                    out["bytes"] += d.stat().st_size
            out["entries"][t] = n
        return out

    def clear(self) -> int:
        """Remove every entry; returns how many there were. Only bgc's own entries (and their
        lock files and temporaries) go: a folder the cache was pointed at keeps the rest
        (``kept``)."""
        if not self.path.exists():
            return 0
        self._ensure()
        import shutil

        for t in TARGETS:  # a link or a file in bgc's place: said, and nothing removed
            sub = self.path / t
            if sub.is_symlink() or (sub.exists() and not sub.is_dir()):
                raise UnsafeCache(f"{sub}: not a folder of the compile cache (a link or a "
                                  "file); bgc removes only its own folders: remove it yourself")
        n = sum(self.info()["entries"].values())
        self.kept = []
        for t in TARGETS:
            if (self.path / t).is_dir():
                self.kept += _remove_own(self.path / t, shutil)
        return n

    #: what :meth:`clear` left because bgc did not make it (paths)
    kept: list = []

    def discard(self, target: str, key: str) -> None:
        """Remove one entry (a corrupt one): renamed aside first, so a reader never finds it
        half removed; nothing is followed through a link."""
        import shutil

        d = self.entry(target, key)
        aside = d.with_name(f".discard.{key[:16]}.{os.getpid()}.{os.urandom(4).hex()}")
        try:
            os.replace(d, aside)
        except OSError:
            return
        if aside.is_symlink() or not aside.is_dir():
            aside.unlink()
        else:
            shutil.rmtree(aside, ignore_errors=True)


def _own(name: str, shard: str) -> bool:
    """Whether ``name`` in the folder ``shard`` (a key's first two characters) is bgc's: an
    entry (named by its key, which starts with the shard's name), or a lock file, build
    folder, record temporary or discarded entry of one (a dot, then the key, or .discard.)."""
    return name.startswith((shard, "." + shard, ".discard."))


def _remove_own(sub: Path, shutil) -> list:
    """Remove bgc's entries in the target folder ``sub`` (``<shard>/<key>``) and the folders
    they leave empty; anything else (a user's file in a folder the cache was pointed at) is
    left, and returned. Links are removed, never followed."""
    kept = []
    for shard in sorted(sub.iterdir()):
        if len(shard.name) != 2 or shard.is_symlink() or not shard.is_dir():
            kept.append(shard)
            continue
        for e in sorted(shard.iterdir()):
            if not _own(e.name, shard.name):
                kept.append(e)
            elif e.is_symlink() or not e.is_dir():
                e.unlink()
            else:
                shutil.rmtree(e)
        if not any(shard.iterdir()):
            shard.rmdir()
    if not any(sub.iterdir()):
        sub.rmdir()
    return kept


def _fcntl():
    """The fcntl module, or None where there is none (Windows: builds are not serialised).
    Imported on a miss only: a hit needs no lock."""
    try:
        import fcntl
    except ImportError:
        return None
    return fcntl


#: lock file -> the thread of this process that holds it (a build nested in that thread's
#: build of the same entry must not wait for itself)
_HELD: dict[str, int] = {}


class _EntryLock:
    """The advisory lock of one entry's build (``fcntl.flock`` on ``path``): taken by
    :meth:`acquire`, given back by :meth:`release` (which removes the file)."""

    def __init__(self, path: Path, entry: Path):
        self.path, self.entry, self.fd = path, entry, None

    def acquire(self, wait: float, what: str, stop=None) -> bool:
        """Take the lock, waiting at most ``wait`` seconds; True when taken or when the entry
        appeared meanwhile (the caller looks again), False when the build goes on without it
        (no fcntl, a file system without locks, a nested build, ``stop`` set, the wait over:
        a note)."""
        import threading

        fcntl = _fcntl()
        if fcntl is None or _HELD.get(str(self.path)) == threading.get_ident():
            return False
        deadline = time.monotonic() + wait
        pause = _POLL[0]
        while not self.entry.is_dir():
            fd = self._open()
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:  # another process builds it
                os.close(fd)
                if stop is not None and stop.is_set():
                    return False
                if time.monotonic() >= deadline:
                    print(f"note: waited {wait:.0f} s for another process building the compile "
                          f"cache's entry {what}; building it here too", file=sys.stderr)
                    return False
                time.sleep(pause)
                pause = min(2 * pause, _POLL[1])
                continue
            except OSError:  # locks refused (a network file system): build without
                os.close(fd)
                return False
            if self._current(fd):
                self.fd = fd
                _HELD[str(self.path)] = threading.get_ident()
                return True
            os.close(fd)  # a finished holder removed that file: take the lock afresh
        return True

    def _open(self) -> int:
        """The lock file, opened (made if missing: mode 600, never through a link) and
        checked like the cache's folders: a regular file of the user's, others cannot write."""
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0)
                         | getattr(os, "O_CLOEXEC", 0), 0o600)
        except OSError as exc:
            if self.path.is_symlink():
                raise UnsafeCache(f"{self.path}: a link in place of a compile-cache lock file; "
                                  "bgc follows no link in its cache: remove it") from exc
            raise
        st = os.fstat(fd)
        bad = (not stat.S_ISREG(st.st_mode) or (hasattr(os, "getuid") and st.st_uid != os.getuid())
               or st.st_mode & (stat.S_IWGRP | stat.S_IWOTH))
        if bad:
            os.close(fd)
            raise UnsafeCache(f"{self.path}: a compile-cache lock file that is not a regular "
                              "file of yours, or that others can write to: remove it")
        return fd

    def _current(self, fd: int) -> bool:
        """Is the locked file still the one at the path (not removed by a holder that just
        finished)?"""
        try:
            now = os.stat(self.path, follow_symlinks=False)
        except FileNotFoundError:
            return False
        st = os.fstat(fd)
        return (now.st_dev, now.st_ino) == (st.st_dev, st.st_ino)

    def release(self) -> None:
        """Remove the lock file, then let the lock go (a waiter that took the removed file's
        lock sees that it is gone and takes a new one: :meth:`_current`)."""
        if self.fd is None:
            return
        try:
            os.unlink(self.path)
        except OSError:
            pass  # (the cache cleared meanwhile)
        _HELD.pop(str(self.path), None)
        fcntl = _fcntl()
        fcntl.flock(self.fd, fcntl.LOCK_UN)
        os.close(self.fd)
        self.fd = None
