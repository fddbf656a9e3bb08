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
    try:
        data = read_bytes(spath, limit)
    except _Refused as exc:
        raise ModelError(where, exc.message(what, shown, limit)) from None
    except OSError as exc:
        raise ModelError(where, f"cannot read {what} {shown}: {_why(exc)}") from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        before = data[:exc.start]
        line = before.count(b"\n") + 1
        col = len(before[before.rfind(b"\n") + 1:].decode("utf-8", "replace")) + 1
        raise ModelError(Coord(spath, line, col), f"{what} is not UTF-8 text "
                                                  f"(byte 0x{data[exc.start]:02x})") from None


class _Refused(OSError):
    """A file that is not read: not a regular file, or larger than the limit."""

    def __init__(self, kind: str, size: int = 0):
        super().__init__(kind)
        self.kind, self.size = kind, size

    def message(self, what: str, shown: str, limit: int) -> str:
        if self.kind == "folder":
            return f"cannot read {what} {shown}: it is a folder"
        if self.kind == "special":
            return f"cannot read {what} {shown}: not a regular file (a device, FIFO or socket)"
        size = f" ({self.size} bytes)" if self.size else ""
        return f"{what} {shown} is larger than the limit of {limit} bytes{size}"


def read_bytes(path, limit: int, follow: bool = True) -> bytes:
    """The bytes of the regular file ``path``, at most ``limit`` of them: opened without
    blocking (``O_NONBLOCK``: a FIFO's open returns at once), checked with ``fstat`` to be a
    regular file no larger than ``limit`` before anything is read, read at most ``limit + 1``
    bytes (a file that grows meanwhile is refused). ``follow=False``: a symbolic link as the
    last part of the path is refused (``O_NOFOLLOW``). Raises ``OSError`` (a refusal is one
    too, whose ``kind`` says why): every caller that only wants the bytes or nothing catches
    ``OSError``."""
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0)
    if not follow:
        flags |= getattr(os, "O_NOFOLLOW", 0)
    fd = os.open(os.fspath(path), flags)
    try:
        st = os.fstat(fd)
        if stat.S_ISDIR(st.st_mode):
            raise _Refused("folder")
        if not stat.S_ISREG(st.st_mode):
            raise _Refused("special")
        if st.st_size > limit:
            raise _Refused("size", st.st_size)
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
            raise _Refused("size")
    finally:
        os.close(fd)
    return b"".join(chunks)


def not_a_file(path) -> str | None:
    """Why ``path`` is not a regular file to read ("does not exist", "is a folder", ...), or
    None when it is one (links followed): the words after "model file" in a message."""
    try:
        st = os.stat(path)
    except (OSError, ValueError) as exc:
        return "does not exist" if isinstance(exc, ValueError) or exc.errno in (
            errno.ENOENT, errno.ENOTDIR) else f"cannot be read: {_why(exc)}"
    if stat.S_ISDIR(st.st_mode):
        return "is a folder"
    if not stat.S_ISREG(st.st_mode):
        return "is not a regular file (a device, FIFO or socket)"
    return None


def _why(exc: OSError) -> str:
    if exc.errno == errno.ELOOP:
        return "too many levels of symbolic links (a symlink loop?)"
    if exc.errno == errno.ENOENT:
        return "no such file"
    return exc.strerror or type(exc).__name__


def _show(path: str) -> str:
    r = repr(path)
    return r if len(r) <= 120 else r[:100] + "...'"


def read_bytes_bounded(path, what: str, limit: int) -> bytes:
    """The bytes of the regular file ``path``, at most ``limit`` of them, or a ModelError at
    the file's first character (a folder, FIFO, device, or a file over the limit): for readers
    that digest files (the compile cache's key) before any parser has checked them."""
    spath = os.fspath(path)
    where, shown = Coord(spath, 1, 1), _show(spath)
    if "\0" in spath:
        raise ModelError(where, f"cannot read {what} {shown}: the path contains a NUL byte")
    try:
        return read_bytes(spath, limit)
    except _Refused as exc:
        raise ModelError(where, exc.message(what, shown, limit)) from None
    except OSError as exc:
        raise ModelError(where, f"cannot read {what} {shown}: {_why(exc)}") from None
