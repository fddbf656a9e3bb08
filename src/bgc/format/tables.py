"""Table inputs: an input given as data, ``{table: FILE.csv, columns: [t, v], interp:
linear|pchip|previous, extrapolate: hold|error}``.

The file is read relative to the model or scene file that names it, only if it is a regular
file no larger than :data:`MAX_BYTES`; its shape is checked (at least two rows, finite
numbers, strictly increasing time) with errors at the ``table:`` key or at the CSV's own
``file:line``. Only the numbers reach the generated module, as float literals.
"""
from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path

from bgc.base.errors import Coord, ModelError
from bgc.base.safeio import read_text_bounded
from bgc.format.reader import require

MAX_BYTES = 16 * 1024 * 1024
MAX_ROWS = 200_000  # every row becomes two float literals in the generated module
INTERP = ("linear", "pchip", "previous")
EXTRAPOLATE = ("hold", "error")


@dataclass(frozen=True)
class Table:
    file: str  # as written in the model
    t: tuple[float, ...]
    v: tuple[float, ...]
    interp: str
    extrapolate: str
    coord: Coord

    @property
    def kinks(self) -> tuple[float, ...]:
        """Where the interpolant is not smooth: every knot (linear, previous), none (pchip:
        continuously differentiable)."""
        return () if self.interp == "pchip" else self.t


def is_table(r, node) -> bool:
    import yaml

    return isinstance(node, yaml.MappingNode) and any(
        isinstance(k, yaml.ScalarNode) and k.value == "table" for k, _ in node.value)


def read_table(r, node, what: str, extra_keys=()) -> Table:
    """The table a mapping node describes (``r`` is parse's reader: coordinates, types)."""
    m = r.mapping(node, what)
    require(r, m, node, ("table", "columns", "interp", "extrapolate") + tuple(extra_keys), what,
             required=("table",))
    tcoord = r.coord(m["table"][0])
    rel = r.string(m["table"][1], f"{what}: table")
    interp = r.string(m["interp"][1], "interp") if "interp" in m else "linear"
    if interp not in INTERP:
        raise ModelError(r.coord(m["interp"][1]), f"{what}: interp {interp!r} is not one of "
                                                  f"{', '.join(INTERP)}")
    extra = r.string(m["extrapolate"][1], "extrapolate") if "extrapolate" in m else "hold"
    if extra not in EXTRAPOLATE:
        raise ModelError(r.coord(m["extrapolate"][1]), f"{what}: extrapolate {extra!r} is not "
                                                       f"one of {', '.join(EXTRAPOLATE)}")
    columns = None
    if "columns" in m:
        cn = m["columns"][1]
        items = r.seq(cn, f"{what}: columns")
        if len(items) != 2:
            raise ModelError(r.coord(cn), f"{what}: columns is [time, value] (two columns)")
        columns = [r.scalar(c, "column") for c in items]
        for c, cnode in zip(columns, items):
            if isinstance(c, bool) or not isinstance(c, (int, str)) or (
                    isinstance(c, int) and c < 0):
                raise ModelError(r.coord(cnode), f"{what}: a column is a header name or a "
                                                 "column number (0 first)")
    t, v = load_csv(Path(r.path).parent, rel, columns, tcoord, what)
    return Table(rel, t, v, interp, extra, tcoord)


def load_csv(base: Path, rel: str, columns, coord: Coord, what: str):
    """(times, values) from the CSV file ``rel`` (relative to ``base``)."""
    if not rel or Path(rel).is_absolute():
        raise ModelError(coord, f"{what}: the table file is given relative to this file, not "
                                f"as an absolute path ({rel!r})")
    path = base / rel

    text = read_text_bounded(path, coord, f"{what}: table", MAX_BYTES).removeprefix("\ufeff")
    rows = []
    for lineno, line in enumerate(io.StringIO(text), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        rows.append((lineno, next(csv.reader([s]))))
    where = lambda ln: Coord(str(path), ln, 1)  # noqa: E731
    if not rows:
        raise ModelError(coord, f"{what}: table {rel!r} is empty")
    header = None
    if not all(_is_number(c) for c in rows[0][1]):
        header = [c.strip() for c in rows[0][1]]
        rows = rows[1:]
    cols = columns if columns is not None else [0, 1]
    idx = []
    for c in cols:
        if isinstance(c, str):
            if header is None or c not in header:
                # only what the model wrote: the file may be any file (through '..' or a
                # link), and its first line is not the model's to show
                where_ = "its first line is not a header" if header is None else \
                    "no cell of its header line is that name"
                raise ModelError(coord, f"{what}: table {rel!r} has no column {c!r} ({where_})")
            idx.append(header.index(c))
        else:
            idx.append(c)
    t, v = [], []
    for lineno, cells in rows:
        vals = []
        for k, name in zip(idx, ("time", "value")):
            if k >= len(cells):
                raise ModelError(where(lineno), f"{what}: row has {len(cells)} column(s), the "
                                                f"{name} is column {k}")
            cell = cells[k].strip()
            if not _is_number(cell):
                raise ModelError(where(lineno), f"{what}: the {name} (column {k}) is not a "
                                                "number")
            x = float(cell)
            if not math.isfinite(x):
                raise ModelError(where(lineno), f"{what}: the {name} (column {k}) is not finite")
            vals.append(x)
        if len(t) >= MAX_ROWS:
            raise ModelError(where(lineno), f"{what}: more than {MAX_ROWS} rows (the limit for "
                                            "a table compiled into the module)")
        if t and not vals[0] > t[-1]:
            raise ModelError(where(lineno), f"{what}: time {vals[0]:g} does not increase "
                                            f"(previous row {t[-1]:g})")
        t.append(vals[0])
        v.append(vals[1])
    if len(t) < 2:
        raise ModelError(coord, f"{what}: table {rel!r} needs at least two rows of data "
                                f"(has {len(t)})")
    return tuple(t), tuple(v)


def _is_number(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True
