"""Where bgc's own files live (a leaf module: importing it imports nothing heavy).

The compile cache and the run records fingerprint bgc's code through :func:`code_files`: every
source file of every subpackage and every template, so an edit anywhere in bgc invalidates
what was built by the code before it.
"""
from __future__ import annotations

import os
from pathlib import Path

#: src/bgc (the package's own folder), found from this file: bgc/base/paths.py.
PACKAGE_DIR = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: .yaml: the component library (bgc/format/library), which shapes every model importing it
_CODE_SUFFIXES = (".py", ".j2", ".c", ".h", ".yaml")


def package_dir() -> Path:
    return Path(PACKAGE_DIR)


def templates_root() -> str:
    """templates/ of the source tree, else the installed package's copy (bgc/templates)."""
    repo = os.path.join(os.path.dirname(os.path.dirname(PACKAGE_DIR)), "templates")
    if os.path.isfile(os.path.join(repo, "numpy", "module.py.j2")):
        return repo
    return os.path.join(PACKAGE_DIR, "templates")


def templates_dir() -> Path:
    """templates/ of the source tree, else the installed package's copy (bgc.templates)."""
    return Path(templates_root())


def _tree(top: str, skip_top: tuple[str, ...] = ()) -> list[str]:
    out = []
    for dirpath, dirnames, filenames in os.walk(top):
        dirnames[:] = sorted(d for d in dirnames if d != "__pycache__"
                             and not (dirpath == top and d in skip_top))
        out += [os.path.join(dirpath, f) for f in sorted(filenames) if f.endswith(_CODE_SUFFIXES)]
    return out


def code_files() -> list[tuple[str, str]]:
    """(name, path) of every file of bgc's code that shapes an output: the sources of every
    subpackage and every template. Names are relative to their root (``bgc/...`` or
    ``templates/...``), so the same tree gives the same names wherever it is installed."""
    templates = templates_root()
    inside = os.path.dirname(templates) == PACKAGE_DIR  # installed: bgc/templates
    files = [("bgc/" + os.path.relpath(p, PACKAGE_DIR), p)
             for p in _tree(PACKAGE_DIR, ("templates", "examples", "docs") if inside else ())]
    files += [("templates/" + os.path.relpath(p, templates), p) for p in _tree(templates)]
    return files
