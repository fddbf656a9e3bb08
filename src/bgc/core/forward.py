"""Forward-mode differentiation along the causal assignments: the state Jacobian, and the
linearisation's B, C and D.

Derivatives are propagated assignment by assignment (the chain rule), never by differentiating
an expanded right-hand side; every non-trivial entry becomes a new intermediate, so each
emitted expression stays as small as one assignment's. Linear solves and Newton loops are
differentiated through (one more solve per column).
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import sympy as sp

from bgc.base.errors import ModelError
from bgc.core import fastsym
from bgc.core.eqtypes import (
    Assignment,
    Equations,
    LinSolve,
    LinSolveEntry,
    NewtonSolve,
    clean_derivative,
    is_trivial,
    prune,
    real_symbol,
)


def _name(s) -> str:
    """A symbol's text as ``str`` gives it (its name), without sympy's printer for plain
    symbols (the printer was a fifth of a large ladder's Jacobian)."""
    return s.name if type(s) is sp.Symbol else str(s)


class TooDeep(Exception):
    """An assignment whose expression is nested too deeply for sympy to differentiate (its
    ``symbol`` and ``why``), or the ``final`` expression of that index (a derivative, an
    output); bgc.core.equations names the element that defined it, :func:`linear_parts` the
    output."""

    def __init__(self, symbol, why: str, final: int | None = None):
        super().__init__(why)
        self.symbol, self.why, self.final = symbol, why, final


def jacobian(kept: list[Assignment], state_vars, derivatives, nloops=(), keep=None):
    """Forward-mode Jacobian d(derivatives)/dx along the causal assignments. ``keep``: a list
    the sweep is appended to (as :class:`StateTangents`), for the linearisation's C to go on
    from (every assignment's derivative with respect to the states is the same there)."""
    seeds = {sv.symbol: j for j, sv in enumerate(state_vars)}
    sweep = _Sweep(kept, seeds, "_d", nloops)
    out, assigns = forward_mode(kept, seeds, list(derivatives), "_d", nloops, sweep=sweep)
    if keep is not None:
        sweep.bridge = None  # (its conversions' memo freed: a fork makes its own)
        keep.append(StateTangents(tuple(sv.symbol for sv in state_vars), tuple(kept),
                                  tuple(nloops), sweep))
    return out, assigns


@dataclass(frozen=True, eq=False)
class StateTangents:
    """The state Jacobian's sweep with what it was made from: the states (its columns), the
    causal assignments and the Newton loops. :func:`linear_parts` goes on from it only for
    equations made of the very same (a sliced scene's are not: it sweeps anew)."""

    states: tuple
    kept: tuple
    nloops: tuple
    sweep: object

    def fits(self, eq: Equations) -> bool:
        nl = tuple(getattr(eq, "newton", ()))
        return (len(self.states) == len(eq.states) and len(self.kept) == len(eq.assignments)
                and len(self.nloops) == len(nl)
                and all(s is sv.symbol for s, sv in zip(self.states, eq.states))
                and all(a is b for a, b in zip(self.kept, eq.assignments))
                and all(a is b for a, b in zip(self.nloops, nl)))


def forward_mode(kept: list[Assignment], seeds: dict, finals: list, prefix: str = "_d",
                 nloops=(), sweep=None):
    """Forward-mode derivatives of ``finals`` with respect to the seed symbols (symbol ->
    column) along the causal assignments ``kept``: the state Jacobian (seeds: the states) and
    the linearisation's B, C, D (seeds: inputs or states; finals: derivatives or outputs).

    D[v] maps a column j to dv/d(seed j). Non-trivial entries become new intermediates
    (``<prefix><k>``), so every emitted expression stays as small as one assignment's; linear
    solves and Newton loops are differentiated through (one more solve per column). Only the
    assignments the finals depend on are visited (linear in model size).
    """
    sweep = _Sweep(kept, seeds, prefix, nloops) if sweep is None else sweep
    used = prune(finals, kept, lambda a: (  # a Newton loop's own assignments feed it
        nloops[int(a.expr.args[0])].rest if isinstance(a.expr, NewtonSolve) else ()))
    for a in used:
        if a.symbol not in sweep.visited:  # (a sweep gone on from: each assignment once)
            sweep.step(a)
    out = {}
    for i, expr in enumerate(finals):
        try:
            g = sweep.grad(expr)
        except RecursionError:
            raise TooDeep(None, "", final=i) from None
        for j, v in g.items():
            out[(i, j)] = v
    return out, sweep.jac_assign


def _partials(bridge, expr, syms) -> dict | None:
    """{s: d expr / d s} through symengine (bgc.core.fastsym), or None (sympy's ``diff``).
    An output angle ``atan2(y, x)`` of convertible y and x (symengine does not take atan2) is
    differentiated by its chain rule, (x dy - y dx) / (x^2 + y^2), in symengine: sympy's
    ``diff`` of it asks the assumptions system about its arguments, and the 3R2S's four joint
    angles cost more there than all its other outputs together."""
    parts = fastsym.partials(bridge, expr, syms)
    if parts is not None or type(expr) is not sp.atan2:
        return parts
    y, x = expr.args
    ys, xs = bridge.to_se(y), bridge.to_se(x)
    py, px = fastsym.partials(bridge, y, syms), fastsym.partials(bridge, x, syms)
    if ys is None or xs is None or py is None or px is None:
        return None
    r2 = xs ** 2 + ys ** 2
    out = {}
    for s in syms:
        d = (xs * py.get(s, 0) - ys * px.get(s, 0)) / r2
        if d != 0:
            out[s] = d
    return out


class _Sweep:
    """One forward sweep: ``D[v]`` maps a column j to dv/d(seed j); ``jac_assign`` collects
    the new intermediates in the order they are made."""

    def __init__(self, kept: list[Assignment], seeds: dict, prefix: str, nloops):
        self.D: dict[sp.Symbol, dict[int, object]] = {s: {j: sp.Integer(1)}
                                                      for s, j in seeds.items()}
        self.jac_assign: list[Assignment] = []
        self.counter = itertools.count()
        self.prefix = prefix
        self.nloops = nloops
        self.bridge = fastsym.Bridge() if fastsym.available() else None
        self.solves: dict = {}  # LinSolve result symbol -> {state index: symbol of its derivative}
        self.kept_map = {a.symbol: a for a in kept}
        self.visited: set = set()  # the assignments differentiated so far

    def fork(self) -> "_Sweep":
        """A copy to go on from (new intermediates numbered on), this sweep left as it is:
        the tangents made so far are shared, never changed."""
        new = object.__new__(_Sweep)
        new.__dict__.update(self.__dict__)
        new.D, new.solves, new.visited = dict(self.D), dict(self.solves), set(self.visited)
        new.jac_assign = list(self.jac_assign)
        new.counter = itertools.count(len(self.jac_assign))
        new.bridge = fastsym.Bridge() if fastsym.available() else None
        return new

    def new(self, expr) -> sp.Symbol:
        """A new intermediate ``<prefix><k>`` assigned ``expr``."""
        s = real_symbol(f"{self.prefix}{next(self.counter)}")
        self.jac_assign.append(Assignment(s, expr, ""))
        return s

    def grad(self, expr) -> dict[int, object]:
        D, bridge = self.D, self.bridge
        syms = sorted((s for s in fastsym.free_symbols(expr) if D.get(s)),
                      key=_name)  # deterministic
        if not syms:
            return {}
        parts = _partials(bridge, expr, syms) if bridge is not None else None
        if parts is not None:  # symengine: same algebra, a hundred times faster
            acc_se: dict[int, object] = {}
            for s, partial in parts.items():
                for j, dj in D[s].items():
                    term = partial * bridge.to_se(dj)
                    acc_se[j] = acc_se[j] + term if j in acc_se else term
            return {j: bridge.from_se(v) for j, v in acc_se.items() if v != 0}
        acc: dict[int, object] = {}
        for s in syms:
            partial = clean_derivative(sp.diff(expr, s))
            if partial == 0:
                continue
            for j, dj in D[s].items():
                term = partial * dj
                acc[j] = acc[j] + term if j in acc else term
        return {j: v for j, v in acc.items() if v != 0}

    def local(self, seed: dict, exprs_of, order, outer: bool):
        """Forward mode over the loop's variables with the tear variables seeded."""
        D = self.D
        Dl = dict(seed)
        for s in order:
            a = self.kept_map.get(s)
            if a is None:
                continue
            acc: dict = {}
            for d in a.expr.free_symbols:
                ds = Dl.get(d) if d in Dl else (D.get(d) if outer else None)
                if not ds:
                    continue
                part = clean_derivative(sp.diff(a.expr, d))
                if part == 0:
                    continue
                for j, dj in ds.items():
                    acc[j] = acc[j] + part * dj if j in acc else part * dj
            dv = {}
            for j, v in sorted(acc.items()):
                if v == 0:
                    continue
                dv[j] = v if is_trivial(v) else self.new(v)
            Dl[s] = dv
        out = []
        for e in exprs_of:
            acc = {}
            for d in e.free_symbols:
                ds = Dl.get(d) if d in Dl else (D.get(d) if outer else None)
                if not ds:
                    continue
                part = clean_derivative(sp.diff(e, d))
                for j, dj in ds.items():
                    acc[j] = acc[j] + part * dj if j in acc else part * dj
            out.append({j: v for j, v in acc.items() if v != 0})
        return out

    def step(self, a: Assignment) -> None:
        """Differentiate one assignment (in causal order)."""
        self.visited.add(a.symbol)
        if isinstance(a.expr, NewtonSolve):
            self.newton(a)
        elif isinstance(a.expr, LinSolve):
            self.linsolve(a)
        elif isinstance(a.expr, LinSolveEntry):
            X, i = a.expr.args
            dv = {}
            for j, s in self.solves.get(X, {}).items():
                dv[j] = self.new(LinSolveEntry(s, i))
            if dv:
                self.D[a.symbol] = dv
        else:
            try:
                g = self.grad(a.expr)
            except RecursionError:  # sympy's diff recurses per level of a nested law
                raise TooDeep(a.symbol, a.why) from None
            if not g:
                return
            dv = {}
            for j, v in sorted(g.items()):
                dv[j] = v if is_trivial(v) else self.new(v)
            self.D[a.symbol] = dv

    def newton(self, a: Assignment) -> None:
        """Implicit function theorem at the solution: (I - dg/dz) dz = dg/dx (z held)."""
        nl = self.nloops[int(a.expr.args[0])]
        n = len(nl.tear)
        gx = self.local({t: {} for t in nl.tear}, nl.g, nl.rest, True)
        gz = self.local({t: {i: sp.Integer(1)} for i, t in enumerate(nl.tear)}, nl.g, nl.rest,
                        False)
        A = [(1 if i == k else 0) - gz[i].get(k, 0) for i in range(n) for k in range(n)]
        self.solves[a.symbol] = {}
        for j in sorted(set().union(*gx)):
            s = self.new(LinSolve(n, *A, *[gx[i].get(j, 0) for i in range(n)]))
            self.solves[a.symbol][j] = s

    def linsolve(self, a: Assignment) -> None:
        """d(A^-1 b) = A^-1 (db - dA x): one more solve with the same matrix per column."""
        n = int(a.expr.args[0])
        A, b = a.expr.args[1:1 + n * n], a.expr.args[1 + n * n:]
        x = [LinSolveEntry(a.symbol, i) for i in range(n)]
        gA, gb = [self.grad(v) for v in A], [self.grad(v) for v in b]
        cols = sorted(set().union(*gA, *gb))
        self.solves[a.symbol] = {}
        for j in cols:
            r = [gb[i].get(j, 0) - sum((gA[i * n + k].get(j, 0) * x[k] for k in range(n)),
                                       sp.Integer(0)) for i in range(n)]
            self.solves[a.symbol][j] = self.new(LinSolve(n, *A, *r))


# ---------------------------------------------------------------------------------------------
# Linearisation: the derivatives of rhs with respect to the inputs (B) and of the outputs with
# respect to the states and the inputs (C, D), in forward mode along the same assignments as
# the state Jacobian. Computed on demand (emit asks for them), so derive() is unchanged.


@dataclass(frozen=True)
class LinearParts:
    """Nonzero entries of B = d(rhs)/du, C = d(y)/dx, D = d(y)/du, keyed (row, column), with
    the forward-mode intermediates each needs. Inputs are flattened in INPUT_NAMES order (a
    vector input contributes its components in order), outputs in OUTPUT_NAMES order (each
    output's components in row-major order)."""

    B: dict
    B_assignments: tuple[Assignment, ...]
    C: dict
    D: dict
    CD_assignments: tuple[Assignment, ...]
    input_labels: tuple[str, ...]
    output_labels: tuple[str, ...]


def _label(name: str, shape, k: int) -> str:
    if not shape:
        return name
    if len(shape) == 1:
        return f"{name}[{k}]"
    return f"{name}[{k // shape[1]},{k % shape[1]}]"


def linear_labels(eq: Equations) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(input labels, output labels): the columns of B and D and the rows of C and D, without
    deriving them (a C wrapper names them; its B, C, D come from the numpy module)."""
    ilabels = tuple(_label(iv.name, iv.shape, k) for iv in eq.inputs
                    for k in range(len(iv.symbols)))
    olabels = tuple(_label(name, shp, k) for name, shp, vals in eq.outputs
                    for k in range(len(vals)))
    return ilabels, olabels


def linear_parts(eq: Equations) -> LinearParts:
    """B, C and D of the linearisation (A is ``eq.jacobian``)."""
    useeds = {s: j for j, s in enumerate(s for iv in eq.inputs for s in iv.symbols)}
    ilabels, olabels = linear_labels(eq)
    xseeds = {sv.symbol: j for j, sv in enumerate(eq.states)}
    youts = [v for _, _, vals in eq.outputs for v in vals]
    kept = list(eq.assignments)
    nloops = tuple(getattr(eq, "newton", ()))
    try:
        B, b_assign = forward_mode(kept, useeds, list(eq.derivatives), "_du", nloops)
    except TooDeep as exc:
        raise _too_deep(exc, [f"d{sv.name}/dt" for sv in eq.states]) from None
    tangents = getattr(eq, "jac_tangents", None)
    try:
        if tangents is not None and tangents.fits(eq):
            # C goes on from the state Jacobian's sweep: the assignments the derivatives read
            # already have their derivatives (the Jacobian's intermediates _d*, which C's
            # function then computes too); only those that only the outputs read are new
            C, c_assign = forward_mode(kept, xseeds, youts, "_d", nloops,
                                       sweep=tangents.sweep.fork())
        else:
            C, c_assign = forward_mode(kept, xseeds, youts, "_dx", nloops)
        D, d_assign = forward_mode(kept, useeds, youts, "_du", nloops)
    except TooDeep as exc:
        names = [n for n, _, vals in eq.outputs for _ in vals]
        err = _too_deep(exc, [f"output {n!r}" for n in names])
        err.output = names[exc.final] if exc.final is not None else None  # (for its place)
        raise err from None
    # B's and D's intermediates share a prefix: they live in different generated functions
    # except D's, which sits beside C's (prefix _d or _dx): no clash inside one function.
    return LinearParts(B, tuple(b_assign), C, D, tuple(c_assign) + tuple(d_assign),
                       tuple(ilabels), tuple(olabels))


def _too_deep(exc: TooDeep, finals: list[str]) -> ModelError:
    """The linearisation's refusal of an expression sympy cannot differentiate: the output (or
    derivative) it is, else the assignment's own words."""
    what = finals[exc.final] if exc.final is not None else exc.why
    return ModelError(None, f"{what}: its expression is nested too deeply to differentiate "
                            "(nested where(...)? flatten the conditions)")
