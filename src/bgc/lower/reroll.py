"""Loop re-rolling (issue 27): repeated structure in a lowered function as loops over arrays.

A model that instantiates a component many times (an RC ladder's sections, a chain's links)
lowers to a body whose lines repeat with a period: the same expressions, up to which states,
parameters and temporaries they read and write. This pass finds such runs in a scheduled
:class:`bgc.lower.ir.Function` and replaces each by one :class:`Loop`, whose body is one
period of the run with every leaf that changes from one instance to the next read through
an :class:`Index` (affine ``start + stride*i`` where it can, else a table of indices):

    for (i = 0; i < count; i++)  v[w(i)] = f(x[a(i)], p[b(i)], v[c(i)], ...)

The shape of a line is its expression tree with every leaf replaced by its role: a state
("x"), a parameter ("p"), a temporary of the body ("v"), or, for every other symbol and every
number, the leaf itself (inputs, t and constants must be the same in every instance). The
arguments of sums and products are put in one order by their shapes, so ``a - b`` and
``-d + c`` are one shape. Shapes are numbered by hash-consing, so finding a shape costs one
visit of the expression.

Order: a loop runs its iterations in order and each iteration its statements in order, which
is exactly the order of the lines it replaces; a value an iteration reads from an earlier one
(a ladder's node reads its neighbour's current) is therefore always written before it is read.
The temporaries a loop writes, and those it reads by index, live in one array of values
(``Rolled.values``: symbol -> slot); every other line stays as it was.

:data:`MIN_RUN` is the fewest iterations worth a loop (chosen by bench/bench_reroll.py: see
bench/RESULTS_reroll.md); below it, and in a function without repetition, nothing changes.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import sympy as sp

from bgc.core.eqtypes import LinSolve, LinSolveEntry, NewtonSolve
from bgc.lower.cse import _rebuilt
from bgc.lower.ir import Function, Line

#: the fewest iterations a run must have to become a loop
MIN_RUN = 8
#: the longest period (lines per iteration) searched for, and how many repeats of a line's
#: shape after it are tried as the end of its period
MAX_PERIOD = 512
CANDIDATES = 16

_OPAQUE = (LinSolve, LinSolveEntry, NewtonSolve)


@dataclass(frozen=True)
class Index:
    """An iteration's index: ``start + stride*i``, or ``table[i]`` where ``table`` is set."""
    start: int = 0
    stride: int = 0
    table: tuple[int, ...] = ()

    @classmethod
    def of(cls, values) -> Index:
        vals = [int(v) for v in values]
        stride = vals[1] - vals[0] if len(vals) > 1 else 0
        if all(v == vals[0] + stride * i for i, v in enumerate(vals)):
            return cls(vals[0], stride)
        return cls(0, 0, tuple(vals))


@dataclass(frozen=True)
class Read:
    """A leaf of a loop's statement read per iteration: placeholder -> array ("x" the state,
    "p" the parameters, "v" the values) at an index."""
    name: sp.Symbol
    array: str
    index: Index


@dataclass(frozen=True)
class Stmt:
    """One statement of a loop's body: ``array[index] = expr`` with ``array`` "v" (a value) or
    "out" (a result of the function); ``expr`` holds the reads' placeholders."""
    expr: sp.Basic
    reads: tuple[Read, ...]
    array: str
    index: Index
    comment: str = ""


@dataclass(frozen=True)
class Loop:
    """``count`` iterations of ``body``; ``symbols``: the symbols every iteration reads as they
    are (parameters, states, inputs, temporaries the same in every instance)."""
    count: int
    body: tuple[Stmt, ...]
    symbols: frozenset


@dataclass(frozen=True)
class Result:
    """Result ``key`` (its position among the function's results) = expr, not rolled."""
    key: int
    expr: sp.Basic


@dataclass(frozen=True)
class Rolled:
    """A function's body as lines (:class:`bgc.lower.ir.Line`), results (:class:`Result`) and
    loops, in the order they run; ``values``: the symbols that live in the array of values and
    their slots (``nvalues`` slots in all)."""
    items: tuple
    values: dict
    nvalues: int

    @property
    def loops(self) -> int:
        return sum(isinstance(it, Loop) for it in self.items)


class _Shapes:
    """Shapes by hash-consing: one number per distinct (role-replaced) tree."""

    def __init__(self, states, params, temps):
        self.ids: dict = {}
        self.states = {s: k for k, s in enumerate(states)}
        self.params = {s: k for k, s in enumerate(params)}
        self.temps = temps
        self.fresh = itertools.count(-1, -1)
        self.memo: dict = {}  # atom -> leaf()

    def id(self, key) -> int:
        got = self.ids.get(key)
        if got is None:
            got = self.ids[key] = len(self.ids)
        return got

    def leaf(self, e):
        """(shape id, the leaf as (array, index or symbol, symbol), or None) of an atom."""
        got = self.memo.get(e)
        if got is None:
            got = self.memo[e] = self._leaf(e)
        return got

    def _leaf(self, e):
        if e.is_Symbol:
            if e in self.states:
                return self.id("x"), ("x", self.states[e], e)
            if e in self.params:
                return self.id("p"), ("p", self.params[e], e)
            if e in self.temps:
                return self.id("v"), ("v", e, e)
            return self.id(("s", e)), None
        return self.id(("n", type(e).__name__, e)), None

    def shape(self, e, leaves: list | None):
        """The shape id of an expression (None for what cannot be rolled: numeric solves);
        its leaves appended to ``leaves`` in canonical order."""
        args = e.args
        if not args:
            sid, lf = self.leaf(e)
            if lf is not None and leaves is not None:
                leaves.append(lf)
            return sid
        if isinstance(e, _OPAQUE):
            return None
        if not (e.is_Add or e.is_Mul):  # arguments in their order: leaves straight in
            kids = []
            for a in args:
                k = self.shape(a, leaves)
                if k is None:
                    return None
                kids.append(k)
            return self.id((e.func, tuple(kids)))
        pairs = []
        for a in args:
            sub: list | None = [] if leaves is not None else None
            k = self.shape(a, sub)
            if k is None:
                return None
            pairs.append((k, sub))
        pairs.sort(key=lambda kv: kv[0])
        if leaves is not None:
            for _, sub in pairs:
                leaves.extend(sub)
        return self.id((e.func, tuple(k for k, _ in pairs)))


def _canonical(e, shapes: _Shapes, make):
    """The expression rebuilt with its sum and product arguments in canonical order (that of
    :meth:`_Shapes.shape`) and its k-th leaf replaced by ``make(leaf)``."""
    if not e.args:
        return make(shapes.leaf(e)[1]) if shapes.leaf(e)[1] is not None else e
    kids = list(e.args)
    if e.is_Add or e.is_Mul:
        kids.sort(key=lambda a: shapes.shape(a, None))
    return _rebuilt(e, tuple(_canonical(a, shapes, make) for a in kids))


def _runs(seq: list, min_run: int) -> list[tuple[int, int, int]]:
    """(start, period, count) of the runs of ``seq`` (shape ids) that repeat a block of
    ``period`` ids at least ``min_run`` times, greedily from the left (at each start, the
    period that covers the most lines among the next :data:`CANDIDATES` repeats of its id)."""
    nxt: list = [None] * len(seq)
    last: dict = {}
    for i in range(len(seq) - 1, -1, -1):
        nxt[i] = last.get(seq[i])
        last[seq[i]] = i
    out, s, n = [], 0, len(seq)
    while s + min_run <= n:
        best, c, tries = None, nxt[s], 0
        while c is not None and c - s <= MAX_PERIOD and tries < CANDIDATES:
            p, tries = c - s, tries + 1
            if s + p * min_run > n:
                break
            if seq[s + p * (min_run - 1)] == seq[s] and seq[s + 1] == seq[s + p + 1] and \
                    seq[s:s + p] == seq[s + p:s + 2 * p]:
                block, m = seq[s:s + p], 2
                while s + (m + 1) * p <= n and seq[s + m * p:s + (m + 1) * p] == block:
                    m += 1
                if m >= min_run and (best is None or m * p > best[1] * best[0]):
                    best = (p, m)
            c = nxt[c]
        if best is None:
            s += 1
            continue
        out.append((s, best[0], best[1]))
        s += best[0] * best[1]
    return out


def reroll(fn: Function, states, params, min_run: int | None = None) -> Rolled:
    """The function's body with its runs of :data:`MIN_RUN` or more repetitions as loops.
    ``states`` and ``params``: the symbols of the state and parameter vectors, in order (the
    indices the loops read them at)."""
    min_run = max(2, MIN_RUN if min_run is None else min_run)
    items = tuple(fn.lines) + tuple(Result(k, r) for k, (_, r) in enumerate(fn.results))
    if len(items) < min_run:  # too short for a run (or the pass switched off)
        return Rolled(items, {}, 0)
    vec = set()  # numeric solves' results (arrays): never rolled
    for ln in fn.lines:
        if isinstance(ln.expr, _OPAQUE) or (ln.expr.is_Symbol and ln.expr in vec):
            vec.add(ln.target)
    temps = {ln.target for ln in fn.lines} - vec
    shapes = _Shapes(states, params, temps)
    seq: list = []
    leaves: list = []
    for kind, e in itertools.chain((("line", ln.expr) for ln in fn.lines),
                                   (("out", r) for _, r in fn.results)):
        lv: list = []
        sid = shapes.shape(e, lv) if kind == "out" or not e.is_Symbol or e not in vec else None
        seq.append(next(shapes.fresh) if sid is None else shapes.id((kind, sid)))
        leaves.append(lv)
    runs = _runs(seq, min_run)
    if not runs:
        return Rolled(items, {}, 0)
    return _build(items, len(fn.lines), runs, leaves, shapes)


def _build(entries, nlines: int, runs, leaves, shapes: _Shapes) -> Rolled:
    slots: dict = {}
    spare: set = set()
    nslot = 0
    for s, p, m in runs:  # the values the loops write: one range per statement, a spare
        for j in range(p):  # cell before it for a value read just before the run
            if s + j < nlines:
                spare.add(nslot)
                nslot += 1
                for k in range(m):
                    slots[entries[s + j + k * p].target] = nslot + k
                nslot += m
    plans = [[_reads(leaves, s + j, p, m) for j in range(p)] for s, p, m in runs]
    for plan in plans:  # values read by index that no loop writes: placed, then stored
        for reads in plan:
            for array, varying, _ in reads:
                if array == "v" and varying is not None:
                    nslot = _place(varying, slots, spare, nslot)
    items, it = [], 0
    for (s, p, m), plan in zip(runs, plans):
        items.extend(entries[it:s])
        items.append(_loop(entries, s, p, m, plan, slots, shapes))
        it = s + p * m
    items.extend(entries[it:])
    return Rolled(tuple(items), slots, nslot)


def _reads(leaves, first: int, p: int, m: int) -> list:
    """Per leaf position of the statement at ``first``: (array, what each instance reads,
    None), or (array, None, the symbol) where every instance reads the same leaf."""
    out = []
    for pos in range(len(leaves[first])):
        col = [leaves[first + k * p][pos] for k in range(m)]
        if all(c[1] == col[0][1] for c in col):
            out.append((col[0][0], None, col[0][2]))
        else:
            out.append((col[0][0], [c[1] for c in col], None))
    return out


def _place(syms: list, slots: dict, spare: set, nslot: int) -> int:
    """Slots for the values a loop reads by index: where the others (already placed) are
    affine, in the spare cell the affine index points at; else new slots at the end."""
    known = [(k, slots[s]) for k, s in enumerate(syms) if s in slots]
    fit = None
    if len(known) >= 2:
        (k0, v0), (k1, v1) = known[0], known[1]
        if (v1 - v0) % (k1 - k0) == 0:
            st = (v1 - v0) // (k1 - k0)
            if all(v == v0 + st * (k - k0) for k, v in known):
                fit = (v0 - st * k0, st)
    for k, s in enumerate(syms):
        if s in slots:
            continue
        want = None if fit is None else fit[0] + fit[1] * k
        if want is not None and want in spare:
            spare.discard(want)
            slots[s] = want
        else:
            slots[s] = nslot
            nslot += 1
    return nslot


def _loop(entries, s: int, p: int, m: int, plan, slots: dict, shapes: _Shapes) -> Loop:
    """The loop of the run (start s, period p, m iterations)."""
    body, syms = [], set()
    for j in range(p):
        first = entries[s + j]
        reads, subst = [], []
        for array, varying, same in plan[j]:
            if varying is None:  # the same leaf in every instance: read as it is
                subst.append(same)
                continue
            name = sp.Dummy("r")
            idx = [slots[v] for v in varying] if array == "v" else varying
            reads.append(Read(name, array, Index.of(idx)))
            subst.append(name)
        order = iter(subst)
        expr = _canonical(first.expr, shapes, lambda _leaf, order=order: next(order))
        if isinstance(first, Line):
            idx = Index.of([slots[entries[s + j + k * p].target] for k in range(m)])
            body.append(Stmt(expr, tuple(reads), "v", idx, first.comment))
        else:
            idx = Index.of([entries[s + j + k * p].key for k in range(m)])
            body.append(Stmt(expr, tuple(reads), "out", idx))
        syms |= expr.free_symbols - {r.name for r in reads}
    return Loop(m, tuple(body), frozenset(syms))
