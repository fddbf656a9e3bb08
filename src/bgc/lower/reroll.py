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
import weakref
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
    """Shapes by hash-consing: one number per distinct (role-replaced) tree. Each node's shape
    and leaves are computed once (memoised on the node object: a subtree that lines share, an
    atom read many times, the sort keys of :func:`_canonical`)."""

    def __init__(self, states, params, temps):
        self.ids: dict = {}
        self.states = {s: k for k, s in enumerate(states)}
        self.params = {s: k for k, s in enumerate(params)}
        self.temps = temps
        self.fresh = itertools.count(-1, -1)
        # id(node) -> (node, shape id or None, its leaves): the node is held, so its id stays
        # its own while the memo lives (one pass)
        self.memo: dict = {}

    def id(self, key) -> int:
        got = self.ids.get(key)
        if got is None:
            got = self.ids[key] = len(self.ids)
        return got

    def _leaf(self, e):
        """(shape id, the leaf as (array, index or symbol, symbol), or None) of an atom."""
        if e.is_Symbol:
            if e in self.states:
                return self.id("x"), ("x", self.states[e], e)
            if e in self.params:
                return self.id("p"), ("p", self.params[e], e)
            if e in self.temps:
                return self.id("v"), ("v", e, e)
            return self.id(("s", e)), None
        return self.id(("n", type(e).__name__, e)), None

    def of(self, e) -> tuple:
        """(node, shape id or None for what cannot be rolled (numeric solves), its leaves in
        canonical order as a tuple)."""
        got = self.memo.get(id(e))
        if got is None:
            got = self.memo[id(e)] = (e,) + self._shape(e)
        return got

    def shape(self, e) -> int | None:
        return self.of(e)[1]

    def _shape(self, e) -> tuple:
        args = e.args
        if not args:
            sid, lf = self._leaf(e)
            return sid, (() if lf is None else (lf,))
        if isinstance(e, _OPAQUE):
            return None, ()
        memo, kids = self.memo, []
        for a in args:
            got = memo.get(id(a))
            if got is None:
                got = memo[id(a)] = (a,) + self._shape(a)
            if got[1] is None:
                return None, ()
            kids.append(got)
        if e.is_Add or e.is_Mul:  # arguments in one order, by their shapes (a stable sort)
            kids.sort(key=_SID)
        leaves = kids[0][2] if len(kids) == 1 else tuple(
            lf for k in kids for lf in k[2])
        return self.id((e.func, tuple(k[1] for k in kids))), leaves


def _SID(entry) -> int:
    return entry[1]


def _canonical(e, shapes: _Shapes, make):
    """The expression rebuilt with its sum and product arguments in canonical order (that of
    :meth:`_Shapes.of`) and its k-th leaf replaced by ``make(leaf)``."""
    if not e.args:
        leaves = shapes.of(e)[2]
        return make(leaves[0]) if leaves else e
    kids = list(e.args)
    if e.is_Add or e.is_Mul:
        kids.sort(key=shapes.shape)
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


#: id(function) -> (a weak reference to it, {(states, params, min_run): its Rolled}): each
#: function of the IR is rolled once, whichever printers ask (the C parts, the numpy module
#: printed beside them); an entry goes with its function
_DONE: dict = {}


def reroll(fn: Function, states, params, min_run: int | None = None) -> Rolled:
    """The function's body with its runs of :data:`MIN_RUN` or more repetitions as loops.
    ``states`` and ``params``: the symbols of the state and parameter vectors, in order (the
    indices the loops read them at). Computed once per function and arguments (the IR is
    immutable; a :class:`Rolled` is only read)."""
    min_run = max(2, MIN_RUN if min_run is None else min_run)
    key = (tuple(states), tuple(params), min_run)
    k = id(fn)
    entry = _DONE.get(k)
    if entry is None or entry[0]() is not fn:
        entry = _DONE[k] = (weakref.ref(fn, lambda _: _DONE.pop(k, None)), {})
    got = entry[1].get(key)
    if got is None:
        got = entry[1][key] = _reroll(fn, states, params, min_run)
    return got


def _reroll(fn: Function, states, params, min_run: int) -> Rolled:
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
        if kind == "line" and e.is_Symbol and e in vec:
            sid, lv = None, ()
        else:
            _, sid, lv = shapes.of(e)
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
