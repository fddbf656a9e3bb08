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

import itertools
from dataclasses import dataclass

import sympy as sp

from bgc.core import fastsym
from bgc.core.eqtypes import Assignment, DepGraph, Equations, prune, schedule
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
    ops: int  # operation count after CSE


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
    """``free(expr)``: sympy's ``free_symbols``, each expression's computed once (sympy walks
    the whole tree for it, and the functions of one model share their assignments)."""
    memo: dict = {}

    def free(e):
        try:
            return memo[e]
        except KeyError:
            memo[e] = out = e.free_symbols
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
    # schedule: cse temporaries just before their first use, assignments in causal order
    # (each definition's free symbols found once: sympy walks the whole tree for them)
    free = [free_of(e) for _, e, _ in defs]
    g = DepGraph()
    index = {}
    byname = {}
    defined = {s for s, _, _ in defs}
    for (s, e, why), fs in zip(defs, free):
        g.add_node(s)
        byname[s] = (e, why)
        for d in fs:
            if d in defined:
                g.add_edge(d, s)
    pos = {a.symbol: i for i, a in enumerate(assigns)}
    first_use: dict = {}
    for (s, _, _), fs in zip(defs, free):
        if s in pos:
            for d in fs:
                if d in defined:
                    first_use[d] = min(first_use.get(d, 10 ** 9), pos[s])
    for (s, _, _), fs in reversed(list(zip(defs[:len(repl)], free))):  # temporaries used
        for d in fs:  # by later temporaries
            if d in defined and s in first_use:
                first_use[d] = min(first_use.get(d, 10 ** 9), first_use[s])
    for s, _, _ in defs:
        if s in pos:
            index[s] = 2 * pos[s] + 1
        else:
            index[s] = 2 * first_use.get(s, len(assigns)) if s in first_use else 2 * len(assigns)
    order = schedule(g, index)
    lines = tuple(Line(s, byname[s][0], byname[s][1]) for s in order)
    used = set().union(*free) if free else set()
    for r in res:
        used |= free_of(r)
    pnames = tuple(str(s) for pv in eq.params for s in pv.symbols if s in used)
    pnames += tuple(str(a.symbol) for a in eq.derived if a.symbol in used)
    inames = tuple(str(s) for iv in eq.inputs for s in iv.symbols if s in used)
    snames = tuple(str(sv.symbol) if sv.symbol in used else "_" for sv in eq.states)
    ops = count_ops([e for _, e, _ in defs] + list(res))
    return Function(pnames, inames, snames, lines, tuple(zip(keys, res)), ops)


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


def lower_linear(eq: Equations, progress=None, jac: Function | None = None) -> Linear:
    """B, C and D of the linearisation (forward mode along the rhs's assignments:
    bgc.core.forward.linear_parts), lowered like the other functions. ``jac``: the model's
    lowered Jacobian, whose lines (assignments, derivative intermediates, CSE temporaries)
    C and D then read instead of eliminating common subexpressions over them again."""
    (progress or (lambda msg: None))("emitting the linearisation's B, C, D")
    lp = linear_parts(eq)
    bkeys = sorted(lp.B)
    ujac = lower_function(eq, [lp.B[k] for k in bkeys],
                          list(eq.assignments) + list(lp.B_assignments), bkeys)
    ckeys, dkeys = sorted(lp.C), sorted(lp.D)
    results = [lp.C[k] for k in ckeys] + [lp.D[k] for k in dkeys]
    keys = [("C",) + k for k in ckeys] + [("D",) + k for k in dkeys]
    assigns = list(eq.assignments) + list(lp.CD_assignments)
    if jac is None:
        yjac = lower_function(eq, results, assigns, keys)
    else:
        yjac = lower_function(eq, results, _on_lines(jac, assigns), keys, cse=False)
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
    lin = lower_linear(eq, progress, jac) if linear else None
    cvals = list(getattr(eq, "constraint_values", ()))
    cons = lower_function(eq, cvals, list(eq.assignments), list(range(len(cvals))),
                          free=free) \
        if cvals else None
    return Lowered(eq, rhs, jac, outs, init, tuple(jkeys), derived, lin, cons)
