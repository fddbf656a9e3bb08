"""The safe on-disk store behind the compile cache and the run records.

Location: ``$BGC_CACHE_DIR``, else ``$XDG_CACHE_HOME/bgc``, else ``~/.cache/bgc``. Loading a
cached module runs it, so a cache directory that is not owned by the user or that others can
write to is refused. Entries are written into a temporary directory beside their final place
and renamed into it (``os.replace``): a reader sees a whole entry or none, and of two processes
that build the same entry at once, one rename wins and the other's copy is dropped. What goes
into a key is the run layer's business (bgc.run.cache); this module only keeps entries.
"""
from __future__ import annotations

import os
import stat
from pathlib import Path

from bgc.base.errors import ModelError

#: Entry kinds: generated modules, built C libraries, the C runtime's objects and compiler
#: facts, and run records (bgc.run.record: files, not folders).
TARGETS = ("numpy", "c", "c-runtime", "run")


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

    def get_or_build(self, target: str, key: str, build) -> Path:
        """The entry, built by ``build(tmpdir)`` when missing; the rename makes it visible."""
        d = self.get(target, key)
        if d is not None:
            return d
        import shutil
        import tempfile

        self._ensure()
        parent = self.entry(target, key).parent
        parent.mkdir(parents=True, mode=0o700, exist_ok=True)
        for sub in (self.path / target, parent):
            check_dir(sub)
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
        """Remove every entry; returns how many there were."""
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
        for t in TARGETS:
            if (self.path / t).is_dir():
                shutil.rmtree(self.path / t)  # links inside are removed, never followed
        return n

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
