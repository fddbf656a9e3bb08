"""Locations and user errors.

Every node the parser builds carries a :class:`Coord`; every mistake in a model or scene is a
:class:`ModelError` that prints as ``file:line:col: message`` (pycparser's convention).
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Coord:
    """A place in a source file: 1-based line and column."""

    file: str
    line: int
    column: int

    def __str__(self) -> str:
        return f"{self.file}:{self.line}:{self.column}"

    def shifted(self, line_offset: int, col_offset: int) -> "Coord":
        """The coordinate of a character inside an expression that starts here."""
        if line_offset == 0:
            return Coord(self.file, self.line, self.column + col_offset)
        return Coord(self.file, self.line + line_offset, col_offset + 1)


class ModelError(Exception):
    """A mistake in user input (model or scene): reported with its place, exit status 2."""

    def __init__(self, coord: Coord | None, message: str):
        from .limits import LIMITS

        # One line, of bounded length, whatever user text the message quotes.
        message = " ".join(str(message).splitlines())
        cap = LIMITS.message_chars
        if len(message) > cap:
            message = message[:cap - 3] + "..."
        self.coord = coord
        self.message = message
        super().__init__(f"{coord}: {message}" if coord else message)


class InternalError(Exception):
    """A bug in bgc, not in the user's model."""
