"""The sweep's store folder: bgc marks it as its own (bgc.base.outdirs.MARKER), refuses any
other folder that is not empty, and on ``--restart`` removes only the store's own entries."""
from __future__ import annotations

import os
from pathlib import Path

from bgc.base.errors import ModelError
from bgc.base.outdirs import marked_as, out_folder

__all__ = ["STORE_KIND", "check_store"]


def check_store(out) -> Path:
    """``--out`` as a store: missing, an empty folder or a store bgc made (marked), else an
    error (before anything runs)."""
    out = out_folder(out, "--out", create=False)
    if out.exists() and marked_as(out) != STORE_KIND and os.listdir(out):
        raise ModelError(None, f"--out {str(out)!r} exists and is not a sweep store bgc made "
                               "(it has no marker file): name a new or empty folder; bgc "
                               "never empties a folder it did not make")
    return out


#: The marker's word for a sweep store (bgc.base.outdirs.mark_folder).
STORE_KIND = "bgc sweep store"
_ZARR_FILES = (".zattrs", ".zgroup", ".zmetadata", "zarr.json")


def _zarr_own(name: str, path: Path) -> bool:
    """Whether an entry of a store folder is the store's own: a Zarr metadata file, or a
    folder (not a link) holding a Zarr array's metadata."""
    if name in _ZARR_FILES:
        return True
    return path.is_dir() and not path.is_symlink() and any(
        (path / f).is_file() for f in (".zarray", ".zattrs", "zarr.json"))


def _zarr_entries(out: Path) -> bool:
    return any((out / f).exists() for f in _ZARR_FILES)
