"""The compile cache: generated modules (and built C libraries) keyed by what shapes them.

Key: a sha256 of the model file's bytes, every file it imports and every table (CSV) the
model or scene reads, the scene file's bytes
(its plan: signals, effects, folded parameters, outputs), bgc's version, the installed sympy's
version, bgc's own templates and sources, the target, and for C the compiler's identity
(``cc --version``) and flags. Computing the key reads files only: no sympy, no parsing beyond
the YAML of the import lists, so a warm run never imports the compiler.

Location: ``$BGC_CACHE_DIR``, else ``$XDG_CACHE_HOME/bgc``, else ``~/.cache/bgc``. Loading a
cached module runs it, so a cache directory that is not owned by the user or that others can
write to is refused. Entries are written into a temporary directory beside their final place
and renamed into it (``os.replace``): a reader sees a whole entry or none, and of two processes
that build the same entry at once, one rename wins and the other's copy is dropped.
"""
from __future__ import annotations

import os
import stat
import sys
from pathlib import Path

from . import __version__
from .errors import ModelError

#: Entry kinds: generated modules, built C libraries, the C runtime's objects and compiler
#: facts, and run records (bgc.record: files, not folders).
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


def _check(path: Path) -> None:
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
        _check(self.path)
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
                _check(sub)
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
            _check(sub)
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

        n = sum(self.info()["entries"].values())
        for t in TARGETS:
            if (self.path / t).is_dir():
                shutil.rmtree(self.path / t)
        return n


# ---------------------------------------------------------------------------------------------
# Keys

def _table_refs(doc) -> list[str]:
    """Every ``table: FILE`` value in a loaded YAML document (inputs given as data), found
    without recursion; a superset of what the parser reads is harmless in a key."""
    out, todo = [], [doc]
    while todo:
        node = todo.pop()
        if isinstance(node, dict):
            if isinstance(node.get("table"), str):
                out.append(node["table"])
            todo.extend(node.values())
        elif isinstance(node, list):
            todo.extend(node)
    return out


def model_files(path, scene_path=None) -> list[tuple[str, bytes]] | None:
    """The model file, every file it imports (recursively) and every table file (CSV) the
    model, its imports and the scene name, as (resolved path, bytes): what a compile reads
    (the scene itself apart). None when they cannot all be read (the compile then reports the
    error, uncached)."""
    import yaml  # noqa: F401 (parse.py imports it anyway)

    loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
    out: list[tuple[str, bytes]] = []
    seen: set[str] = set()

    def load(data: bytes, word: bytes, doc):
        # a file that never says "imports" (or "table") has none: no need to parse it
        if doc is None and word in data:
            doc = yaml.load(data, Loader=loader)  # noqa: S506 (CSafeLoader or SafeLoader)
        return doc

    def tables(p: Path, data: bytes, doc) -> bool:
        doc = load(data, b"table", doc)
        for rel in _table_refs(doc):
            tp = p.parent / rel
            rt = str(tp.resolve())
            if rt in seen:
                continue
            seen.add(rt)
            try:
                out.append((rt, tp.read_bytes()))
            except OSError:
                return False
        return True

    def visit(p: Path) -> bool:
        rp = str(p.resolve())
        if rp in seen:
            return True
        seen.add(rp)
        try:
            data = p.read_bytes()
            doc = load(data, b"imports", None)
            out.append((rp, data))
            if not tables(p, data, doc):
                return False
        except (OSError, yaml.YAMLError, UnicodeDecodeError, ValueError, RecursionError):
            return False
        imports = doc.get("imports") if isinstance(doc, dict) else None
        if imports is None:
            return True
        if not isinstance(imports, list):
            return False
        for item in imports:
            if not (isinstance(item, dict) and isinstance(item.get("file"), str)):
                return False
            if not visit(p.parent / item["file"]):
                return False
        return True

    if not visit(Path(path)):
        return None
    if scene_path is not None:
        sp = Path(scene_path)
        try:
            if not tables(sp, sp.read_bytes(), None):
                return None
        except (OSError, yaml.YAMLError, UnicodeDecodeError, ValueError, RecursionError):
            return None
    return out


def _tool_versions() -> str:
    """The installed sympy's version (from its dist-info folder's name: cheap, and sympy is
    not imported) and Python's."""
    import importlib.util

    ver = "?"
    try:
        spec = importlib.util.find_spec("sympy")
        if spec is not None and spec.origin:
            site = Path(spec.origin).resolve().parent.parent
            infos = sorted(p.name for p in site.glob("sympy-*.dist-info"))
            ver = ",".join(infos) or "?"
    except (ImportError, OSError, ValueError):
        pass
    return f"sympy {ver}; python {sys.version}"


def _code_digest() -> str:
    """bgc's own sources and templates (a change in either may change the output)."""
    import hashlib

    from .paths import templates_dir

    h = hashlib.sha256()
    here = Path(__file__).resolve().parent
    files = sorted(here.glob("*.py")) + sorted(
        f for f in templates_dir().rglob("*") if f.is_file() and f.suffix in (".j2", ".py",
                                                                              ".c", ".h"))
    for f in files:
        h.update(f.name.encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()


def key(target: str, model_path, scene_path=None, extra: str = "") -> str | None:
    """The cache key of a compile, or None when the inputs cannot be read."""
    return key_inputs(target, model_path, scene_path, extra)[0]


def key_inputs(target: str, model_path, scene_path=None, extra: str = ""):
    """(key or None, the (path, bytes) it digested, the scene's bytes or None): a run record
    (bgc.record) keeps the digests of exactly the bytes the key was made of."""
    import hashlib

    files = model_files(model_path, scene_path)
    if files is None:
        return None, [], None
    h = hashlib.sha256()
    h.update(f"bgc {__version__}\0{_tool_versions()}\0{target}\0{extra}\0".encode())
    h.update(_code_digest().encode())
    for name, data in files:  # models, imports and tables (by file name: keys do not move)
        h.update(b"model\0" + Path(name).name.encode() + b"\0" + data + b"\0")
    scene = None
    if scene_path is not None:
        try:
            scene = Path(scene_path).read_bytes()
        except OSError:
            return None, [], None
        h.update(b"scene\0" + scene)
    if target == "c":
        from . import cbuild

        h.update(("\0" + cbuild.identity() + "\0" + " ".join(cbuild.flags())).encode())
    return h.hexdigest(), files, scene
