"""The compile cache: generated modules (and built C libraries) keyed by what shapes them.

Key: a sha256 of the model file's bytes, every file it imports and every table (CSV) the
model or scene reads, the scene file's bytes
(its plan: signals, effects, folded parameters, outputs), bgc's version, the installed sympy's
version, bgc's own templates and sources, the target, and for C the compiler's identity
(``cc --version``) and flags. Computing the key reads files only: no sympy, no parsing beyond
the YAML of the import lists, so a warm run never imports the compiler.

The entries themselves live in bgc.base.store (location, safety checks, atomic entries).
"""
from __future__ import annotations

import sys
from pathlib import Path

from bgc.base import __version__
from bgc.base.errors import ModelError
from bgc.base.limits import LIMITS
from bgc.base.safeio import read_bytes_bounded
from bgc.base.store import TARGETS, Cache, UnsafeCache, root  # noqa: F401 (the cache's face)

# ---------------------------------------------------------------------------------------------
# Keys

_TABLE_BYTES = 16 * 1024 * 1024  # bgc.format.tables.MAX_BYTES


def _small(path, limit: int) -> bytes:
    """A file's bytes, size-checked before reading (a 10 GB sparse model, a FIFO): a
    ModelError the callers turn into "no key" (the compile then reports it, located)."""
    return read_bytes_bounded(path, "file", limit)


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
                out.append((rt, _small(tp, _TABLE_BYTES)))
            except (OSError, ModelError):
                return False
        return True

    def visit(p: Path) -> bool:
        rp = str(p.resolve())
        if rp in seen:
            return True
        seen.add(rp)
        try:
            data = _small(p, LIMITS.model_bytes)
            doc = load(data, b"imports", None)
            out.append((rp, data))
            if not tables(p, data, doc):
                return False
        except (OSError, ModelError, yaml.YAMLError, UnicodeDecodeError, ValueError,
                RecursionError):
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
            if not tables(sp, _small(sp, LIMITS.scene_bytes), None):
                return None
        except (OSError, ModelError, yaml.YAMLError, UnicodeDecodeError, ValueError,
                RecursionError):
            return None
    return out


def tool_versions() -> str:
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
    """bgc's own sources, in every subpackage, and templates (a change in any may change the
    output): bgc.base.paths.code_files."""
    import hashlib

    from bgc.base.paths import code_files

    h = hashlib.sha256()
    for name, path in code_files():
        h.update(name.encode() + b"\0" + Path(path).read_bytes() + b"\0")
    return h.hexdigest()


def key(target: str, model_path, scene_path=None, extra: str = "") -> str | None:
    """The cache key of a compile, or None when the inputs cannot be read."""
    return key_inputs(target, model_path, scene_path, extra)[0]


def key_inputs(target: str, model_path, scene_path=None, extra: str = ""):
    """(key or None, the (path, bytes) it digested, the scene's bytes or None): a run record
    (bgc.run.record) keeps the digests of exactly the bytes the key was made of."""
    import hashlib

    files = model_files(model_path, scene_path)
    if files is None:
        return None, [], None
    h = hashlib.sha256()
    h.update(f"bgc {__version__}\0{tool_versions()}\0{target}\0{extra}\0".encode())
    h.update(_code_digest().encode())
    for name, data in files:  # models, imports and tables (by file name: keys do not move)
        h.update(b"model\0" + Path(name).name.encode() + b"\0" + data + b"\0")
    scene = None
    if scene_path is not None:
        try:
            scene = _small(scene_path, LIMITS.scene_bytes)
        except (OSError, ModelError):
            return None, [], None
        h.update(b"scene\0" + scene)
    if target == "c":
        from bgc.backends.c import build as cbuild

        h.update(("\0" + cbuild.identity() + "\0" + " ".join(cbuild.flags())).encode())
    return h.hexdigest(), files, scene
