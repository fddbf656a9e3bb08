"""Reading untrusted files with bounded work.

A model, an imported file or a scene is opened without following a FIFO's promise to block
(``O_NONBLOCK``), checked with ``fstat`` to be a regular file no larger than its limit, and
read at most ``limit + 1`` bytes, so a device (``/dev/zero``), a FIFO, a folder or a huge
sparse file is refused before any of it is read.
"""
from __future__ import annotations

import errno
import os
import stat

from bgc.base.errors import Coord, ModelError


def _located(coord: Coord | None, path: str) -> Coord:
    return coord if coord is not None else Coord(path, 1, 1)


def read_text_bounded(path, coord: Coord | None, what: str, limit: int) -> str:
    """The UTF-8 text of the regular file ``path`` (at most ``limit`` bytes).

    ``coord``: where the file is named (an import, a scene's ``model:``), or None for a file
    named on the command line (the error is then placed at the file's first character).
    ``what``: "model file", "imported file", "scene file"."""
    spath = os.fspath(path)
    where = _located(coord, spath)
    shown = _show(spath)
    if "\0" in spath:
        raise ModelError(where, f"cannot read {what} {shown}: the path contains a NUL byte")
    data = _read_bounded(spath, where, shown, what, limit)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        before = data[:exc.start]
        line = before.count(b"\n") + 1
        col = len(before[before.rfind(b"\n") + 1:].decode("utf-8", "replace")) + 1
        raise ModelError(Coord(spath, line, col), f"{what} is not UTF-8 text "
                                                  f"(byte 0x{data[exc.start]:02x})") from None


def read_bytes_bounded(path, what: str, limit: int) -> bytes:
    """The bytes of the regular file ``path``, at most ``limit`` of them: a ModelError (at the
    file's first character) for a folder, FIFO, device, or a file over the limit. For readers
    that digest files (the compile cache's key) before any parser has checked them."""
    spath = os.fspath(path)
    if "\0" in spath:
        raise ModelError(Coord(spath, 1, 1), f"cannot read {what}: the path contains a NUL byte")
    return _read_bounded(spath, Coord(spath, 1, 1), _show(spath), what, limit)


def _read_bounded(spath: str, where: Coord, shown: str, what: str, limit: int) -> bytes:
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0)
    try:
        fd = os.open(spath, flags)
    except OSError as exc:
        raise ModelError(where, f"cannot read {what} {shown}: {_why(exc)}") from None
    try:
        st = os.fstat(fd)
        if stat.S_ISDIR(st.st_mode):
            raise ModelError(where, f"cannot read {what} {shown}: it is a folder")
        if not stat.S_ISREG(st.st_mode):
            raise ModelError(where, f"cannot read {what} {shown}: not a regular file "
                                    "(a device, FIFO or socket)")
        if st.st_size > limit:
            raise ModelError(where, f"{what} {shown} is larger than the limit of {limit} bytes "
                                    f"({st.st_size} bytes)")
        chunks, total = [], 0
        while total <= limit:
            try:
                chunk = os.read(fd, min(1 << 20, limit + 1 - total))
            except BlockingIOError:  # pragma: no cover - regular files never block
                break
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
        if total > limit:  # the file grew while it was read
            raise ModelError(where, f"{what} {shown} is larger than the limit of {limit} bytes")
    except OSError as exc:
        raise ModelError(where, f"cannot read {what} {shown}: {_why(exc)}") from None
    finally:
        os.close(fd)
    return b"".join(chunks)


def _why(exc: OSError) -> str:
    if exc.errno == errno.ELOOP:
        return "too many levels of symbolic links (a symlink loop?)"
    if exc.errno == errno.ENOENT:
        return "no such file"
    return exc.strerror or type(exc).__name__


def _show(path: str) -> str:
    r = repr(path)
    return r if len(r) <= 120 else r[:100] + "...'"
