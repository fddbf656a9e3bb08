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

from bgc.backends.c import build as cbuild
from bgc.base import __version__
from bgc.base.paths import code_files
from bgc.base.reach import MAX_BYTES, reached_files
from bgc.base.safeio import read_bytes
from bgc.base.store import TARGETS, Cache, UnsafeCache, root  # noqa: F401 (the cache's face)

# ---------------------------------------------------------------------------------------------
# Keys

def model_files(path, scene_path=None) -> list[tuple[str, bytes]] | None:
    """The model file, every file it imports (recursively) and every table file (CSV) the
    model, its imports and the scene name, as (resolved path, bytes): what a compile reads
    (the scene itself apart), read with the bounded reader (bgc.base.reach). None when they
    cannot all be read (the compile then reports the error, uncached)."""
    files = reached_files(path, scene_path)
    return None if files is None else [(r.resolved, r.data) for r in files]


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


    h = hashlib.sha256()

    for name, path in code_files():
        h.update(name.encode() + b"\0" + read_bytes(path, 64 << 20) + b"\0")
    return h.hexdigest()


def key(target: str, model_path, scene_path=None, extra: str = "") -> str | None:
    """The cache key of a compile, or None when the inputs cannot be read."""
    return key_inputs(target, model_path, scene_path, extra)[0]


def key_inputs(target: str, model_path, scene_path=None, extra: str = ""):
    """(key or None, the files it digested (bgc.base.reach.Reached: the path as reached, the
    resolved path, the bytes), the scene's bytes or None): a run record (bgc.run.record)
    keeps the paths and digests of exactly the bytes the key was made of."""
    import hashlib

    files = reached_files(model_path, scene_path)
    if files is None:
        return None, [], None
    h = hashlib.sha256()
    h.update(f"bgc {__version__}\0{tool_versions()}\0{target}\0{extra}\0".encode())
    h.update(_code_digest().encode())
    for f in files:  # models, imports and tables (by file name: keys do not move)
        h.update(b"model\0" + Path(f.resolved).name.encode("utf-8", "surrogateescape") + b"\0" + f.data + b"\0")
    scene = None
    if scene_path is not None:
        try:
            scene = read_bytes(scene_path, MAX_BYTES)
        except OSError:
            return None, [], None
        h.update(b"scene\0" + scene)
    if target == "c":
        h.update(("\0" + cbuild.identity() + "\0" + " ".join(cbuild.flags())).encode())
    return h.hexdigest(), files, scene
