"""The state equations' vocabulary, shared by every stage that builds or reads them.

The frozen records (:class:`Equations` and its variables and assignments), the sympy functions
that stand for solves in the generated code (:class:`LinSolve`, :class:`NewtonSolve`), the
symbol makers, and the small operations on assignments that the derivation, the loop solver,
the forward mode and the lowering all use (ordering, pruning, cleaning a derivative). It holds
no algorithm of its own, so every module of the derivation can import it without a cycle.
"""
from __future__ import annotations

import heapq
from dataclasses import dataclass, field

import sympy as sp

from bgc.base.errors import ModelError
from bgc.format.matrices import entries, matrix

T = sp.Symbol("t", real=True)
# Linear systems from derivative causality up to this size are solved symbolically (Cramer-like
# LU on symbols for the matrix entries); larger ones by a numeric solve in the generated code.
SYMBOLIC_MAX = 4


def real_symbol(name: str) -> sp.Symbol:
    return sp.Symbol(name, real=True)


def symbol_vector(prefix: str, n: int):
    if n == 1:
        return real_symbol(prefix)
    return matrix(n, 1, [real_symbol(f"{prefix}_{i}") for i in range(n)])


def symbol_array(prefix: str, shape: tuple[int, ...]):
    if not shape:
        return real_symbol(prefix)
    if len(shape) == 1:
        return matrix(shape[0], 1, [real_symbol(f"{prefix}_{i}") for i in range(shape[0])])
    r, c = shape
    return matrix(r, c, [real_symbol(f"{prefix}_{i}_{j}") for i in range(r) for j in range(c)])


def flat(v) -> list:
    return entries(v) if isinstance(v, sp.MatrixBase) else [v]


def shape_name(shape):
    return "scalar" if not shape else "x".join(map(str, shape))


@dataclass(frozen=True)
class StateVar:
    name: str  # as shown in STATE_NAMES
    symbol: sp.Symbol
    owner: str  # element or state id
    initial: object  # sympy expression of parameters


@dataclass(frozen=True)
class ParamVar:
    id: str  # dotted name (PARAM_DEFAULTS key)
    code: str
    value: object  # float or tuple of tuples
    symbols: tuple  # flat symbols (matrix entries)
    shape: tuple[int, ...]
    unit: str = ""
    description: str = ""


@dataclass(frozen=True)
class InputVar:
    name: str
    symbols: tuple
    shape: tuple[int, ...]
    default: tuple  # flat sympy expressions of t and parameters
    table: object = None  # a bgc.format.tables.Table: the input is data (emit evaluates it)


@dataclass(frozen=True)
class Assignment:
    symbol: sp.Symbol
    expr: object
    why: str  # a comment for the generated code


@dataclass(frozen=True)
class Equations:
    name: str
    states: tuple[StateVar, ...]
    params: tuple[ParamVar, ...]
    derived: tuple[Assignment, ...]  # derived parameters, in dependency order
    inputs: tuple[InputVar, ...]
    assignments: tuple[Assignment, ...]  # intermediate efforts and flows, causal order
    derivatives: tuple  # one expression per state
    outputs: tuple[tuple[str, tuple[int, ...], tuple], ...]  # name, shape, flat exprs
    jacobian: dict  # (i, j) -> expression (nonzero entries only)
    jac_assignments: tuple[Assignment, ...]  # forward-mode derivative intermediates
    loops: tuple[str, ...]  # descriptions of the algebraic loops solved
    notes: tuple[str, ...] = field(default=())
    # storage elements in derivative causality: (element id, the state names it follows from)
    dependent: tuple = field(default=())
    newton: tuple = field(default=())  # NewtonLoop: nonlinear algebraic loops
    #: causality's warnings that the equations leave standing: SCAP's arbitrary choice of an R's
    #: form is no longer a "possible algebraic loop" once the equations are derived (any loop
    #: was found and solved, and is listed in ``loops``; or there was none)
    warnings: tuple[str, ...] = field(default=())
    events: tuple = field(default=())  # bgc.core.events.EventEq: guards and resets
    modes: tuple[str, ...] = field(default=())  # the states that are mode variables
    #: (state symbol, its time derivative, its value) of each storage element in derivative
    #: causality (bgc.core.modes: such a state follows its constraint in a switch's mode)
    rates: tuple = field(default=())
    #: constraint components found redundant (their reaction is zero): (source, component)
    redundant: tuple = field(default=())
    #: the names of the constraints' violation states (q): the linearisation reduces them out
    constraint_states: tuple = field(default=())
    constraint_alpha: float = 0.0  # their stabilisation rate (1/s)
    #: what a projection of a start onto the constraints reads (bgc.core.assembly
    #: ``constraint_values``): per component its position residual (the closure, else q),
    #: then per component its velocity residual f - s, then the kinetic energy
    constraint_values: tuple = field(default=())
    constraint_closed: tuple = field(default=())  # per component: has it a closure?
    momentum_states: tuple = field(default=())  # the states that are I elements' momenta
    closure_states: tuple = field(default=())  # the states the closures read (positions)
    #: the violation states of the components dropped as redundant: a run watches their rates
    constraint_dropped: tuple = field(default=())
    #: the state Jacobian's forward sweep (bgc.core.forward.StateTangents), which the
    #: linearisation's C goes on from instead of differentiating the same assignments again
    jac_tangents: object = field(default=None, compare=False, repr=False)


class LinSolve(sp.Function):
    """x = A^-1 b for LinSolve(n, A entries row-major, b entries): printed as a batched solve."""

    @classmethod
    def eval(cls, *args):
        return None

    def _eval_derivative(self, s):  # the Jacobian goes through _linsolve_grad instead
        raise ModelError(None, "internal: LinSolve differentiated symbolically")


class LinSolveEntry(sp.Function):
    """Component i of a LinSolve result (a symbol)."""

    @classmethod
    def eval(cls, *args):
        return None


@dataclass(frozen=True)
class NewtonLoop:
    """A nonlinear algebraic loop solved by Newton's method in the generated code."""

    name: str  # the generated function
    tear: tuple  # its unknowns (symbols)
    args: tuple  # the symbols from outside the loop it reads
    body: tuple  # (symbol, expr): the loop's other variables and the derivative coefficients
    residual: tuple  # tear_i - g_i(...), zero at the solution
    jac: tuple  # d residual / d tear, row-major
    g: tuple  # g_i: the tear variables' own definitions (for the system Jacobian)
    rest: tuple  # the loop's other variables, in order
    where: str  # for the error message: "file:line:col: algebraic loop through ..."


class NewtonSolve(sp.Function):
    """The tear variables of Newton loop k: NewtonSolve(k, *outside symbols)."""

    @classmethod
    def eval(cls, *args):
        return None


def state_label(oid: str, shape, k: int) -> str:
    if not shape:
        return oid
    if len(shape) == 1:
        return f"{oid}[{k}]"
    return f"{oid}[{k // shape[1]},{k % shape[1]}]"


def is_trivial(v) -> bool:
    if v.is_Symbol or v.is_Number:
        return True
    if isinstance(v, sp.Mul) and len(v.args) == 2 and v.args[0] == -1 and v.args[1].is_Symbol:
        return True
    return False


class DepGraph:
    """A directed graph as insertion-ordered adjacency dicts: the part of
    ``networkx.DiGraph`` that scheduling reads (``nodes``, ``successors``, ``in_degree``),
    without importing networkx or paying its per-edge attribute dicts."""

    def __init__(self):
        self._succ: dict = {}
        self._npred: dict = {}

    def add_node(self, n) -> None:
        if n not in self._succ:
            self._succ[n] = {}
            self._npred[n] = 0

    def add_edge(self, u, v) -> None:
        self.add_node(u)
        self.add_node(v)
        if v not in self._succ[u]:
            self._succ[u][v] = None
            self._npred[v] += 1

    @property
    def nodes(self):
        return self._succ.keys()

    def successors(self, n):
        return iter(self._succ[n])

    def in_degree(self, n) -> int:
        return self._npred[n]


def topological(g, index: dict) -> list | None:
    """Topological order that keeps the given priority wherever dependencies allow; None
    when ``g`` has a cycle. The order is unique (the heap pops the least (index, name) among
    the nodes whose dependencies are done), so it does not depend on how ``g`` stores its
    edges: a :class:`DepGraph` and a networkx graph of the same edges give the same list."""
    indeg = {n: g.in_degree(n) for n in g.nodes}
    heap = [(index[n], n.name if hasattr(n, "name") else str(n), n)
            for n, d in indeg.items() if d == 0]
    heapq.heapify(heap)
    out = []
    while heap:
        _, _, n = heapq.heappop(heap)
        out.append(n)
        for m in g.successors(n):
            indeg[m] -= 1
            if indeg[m] == 0:
                heapq.heappush(heap, (index[m], m.name if hasattr(m, "name") else str(m), m))
    return out if len(out) == len(indeg) else None


def schedule(g, index: dict) -> list:
    """:func:`topological`, where a cycle is an internal error (``g``: a :class:`DepGraph`
    or a networkx ``DiGraph``)."""
    out = topological(g, index)
    if out is None:
        raise ModelError(None, "internal: cycle left after solving algebraic loops")
    return out


def clean_derivative(d):
    """Derivatives of step-like functions (sign, Heaviside) are zero almost everywhere."""
    if d.has(sp.DiracDelta):
        d = d.replace(lambda a: isinstance(a, sp.DiracDelta), lambda a: sp.Integer(0))
    if d.has(sp.Derivative):
        d = d.replace(lambda a: isinstance(a, sp.Derivative)
                      and isinstance(a.expr, (sp.sign, sp.Heaviside)),
                      lambda a: sp.Integer(0))
    if d.has(sp.Derivative):
        raise ModelError(None, f"cannot differentiate {d}")
    return d


def prune(results: list, assigns: list[Assignment], also=None, free=None) -> list[Assignment]:
    """The assignments (in their order) that ``results`` depend on, directly or through each
    other; ``also(a)`` names further symbols an assignment needs (beyond its expression's);
    ``free(expr)``: its free symbols (a caller's memo), else sympy's ``free_symbols``."""
    free = free or (lambda e: e.free_symbols)
    need: set = set()
    for r in results:
        need |= free(r)
    keep = []
    for a in reversed(assigns):
        if a.symbol in need:
            keep.append(a)
            need |= free(a.expr)
            if also is not None:
                need.update(also(a))
    keep.reverse()
    return keep
