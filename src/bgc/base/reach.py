"""The files a model or scene reaches: the model, every file it imports (recursively) and
every table file (CSV) the model, its imports and the scene name.

Read with the bounded reader (bgc.base.safeio.read_bytes: regular files only, size checked
before reading, never blocking on a FIFO or a device), parsed only as far as the import lists
and ``table:`` values. Each file is returned as it was reached (the path the parser opens,
made absolute but not resolved), as its resolved path, and with the bytes actually read: the
compile cache's key and the run records (bgc.run.cache, bgc.run.record) are made of these, and
the checked writer protects them as the run's inputs.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import NamedTuple

from bgc.base.outfiles import Inputs
from bgc.base.safeio import read_bytes

#: The most bytes of one file that a key reads (larger files fail the parser's own limits).
MAX_BYTES = 64 << 20
#: The most files one model reaches (the parser's import limit is far lower).
MAX_FILES = 4096


class Reached(NamedTuple):
    path: str  # as the parser reaches it: absolute, links not resolved
    resolved: str  # os.path.realpath
    data: bytes


def _table_refs(doc) -> list[str]:
    """Every ``table: FILE`` value in a loaded YAML document, found without recursion; a
    superset of what the parser reads is harmless in a key."""
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


class _Walk:
    def __init__(self):
        import yaml

        self.yaml = yaml
        self.loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
        self.out: list[Reached] = []
        self.seen: set[str] = set()

    def read(self, p: Path) -> Reached | None:
        """The file (None when seen already); OSError when it cannot be read."""
        if len(self.out) >= MAX_FILES:
            raise OSError("too many files")
        rp = os.path.realpath(p)
        if rp in self.seen:
            return None
        self.seen.add(rp)
        r = Reached(os.path.abspath(p), rp, read_bytes(p, MAX_BYTES))
        self.out.append(r)
        return r

    def load(self, data: bytes, word: bytes):
        # A file that never says "imports" (or "table") has none: no need to parse it. YAML
        # can spell a key without its letters only through a double-quoted escape
        # ("t\x61ble", "\u0074able"), so a file with a backslash is parsed too; the parser
        # reads UTF-8 only, where every other spelling of the word holds its bytes.
        if word not in data and b"\\" not in data:
            return None
        return self.yaml.load(data, Loader=self.loader)  # (CSafeLoader or SafeLoader)

    def tables(self, p: Path, doc) -> None:
        for rel in _table_refs(doc):
            self.read(p.parent / rel)

    def visit(self, p: Path) -> bool:
        r = self.read(p)
        if r is None:
            return True
        doc = self.load(r.data, b"imports") if b"imports" in r.data else \
            self.load(r.data, b"table")
        self.tables(p, doc)
        imports = doc.get("imports") if isinstance(doc, dict) else None
        if imports is None:
            return True
        if not isinstance(imports, list):
            return False
        for item in imports:
            if isinstance(item, dict) and isinstance(item.get("from"), str) and "file" not in item:
                continue  # the library (bgc:NAME): package files, in bgc.base.paths.code_files
            if not (isinstance(item, dict) and isinstance(item.get("file"), str)):
                return False
            if not self.visit(p.parent / item["file"]):
                return False
        return True


def reached_files(path, scene_path=None, partial: bool = False) -> list[Reached] | None:
    """What the model ``path`` (and the scene ``scene_path``'s tables) reach, the scene itself
    apart; None when they cannot all be read (the compile reports the error) unless
    ``partial``, which returns what could be read."""
    w = _Walk()
    errors = (OSError, ValueError, RecursionError, MemoryError, UnicodeDecodeError,
              w.yaml.YAMLError)
    try:
        ok = w.visit(Path(path))
        if ok and scene_path is not None:
            sp = Path(scene_path)
            data = read_bytes(sp, MAX_BYTES)
            w.tables(sp, w.load(data, b"table"))
    except errors:
        ok = False
    return w.out if ok or partial else None


def run_inputs(model_path=None, scene_path=None, *more):
    """The inputs of a run that no output may replace (bgc.base.outfiles.Inputs): the model,
    the scene, every file they reach (as far as they can be read) and ``more``."""
    ins = Inputs([p for p in (model_path, scene_path, *more) if p is not None])
    if model_path is not None:
        for r in reached_files(model_path, scene_path, partial=True) or ():
            ins.add(r.path)
    return ins
