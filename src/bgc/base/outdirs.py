"""Folder outputs: the checked writer (bgc.base.outfiles) for commands that write a folder.

``compile --target c -o DIR``, ``linearize --out DIR``, ``examples DIR``, ``sweep --out``,
``accuracy --out`` and ``simulate --plot`` write files into a folder the user names. Inside
it bgc never goes through a link: every sub-folder it needs is made (or found) with ``lstat``
checks, so a link at ``DIR/runtime`` or ``DIR/models`` is refused, not followed; each file is
written by :func:`bgc.base.outfiles.write_output` (never an input, never a link, never over
anything but a regular file, atomic). A copy reads its source with the bounded reader.

A folder that bgc may later remove whole (a sweep's store) carries a marker file,
:data:`MARKER`, naming what made it; :func:`remove_marked` removes only such a folder and in it
only the entries its maker says are its own.
"""
from __future__ import annotations

import os
import stat
from pathlib import Path

from bgc.base.outfiles import (
    Inputs,
    OutputError,
    _kind,
    _reason,
    check_output,
    write_output,
)
from bgc.base.safeio import read_bytes

__all__ = ["MARKER", "check_in", "copy_file", "inside", "mark_folder", "marked_as", "out_folder",
           "remove_marked", "sub_folder", "write_in"]

#: The marker of a folder bgc made and may remove (its first line says which command).
MARKER = ".bgc-output"


def out_folder(folder, what: str = "output folder", create: bool = True) -> Path:
    """The folder the user named, created (``mkdir -p``) when missing: an error if it is a
    symbolic link (bgc does not write through links), or exists and is not a folder."""
    text = os.fspath(folder) if folder is not None else ""
    if text == "":
        raise OutputError(what, "", "the path is empty")
    if "\0" in text:
        raise OutputError(what, text, "the path contains a NUL character")
    p = Path(text)
    st = _lstat(p, what, text)
    if st is None and create:
        try:
            p.mkdir(parents=True, exist_ok=True)
        except FileExistsError:
            pass
        except NotADirectoryError:
            raise OutputError(what, text, "a part of the path is a file, not a folder") from None
        except OSError as exc:
            raise OutputError(what, text, f"cannot create the folder: {_reason(exc)}") from None
        st = _lstat(p, what, text)
    if st is not None:
        _must_be_folder(st, what, text)
    return p


def _lstat(p: Path, what: str, text: str):
    try:
        return os.lstat(p)
    except FileNotFoundError:
        return None
    except NotADirectoryError:
        raise OutputError(what, text, "a part of the path is a file, not a folder") from None
    except OSError as exc:
        raise OutputError(what, text, _reason(exc)) from None


def _must_be_folder(st, what: str, text: str) -> None:
    if stat.S_ISLNK(st.st_mode):
        raise OutputError(what, text, "is a symbolic link; bgc does not write through links: "
                                      "name the folder itself")
    if stat.S_ISREG(st.st_mode):
        raise OutputError(what, text, "exists and is not a folder")
    if not stat.S_ISDIR(st.st_mode):
        raise OutputError(what, text, f"is {_kind(st.st_mode)}, not a folder")


def sub_folder(root: Path, rel: str, what: str = "output folder") -> Path:
    """``root/rel`` (rel: '/'-separated, no '..'), each part made if missing and checked to be
    a folder, not a link."""
    p = Path(root)
    for part in [x for x in rel.split("/") if x not in ("", ".")]:
        if part == "..":
            raise OutputError(what, str(p / rel), "leaves the output folder")
        p = p / part
        st = _lstat(p, what, str(p))
        if st is None:
            try:
                p.mkdir()
            except FileExistsError:
                pass
            except OSError as exc:
                raise OutputError(what, str(p), f"cannot create the folder: {_reason(exc)}") \
                    from None
            st = _lstat(p, what, str(p))
        _must_be_folder(st, what, str(p))
    return p


def check_in(root: Path, rel: str, inputs: Inputs | None = None, what: str = "output") -> Path:
    """The checks of :func:`write_in` without writing: each existing folder on the way is a
    folder, not a link, and the file may be replaced (bgc.base.outfiles.check_output)."""
    p = Path(root)
    for part in [x for x in rel.split("/")[:-1] if x not in ("", ".")]:
        if part == "..":
            raise OutputError(what, str(p / rel), "leaves the output folder")
        p = p / part
        st = _lstat(p, what, str(p))
        if st is None:
            break
        _must_be_folder(st, what, str(p))
    return check_output(Path(root) / rel, inputs, what)


def write_in(root: Path, rel: str, data, inputs: Inputs | None = None,
             what: str = "output") -> Path:
    """Write ``data`` to ``root/rel`` through the checked writer, its folders made inside root
    without following links."""
    head, _, name = rel.rpartition("/")
    return write_output(sub_folder(root, head, what) / name, data, inputs, what)


def copy_file(src, root: Path, rel: str, inputs: Inputs | None = None, what: str = "output",
              limit: int = 64 << 20) -> Path:
    """Copy the regular file ``src`` (bgc's own: a template, an example) to ``root/rel``: read
    with the bounded reader, written with the checked writer (never through a link)."""
    try:
        data = read_bytes(src, limit)
    except OSError as exc:
        raise OutputError(what, os.fspath(src), f"cannot read the file to copy: "
                                                f"{_reason(exc)}") from None
    return write_in(root, rel, data, inputs, what)


def inside(path, folder) -> bool:
    """Whether ``path`` (resolved) lies in ``folder`` (resolved), or is it."""
    try:
        p, f = os.path.realpath(path), os.path.realpath(folder)
    except (OSError, ValueError):
        return False
    return p == f or p.startswith(f.rstrip(os.sep) + os.sep)


def mark_folder(folder: Path, kind: str, inputs: Inputs | None = None,
                what: str = "output folder") -> Path:
    """Make ``folder`` a marked output of ``kind``: it must be missing, empty or already marked
    for ``kind`` (a folder holding anything else is not bgc's to fill)."""
    p = out_folder(folder, what)
    mark = marked_as(p)
    if mark == kind:
        return p
    if mark is not None:
        raise OutputError(what, str(p), f"is a {mark} folder of bgc's, not a {kind} folder")
    try:
        entries = os.listdir(p)
    except OSError as exc:
        raise OutputError(what, str(p), _reason(exc)) from None
    if entries:
        raise OutputError(what, str(p), "exists and is not empty, and bgc did not make it "
                                        f"(no {MARKER} file): name a new or empty folder")
    write_output(p / MARKER, f"{kind}\nmade by bgc; bgc may remove this folder's {kind} "
                              "files\n", inputs, what)
    return p


def marked_as(folder) -> str | None:
    """The kind a marked folder was made for, or None (no marker, a link, not a folder)."""
    try:
        if not stat.S_ISDIR(os.lstat(folder).st_mode):
            return None
        data = read_bytes(Path(folder) / MARKER, 4096, follow=False)
    except OSError:
        return None
    first = data.split(b"\n", 1)[0].decode("ascii", "replace").strip()
    return first or None


def remove_marked(folder, kind: str, own, inputs: Inputs | None = None,
                  what: str = "output folder") -> int:
    """Remove from the marked ``folder`` the entries ``own(name, path)`` says are its own
    (never following a link, never one holding an input of the run), leaving everything else
    and the marker; returns how many were removed. An error unless the folder is a ``kind``
    folder bgc made."""
    import shutil

    text = os.fspath(folder)
    p = out_folder(folder, what, create=False)
    if not p.exists():
        return 0
    mark = marked_as(p)
    if mark != kind:
        raise OutputError(what, text, f"is not a {kind} folder bgc made (no {MARKER} file "
                                      f"saying {kind!r}): bgc removes only its own folders")
    held = [name for name in (inputs.ids.values() if inputs is not None else ()) if
            inside(name, p)]
    if held:
        raise OutputError(what, text, f"holds an input of this run ({held[0]!r}): not removed")
    n = 0
    for name in sorted(os.listdir(p)):
        sub = p / name
        if name == MARKER or not own(name, sub):
            continue
        st = os.lstat(sub)
        try:
            if stat.S_ISDIR(st.st_mode):
                shutil.rmtree(sub)  # does not follow links inside (it unlinks them)
            else:
                os.unlink(sub)
        except OSError as exc:
            raise OutputError(what, str(sub), f"cannot remove: {_reason(exc)}") from None
        n += 1
    return n
