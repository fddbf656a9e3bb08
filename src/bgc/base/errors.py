"""Locations and user errors.

Every node the parser builds carries a :class:`Coord`; every mistake in a model or scene is a
:class:`ModelError` that prints as ``file:line:col: message`` (pycparser's convention).
"""
from __future__ import annotations

from dataclasses import dataclass, field

from bgc.base.limits import LIMITS


def oneline(text, limit: int = 200) -> str:
    """Free text made safe for one line inside a docstring or a comment: control characters,
    line breaks and unprintable characters become visible escapes; long text is cut."""
    s = "".join(c if c.isprintable() else repr(c)[1:-1] for c in str(text))
    return s if len(s) <= limit else s[:limit - 3] + "..."


#: The most lines of advice a ModelError carries after its message.
ADVICE_LINES = 12


@dataclass(frozen=True)
class Coord:
    """A place in a source file: 1-based line and column. ``via``: what stands at that place
    when the error is really inside a library part the user's line brought in (``element
    'r4.lock' (from bgc:mechanics.spatial revolute_lock)``): a message located here starts
    with it. Not part of the place's identity."""

    file: str
    line: int
    column: int
    via: str = field(default="", compare=False)

    def __str__(self) -> str:
        return f"{self.file}:{self.line}:{self.column}"

    def shifted(self, line_offset: int, col_offset: int) -> "Coord":
        """The coordinate of a character inside an expression that starts here."""
        if line_offset == 0:
            return Coord(self.file, self.line, self.column + col_offset)
        return Coord(self.file, self.line + line_offset, col_offset + 1)


class ModelError(Exception):
    """A mistake in user input (model or scene): reported with its place, exit status 2.

    The message is one line, ``file:line:col: message``, cut at the limit of messages (user
    text it quotes can be long). ``advice``, bgc's own text on what to do, follows on lines of
    its own, never cut (each line made printable; at most :data:`ADVICE_LINES` lines)."""

    def __init__(self, coord: Coord | None, message: str, advice: str = ""):
        # One line, of bounded length, whatever user text the message quotes.
        message = " ".join(str(message).splitlines())
        via = getattr(coord, "via", "")
        if via and not message.startswith(via):
            message = f"{via}: {message}"
        cap = LIMITS.message_chars
        if len(message) > cap:
            message = message[:cap - 3] + "..."
        self.coord = coord
        self.message = message
        self.advice = "\n".join("  " + oneline(line.strip(), 4 * cap)
                                for line in str(advice).splitlines()[:ADVICE_LINES]
                                if line.strip())
        first = f"{coord}: {message}" if coord else message
        super().__init__(first + ("\n" + self.advice if self.advice else ""))


class SimulationFailed(ModelError):
    """A run that failed numerically or was stopped (non-finite values, a solver failure, a
    stiff model for an explicit method, a time limit): reported with its place, exit status 1."""


class InternalError(Exception):
    """A bug in bgc, not in the user's model."""
