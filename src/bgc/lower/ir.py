"""Stage 5a: equations -> a backend-neutral lowered form (the IR every printer consumes).

Each generated function (rhs, Jacobian values on JAC_SPARSITY, outputs, initial state)
computes only what its results need: the assignments are pruned backwards from the results,
common subexpressions are eliminated (symengine's ``cse``, else sympy's; beyond
:data:`bgc.lower.cse.LINEAR_ABOVE` nodes, or beyond :data:`~bgc.lower.cse.BINARY_ABOVE` where every sum and product has two operands,
bgc.lower.cse's linear pass), and the definitions are scheduled in
causal order. The result is a tree of frozen dataclasses holding sympy expressions; printing
them as numpy (:mod:`bgc.backends.numpy.printer`) or C (:mod:`bgc.backends.c.printer`) is the printers' business.
"""
from __future__ import annotations

import heapq
import itertools
from dataclasses import dataclass

import sympy as sp

from bgc.base.errors import ModelError
from bgc.core import fastsym
from bgc.core.eqtypes import Assignment, Equations, prune
from bgc.core.forward import linear_parts
from bgc.lower import cse as lcse


@dataclass(frozen=True)
class Line:
    """One definition ``target = expr`` of a function body (``comment`` names the element)."""
    target: sp.Symbol
    expr: sp.Basic
    comment: str = ""


@dataclass(frozen=True)
class Function:
    params: tuple[str, ...]  # parameter identifiers the body uses
    inputs: tuple[str, ...]  # input symbols the body uses
    states: tuple[str, ...]  # state identifiers, "_" where unused
    lines: tuple[Line, ...]
    results: tuple[tuple[object, sp.Basic], ...]  # (key, expression)
    #: operation count after CSE, or None: not counted (nothing on the compile path reads it;
    #: :meth:`op_count` counts on demand)
    ops: int | None = None

    def op_count(self) -> int:
        """Arithmetic operations and function calls of the body and results (:func:`count_ops`)."""
        if self.ops is not None:
            return self.ops
        return count_ops([ln.expr for ln in self.lines] + [r for _, r in self.results])


@dataclass(frozen=True)
class Linear:
    """The linearisation's B = d(rhs)/du, and C = d(y)/dx with D = d(y)/du (A is the Jacobian),
    lowered: ``ujac`` results keyed (row, input column), ``yjac`` keyed ("C", row, col) then
    ("D", row, col); the flat input and output labels name the columns and rows."""
    ujac: Function
    yjac: Function
    input_labels: tuple[str, ...]
    output_labels: tuple[str, ...]


@dataclass(frozen=True)
class Lowered:
    """Everything a printer needs about one model, in a fixed (deterministic) order."""
    eq: Equations
    rhs: Function  # results keyed by state index
    jac: Function  # results keyed by (row, col), sorted: the order of JAC_SPARSITY's values
    outs: Function  # results keyed by (output name, flat index)
    init: Function  # results keyed by state index (no CSE)
    jac_keys: tuple[tuple[int, int], ...]
    derived: tuple[Line, ...]  # derived parameters, in dependency order
    linear: Linear | None = None  # B, C, D (lowered on demand: lower(..., linear=True))
    #: closed loops' constraint values (results keyed 0..2m: the m position residuals, the m
    #: velocity residuals, the kinetic energy): what a start's check and projection read
    cons: Function | None = None

    @property
    def n(self) -> int:
        return len(self.eq.states)


def free_memo():
    """``free(expr)``: sympy's ``free_symbols``, each expression object's computed once (the
    functions of one model share their assignments). Keyed by the object, not its value: a
    fresh expression (a CSE result) is never hashed for it, which walks its whole tree; the
    memo holds the expression, so its id is not reused while it is there."""
    memo: dict = {}

    def free(e):
        hit = memo.get(id(e))
        if hit is not None and hit[0] is e:
            return hit[1]
        out = fastsym.free_symbols(e)
        memo[id(e)] = (e, out)
        return out
    return free


def lower_function(eq: Equations, results: list, assigns: list[Assignment], keys: list,
                   cse: bool = True, free=None) -> Function:
    """Prune, CSE and schedule one generated function's body (``free``: a :func:`free_memo`
    shared by the functions of one model)."""
    free_of = free or free_memo()
    assigns = prune(results, assigns, free=free_of)
    exprs = [a.expr for a in assigns] + list(results)
    if cse and exprs:
        names = (sp.Symbol(f"_c{i}", real=True) for i in itertools.count())
        # a large body, or a large binary one: the linear pass (the pairwise search's cost
        # grows as its square)
        big = lcse.linear_wanted(exprs)
        fast = lcse.linear_cse(exprs, lambda: next(names)) if big else \
            fastsym.cse(exprs, lambda: next(names))  # symengine, when it can read them all
        if fast is not None:
            repl, reduced = fast
        else:
            repl, reduced = sp.cse(exprs, symbols=names, order="none", list=True)
    else:
        repl, reduced = [], exprs
    defs = [(s, e, "") for s, e in repl]
    defs += [(a.symbol, r, a.why) for a, r in zip(assigns, reduced[:len(assigns)])]
    res = reduced[len(assigns):]
    free = [free_of(e) for _, e, _ in defs]
    order = _schedule(defs, free, len(repl))
    lines = tuple(Line(*defs[i]) for i in order)
    used = set().union(*free) if free else set()
    for r in res:
        used |= free_of(r)
    pnames = tuple(str(s) for pv in eq.params for s in pv.symbols if s in used)
    pnames += tuple(str(a.symbol) for a in eq.derived if a.symbol in used)
    inames = tuple(str(s) for iv in eq.inputs for s in iv.symbols if s in used)
    snames = tuple(str(sv.symbol) if sv.symbol in used else "_" for sv in eq.states)
    return Function(pnames, inames, snames, lines, tuple(zip(keys, res)))


def _schedule(defs: list, free: list, ntemp: int) -> list[int]:
    """The definitions' order (indices into ``defs``, whose first ``ntemp`` are CSE
    temporaries and the rest assignments in causal order; ``free``: each one's free symbols):
    assignments in causal order, each temporary just before its first use. A topological
    order that keeps the priority (index, name) wherever dependencies allow: the order of
    bgc.core.eqtypes.schedule, on positions rather than symbols (each symbol hashed once)."""
    at = {s: i for i, (s, _, _) in enumerate(defs)}
    nassign = len(defs) - ntemp
    reads = [[k for k in map(at.get, fs) if k is not None] for fs in free]
    first_use = [None] * len(defs)
    for i in range(ntemp, len(defs)):  # assignments, at their position among the assignments
        p = i - ntemp
        for k in reads[i]:
            if first_use[k] is None or p < first_use[k]:
                first_use[k] = p
    for i in range(ntemp - 1, -1, -1):  # temporaries used by later temporaries
        fu = first_use[i]
        if fu is None:
            continue
        for k in reads[i]:
            if first_use[k] is None or fu < first_use[k]:
                first_use[k] = fu
    prio = [2 * (i - ntemp) + 1 if i >= ntemp else
            2 * (first_use[i] if first_use[i] is not None else nassign)
            for i in range(len(defs))]
    succ: list[list[int]] = [[] for _ in defs]
    indeg = [0] * len(defs)
    for i, ks in enumerate(reads):
        for k in set(ks):
            succ[k].append(i)
            indeg[i] += 1
    names = [s.name if hasattr(s, "name") else str(s) for s, _, _ in defs]
    heap = [(prio[i], names[i], i) for i in range(len(defs)) if indeg[i] == 0]
    heapq.heapify(heap)
    out = []
    while heap:
        _, _, i = heapq.heappop(heap)
        out.append(i)
        for m in succ[i]:
            indeg[m] -= 1
            if indeg[m] == 0:
                heapq.heappush(heap, (prio[m], names[m], m))
    if len(out) != len(defs):
        raise ModelError(None, "internal: cycle left after solving algebraic loops")
    return out


def count_ops(exprs) -> int:
    """Arithmetic operations and function calls, counted on the expression trees (cheap)."""
    n = 0
    stack = list(exprs)  # every node of every tree, as sympy's preorder traversal visits them
    while stack:
        node = stack.pop()
        if node.is_Add or node.is_Mul:
            n += len(node.args) - 1
        elif node.is_Pow or node.is_Function or isinstance(node, sp.Piecewise):
            n += 1
        stack.extend(node.args)
    return n


def lower_linear(eq: Equations, progress=None, jac: Function | None = None,
                 free=None) -> Linear:
    """B, C and D of the linearisation (forward mode along the rhs's assignments:
    bgc.core.forward.linear_parts), lowered like the other functions. ``jac``: the model's
    lowered Jacobian, whose lines (assignments, derivative intermediates, CSE temporaries)
    C and D then read instead of eliminating common subexpressions over them again; ``free``:
    the :func:`free_memo` its lowering shared (the Jacobian's lines' free symbols known)."""
    (progress or (lambda msg: None))("emitting the linearisation's B, C, D")
    lp = linear_parts(eq)
    bkeys = sorted(lp.B)
    free = free or free_memo()
    ujac = lower_function(eq, [lp.B[k] for k in bkeys],
                          list(eq.assignments) + list(lp.B_assignments), bkeys, free=free)
    ckeys, dkeys = sorted(lp.C), sorted(lp.D)
    results = [lp.C[k] for k in ckeys] + [lp.D[k] for k in dkeys]
    keys = [("C",) + k for k in ckeys] + [("D",) + k for k in dkeys]
    assigns = list(eq.assignments) + list(lp.CD_assignments)
    if jac is None:
        yjac = lower_function(eq, results, assigns, keys, free=free)
    else:
        yjac = lower_function(eq, results, _on_lines(jac, assigns), keys, cse=False, free=free)
    return Linear(ujac, yjac, lp.input_labels, lp.output_labels)


def _on_lines(base: Function, assigns: list[Assignment]) -> list[Assignment]:
    """A lowered function's lines as assignments (already scheduled and CSE'd), then those of
    ``assigns`` that they do not define, in their order: a valid order, since the lines
    never read what they do not define themselves."""
    own = [Assignment(ln.target, ln.expr, ln.comment) for ln in base.lines]
    defined = {a.symbol for a in own}
    return own + [a for a in assigns if a.symbol not in defined]


def lower(eq: Equations, progress=None, linear: bool = True) -> Lowered:
    """The model's functions, pruned, CSE'd and scheduled (backend-neutral); with ``linear``,
    the linearisation's B, C, D too (every printed module has ``linearize``)."""
    say = progress or (lambda msg: None)
    n = len(eq.states)
    say("lowering rhs")
    free = free_memo()
    rhs = lower_function(eq, list(eq.derivatives), list(eq.assignments), list(range(n)),
                         free=free)
    say("lowering jacobian")
    jkeys = sorted(eq.jacobian)
    jac = lower_function(eq, [eq.jacobian[k] for k in jkeys],
                         list(eq.assignments) + list(eq.jac_assignments), jkeys, free=free)
    say("lowering outputs")
    oexprs, okeys = [], []
    for name, shp, vals in eq.outputs:
        for k, v in enumerate(vals):
            oexprs.append(v)
            okeys.append((name, k))
    outs = lower_function(eq, oexprs, list(eq.assignments), okeys, free=free)
    init = lower_function(eq, [sv.initial for sv in eq.states], [], list(range(n)), cse=False)
    derived = tuple(Line(a.symbol, a.expr, a.why) for a in eq.derived)
    lin = lower_linear(eq, progress, jac, free) if linear else None
    cvals = list(getattr(eq, "constraint_values", ()))
    cons = lower_function(eq, cvals, list(eq.assignments), list(range(len(cvals))),
                          free=free) \
        if cvals else None
    return Lowered(eq, rhs, jac, outs, init, tuple(jkeys), derived, lin, cons)
