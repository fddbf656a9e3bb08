"""Re-rolled functions in the numpy module (issue 27): a lowered function that is mostly
repeated structure (:mod:`bgc.lower.reroll`'s runs: a ladder's sections, a chain's links)
printed as vectorised statements over the runs' index arrays.

Each statement of a loop's body becomes one array statement over all its iterations: the
leaves that change from one instance to the next are gathered first (``_g0 = x[0:1000]``,
``_g1 = _pa[_IX[3]]``: a slice where the indices are affine, a static index table ``_IX[k]``
otherwise), then the values are computed and scattered at once (``_w[4:1004] = _c0*_g0``).
The temporaries the loops write (and those they read by index) live in one array ``_w`` of
``Rolled.values`` slots; the parameters the loops read per instance are gathered from one
array ``_pa`` (``_param_array``: made once per tuple of parameter values, so once per run).

Order: the vector form runs statement by statement, each over all iterations, where the loop
runs iteration by iteration. The two agree exactly when no statement reads a value that the
same statement or a later one of the same loop writes (a neighbour's value written by an
earlier statement is fine: that statement has run for every iteration). A loop that reads
what it writes otherwise is a true recurrence and stays a loop (``for _i in range(count)``,
the same statements on one index at a time), in the order of the lines it replaces.

A function whose loops cover less than :data:`MIN_COVER` of its lines is printed as before,
line by line (and so is every function without runs: such a module is unchanged).
"""
from __future__ import annotations

import numpy as np

from bgc.lower import ir as lower
from bgc.lower import reroll as rr
from bgc.lower.reroll import Index, Loop, Result, reroll

#: the least share of a function's lines (definitions and results) its loops must cover for
#: the numpy module to print it vectorised. Scattered short runs (the 3R2S's Jacobian: at
#: most half of its lines in loops) would pay each vector statement's gathers and scatter for
#: a handful of values; a function of many instances (a ladder: 97 %) pays them once for all.
MIN_COVER = 0.75

_ARRAY = {"x": "x", "p": "_pa", "v": "_w"}


class Tables:
    """The static index tables of one module, shared by its functions: ``_IX[k]``."""

    def __init__(self):
        self.rows: dict[tuple[int, ...], int] = {}

    def ref(self, values: tuple[int, ...]) -> str:
        k = self.rows.setdefault(tuple(int(v) for v in values), len(self.rows))
        return f"_IX[{k}]"

    @property
    def literals(self) -> list[str]:
        """Each table as the text of a list literal, in the order of their numbers."""
        return ["[" + ", ".join(str(v) for v in t) + "]" for t in self.rows]


def _slice(ix: Index, count: int, tables: Tables) -> str:
    """The index text selecting all ``count`` iterations' entries at once."""
    if ix.table:
        return tables.ref(ix.table)
    stop = ix.start + ix.stride * count
    if ix.stride == 1:
        return f"{ix.start}:{stop}"
    return f"{ix.start}:{stop if stop >= 0 else ''}:{ix.stride}"


def _one(ix: Index, tables: Tables) -> str:
    """The index text of iteration ``_i`` alone (a loop kept as a loop)."""
    if ix.table:
        return f"{tables.ref(ix.table)}[_i]"
    if ix.stride == 0:
        return str(ix.start)
    return f"{ix.start} + {ix.stride}*_i" if ix.start else f"{ix.stride}*_i"


def _vector_order(loop: Loop, slot_of: dict) -> list[int] | None:
    """The order in which the loop's statements can each run over all iterations at once
    (see the module's docstring), or None for a recurrence. Every value is written once and
    read after it is written, so a statement only has to come after the statements whose
    values it reads (in the same iteration or an earlier one): the body's order, with a
    statement moved after those; a statement that reads its own values, or a cycle of
    statements, is a recurrence."""
    writer: dict = {}
    for j, st in enumerate(loop.body):
        if st.array == "v":
            for s in _slots(st.index, loop.count):
                writer[s] = j
    needs = []
    for st in loop.body:
        reads = set()
        for r in st.reads:
            if r.array == "v":
                reads |= _slots(r.index, loop.count)
        reads |= {slot_of[s] for s in st.expr.free_symbols if s in slot_of}
        needs.append({writer[s] for s in reads if s in writer})
    order: list[int] = []
    done: set = set()
    while len(order) < len(loop.body):
        ready = [j for j in range(len(loop.body)) if j not in done and needs[j] <= done]
        if not ready:
            return None  # a statement that needs itself (directly or round a cycle)
        order.append(ready[0])
        done.add(ready[0])
    return order


def _slots(ix: Index, count: int) -> set:
    return set(ix.table) if ix.table else {ix.start + ix.stride * i for i in range(count)}


class Emitter:
    """Prints one re-rolled function's items as numpy lines (``Line``: target, code,
    comment; a loop kept as a loop is one Line without target holding its whole text)."""

    def __init__(self, printer, line_cls, rolled, out_ref, tables: Tables):
        self.printer, self.Line, self.rolled = printer, line_cls, rolled
        self.out_ref = out_ref  # result position -> the result array's flat index
        self.tables = tables
        self.named = {s: f"_w[{k}]" for s, k in rolled.values.items()}

    def code(self, expr, extra=None) -> str:
        """``expr``'s text, its values named by their slots (``_w[k]``) and the symbols of
        ``extra`` (symbol -> text) by their texts."""
        if not extra:
            return self.printer.doprint(expr)
        with self.printer.renamed(extra):
            return self.printer.doprint(expr)

    def lines(self, out_name: str) -> list:
        with self.printer.renamed(self.named):
            return self._lines(out_name)

    def _lines(self, out_name: str) -> list:
        out = []
        for it in self.rolled.items:
            if isinstance(it, Loop):
                out += self._loop(it, out_name)
            elif isinstance(it, Result):
                out.append(self.Line(f"{out_name}[{self.out_ref(it.key)}]", self.code(it.expr)))
            else:
                tgt = it.target
                name = f"_w[{self.rolled.values[tgt]}]" if tgt in self.rolled.values else str(tgt)
                out.append(self.Line(name, self.code(it.expr), it.comment))
        return out

    def _target(self, st, count: int, out_name: str, index_text) -> str:
        """The text a statement assigns to: the values, or the results' array at the
        positions its results have there."""
        if st.array == "v":
            return f"_w[{index_text(st.index)}]"
        ix = st.index  # the results' positions among the function's results
        keys = [self.out_ref(ix.table[i] if ix.table else ix.start + ix.stride * i)
                for i in range(count)]
        return f"{out_name}[{index_text(Index.of(keys))}]"

    def _loop(self, loop: Loop, out_name: str) -> list:
        order = _vector_order(loop, self.rolled.values)
        if order is not None:  # one vector statement per statement of the body
            def every(ix):
                return _slice(ix, loop.count, self.tables)
            out = []
            for st in (loop.body[j] for j in order):
                extra = {}
                for j, r in enumerate(st.reads):
                    out.append(self.Line(f"_g{j}", f"{_ARRAY[r.array]}[{every(r.index)}]"))
                    extra[r.name] = f"_g{j}"
                why = f"{st.comment} (and {loop.count - 1} more alike)" if st.comment else ""
                out.append(self.Line(self._target(st, loop.count, out_name, every),
                                     self.code(st.expr, extra), why))
            return out

        def one(ix):
            return _one(ix, self.tables)
        text = [f"for _i in range({loop.count}):  # a recurrence: one instance at a time"]
        for st in loop.body:
            extra = {r.name: f"{_ARRAY[r.array]}[{one(r.index)}]" for r in st.reads}
            text.append(f"        {self._target(st, loop.count, out_name, one)} = "
                        f"{self.code(st.expr, extra)}")
        return [self.Line("", "\n".join(text))]


def rolled_function(fn: lower.Function, printer, line_cls, function_cls, states: list,
                    params: list, kind: str, tables: Tables):
    """The function printed vectorised (a ``function_cls`` with ``rolled`` set), or None where
    it has no runs or they cover less than :data:`MIN_COVER` of it. ``kind``: "rhs" (results
    into ``_dx`` by state), "jac" (into ``_Jv``: the values at JAC_SPARSITY's nonzeros, in
    order), "outs" (into ``_o``), "init" (into ``_x0`` by state), "ujac" and "yjac" (into
    ``_Bv`` and ``_Yv``, in the order of their results; numpy arrays only, as their unrolled
    forms)."""
    need = MIN_COVER * (len(fn.lines) + len(fn.results))
    if not may_cover(fn, need):
        return None
    rolled = reroll(fn, states, params)
    covered = sum(it.count * len(it.body) for it in rolled.items if isinstance(it, Loop))
    if not rolled.loops or covered < need:
        return None
    keys = [k for k, _ in fn.results]
    out_name, out_ref = {
        "rhs": ("_dx", lambda pos: int(keys[pos])),
        "jac": ("_Jv", lambda pos: pos),
        "outs": ("_o", lambda pos: pos),
        "init": ("_x0", lambda pos: int(keys[pos])),
        "ujac": ("_Bv", lambda pos: pos),
        "yjac": ("_Yv", lambda pos: pos)}[kind]
    xp = "np" if kind in ("init", "ujac", "yjac") else "xp"
    em = Emitter(printer, line_cls, rolled, out_ref, tables)
    body = em.lines(out_name)
    used = set()
    for it in rolled.items:
        used |= it.symbols if isinstance(it, Loop) else it.expr.free_symbols
    names = {str(s) for s in used}
    head = []
    if rolled.nvalues:
        head.append(line_cls("_w", f"np.empty(({rolled.nvalues},) + _bs)" if xp == "np" else
                             f"xp.empty(({rolled.nvalues},) + _bs, dtype=xp.float64, "
                             "device=_device(x))"))
    if any(r.array == "p" for it in rolled.items if isinstance(it, Loop)
           for st in it.body for r in st.reads):
        head.append(line_cls("_pa", f"_param_array(_pv, _bshape, _bs, {xp})"))
    state_names = {str(s): k for k, s in enumerate(states)}
    head += [line_cls(name, f"x[{state_names[name]}]") for name in fn.states
             if name != "_" and name in names]
    return function_cls(tuple(p for p in fn.params if p in names),
                        tuple(u for u in fn.inputs if u in names),
                        tuple("_" for _ in fn.states), tuple(head + body), (), fn.ops,
                        rolled=True, nresults=len(fn.results))


def may_cover(fn: lower.Function, need: float) -> bool:
    """False where :func:`bgc.lower.reroll.reroll`'s loops cannot cover ``need`` of the
    function's items (lines, then results), told without rerolling it (the 3R2S's rhs,
    Jacobian and outputs: a fifth of the time rerolling them took).

    An upper bound: every item gets a coarse shape (:func:`_coarse`), equal wherever
    reroll's shapes are equal. A loop of period p and MIN_RUN or more
    iterations starting at s needs the shapes to repeat with period p over the
    (MIN_RUN - 1)*p items from s, so the coarse shapes do too; every item of every stretch
    where they do, for every period reroll tries, is counted (items in no such stretch can be
    in no loop). The count is at least what the loops cover; it stops as soon as it reaches
    ``need``."""
    ids: dict = {}
    seq = [ids.setdefault(_coarse("line", ln.expr), len(ids)) for ln in fn.lines]
    seq += [ids.setdefault(_coarse("out", r), len(ids)) for _, r in fn.results]
    a = np.asarray(seq, dtype=np.int64)
    n = len(a)
    marks = np.zeros(n + 1, dtype=np.int64)  # +1 where a counted stretch starts, -1 after it
    run = max(2, rr.MIN_RUN)  # (reroll's least run, read now: tests change it)
    for p in range(1, min(rr.MAX_PERIOD, n // run) + 1):
        span = (run - 1) * p
        breaks = np.concatenate(([0], np.cumsum(a[:-p] != a[p:])))
        starts = np.flatnonzero(breaks[span:] == breaks[:-span])  # a[s:s+span] = a[s+p:...]
        if starts.size:
            marks[starts] += 1
            marks[starts + span + p] -= 1  # a loop's items: s .. s + run*p - 1, at most
            if np.count_nonzero(np.cumsum(marks[:-1])) >= need:
                return True
    return False


def _coarse(kind: str, e) -> tuple:
    """The item's kind, and the head of its expression and its number of arguments (every
    leaf one coarse shape): equal wherever reroll's shapes (its kind, ``e.func`` and the
    shapes of ``e.args``) are."""
    args = e.args
    return (kind, e.func, len(args)) if args else (kind,)
