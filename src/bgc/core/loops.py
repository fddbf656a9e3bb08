"""Algebraic loops and derivative causality: putting the assignments in causal order.

``causal_order`` sorts the element equations by their dependencies; a strongly connected
component is an algebraic loop, solved symbolically when linear, by Newton's method in the
generated code when not (``NewtonLoop``). Storage elements in derivative causality make their
time derivatives unknowns (``time_derivatives``, the chain rule along the assignments); the
loop that closes is linear in them and solved by tearing at the state derivatives, on symbols
while small, else by a numeric solve in the generated code (``LinSolve``).
"""
from __future__ import annotations

import itertools
import os

import sympy as sp

from bgc.base.errors import ModelError
from bgc.core.context import Context
from bgc.core.eqtypes import (
    SYMBOLIC_MAX,
    Assignment,
    DepGraph,
    LinSolve,
    LinSolveEntry,
    NewtonLoop,
    NewtonSolve,
    T,
    clean_derivative,
    is_trivial,
    real_symbol,
    schedule,
    topological,
)
from bgc.core.graph import BondGraph, FlatElement


def time_derivatives(ctx: Context, defs: dict, owner: dict, derivs: dict, state_vars,
                     seeds=()) -> tuple:
    """Define the ``dt_`` symbols of the dependent storage elements by the chain rule.

    Forward mode in time along the causal assignments: for every assignment v = g(...) that a
    dependent state depends on, ``_dt_v = sum(dg/ds * _dt_s) + dg/dt``; a state's time
    derivative is the symbol ``_dx_<state>``, itself assigned the state's derivative. The
    loop this closes (state derivatives -> dependent efforts -> junctions -> state
    derivatives) is linear in its unknowns and solved by ``_tear_solve``.
    ``seeds``: further symbols whose ``_dt_`` a constraint needs (the flows it holds).
    Returns the tear candidates: (the _dx_ symbols, the dependent dt_ symbols)."""
    bg = ctx.bg
    state_syms = {sv.symbol: sv for sv in state_vars}
    input_syms = {s: iv.name for iv in ctx.inputs.values() for s in iv.symbols}
    dt_syms = {d: eid for eid, _, dots in ctx.dependent for d in dots}
    dep_of: dict = {}  # state symbol of a dependent element -> its dt_ symbol
    for eid, states, dots in ctx.dependent:
        dep_of.update(zip(states, dots))
    # closure of the assignments the dependent states depend on
    need, stack = set(), [s for s in dep_of] + list(seeds)
    while stack:
        s = stack.pop()
        if s in need or s not in defs:
            continue
        need.add(s)
        stack.extend(d for d in defs[s].expr.free_symbols if d in defs)
    dot: dict = {}
    dx: dict = {}
    for s in sorted(need, key=str):
        dot[s] = dep_of.get(s) or real_symbol(f"_dt_{s}")
    for s in sorted({d for v in need for d in defs[v].expr.free_symbols if d in state_syms},
                    key=str):
        dot[s] = real_symbol(f"_dx_{s}")
        dx[dot[s]] = s
    for s in sorted(need, key=str):
        a = defs[s]
        expr = a.expr
        free = expr.free_symbols
        for d in free:
            if d in input_syms:
                who = owner[s]
                deps = sorted({e for e, st, _ in ctx.dependent}) or list(ctx.caus.constraints)
                raise ModelError(bg.element(who).coord,
                                 f"derivative causality of {', '.join(map(repr, deps))}: its "
                                 f"state (or the constraint's flow) follows from input {input_syms[d]!r} through "
                                 f"{_kind(bg.element(who))}, whose time derivative bgc would "
                                 "need; drive it through a compliant coupling, or make the "
                                 "signal an expression of t")
            if d in dt_syms:
                raise ModelError(bg.element(dt_syms[d]).coord,
                                 f"derivative causality of {dt_syms[d]!r} feeds another "
                                 f"dependent element through {_kind(bg.element(owner[s]))}: "
                                 "a second derivative would be needed (index > 2); add a "
                                 "compliant coupling")
        terms = [clean_derivative(sp.diff(expr, d)) * dot[d] for d in sorted(free, key=str) if d in dot]
        terms.append(clean_derivative(sp.diff(expr, T)))
        val = sp.Add(*terms)
        defs[dot[s]] = Assignment(dot[s], val, f"d/dt of {s} ({a.why})" if s not in dep_of
                                  else f"{owner[s]}: d/dt of its state (chain rule)")
        owner[dot[s]] = owner[s]
    for d, s in dx.items():
        defs[d] = Assignment(d, derivs[s], f"derivative of state {state_syms[s].name}")
        owner[d] = state_syms[s].owner
    return (frozenset(dx), frozenset(dt_syms))


def _tear_solve(bg, g, defs, owner, comp, index, tear_sets, symbolic_max, residual=frozenset()):
    """Solve an algebraic loop that is linear in its unknowns by tearing.

    With the tear variables known, the rest of the loop is acyclic; every value in it is
    affine in the tear variables, with coefficients found by forward-mode differentiation
    along the loop (new assignments, free of loop variables: otherwise the loop is
    nonlinear). The loop evaluated at tear = 0 gives the constant part. That leaves
    (I - A) tear = b, solved symbolically on symbols standing for the entries while small,
    else numerically in the generated code. ``residual``: unknowns whose assignment is a
    residual, zero at the solution (a constraint's reaction), always torn. Returns
    (description or None)."""
    cset = set(comp)
    tear = _tear_choice(g, comp, index, tear_sets, residual)
    if tear is None:
        return None
    tset = set(tear)
    rest_g = g.subgraph([s for s in comp if s not in tset]).copy()
    rest = schedule(rest_g, index)
    els = sorted({owner[s] for s in comp if owner.get(s)})
    where = _coord(bg, els[0])
    counter = itertools.count(len(index))
    new: list = []

    def add(sym, expr, why, own):
        defs[sym] = Assignment(sym, expr, why)
        owner[sym] = own
        index[sym] = next(counter)
        new.append(sym)

    C: dict = {t: {k: sp.Integer(1)} for k, t in enumerate(tear)}
    tag = str(tear[0]).lstrip("_")
    nco = itertools.count()

    def coeffs(s):
        expr = defs[s].expr
        acc: dict = {}
        for d in expr.free_symbols & cset:
            part = clean_derivative(sp.diff(expr, d))
            if part == 0:
                continue
            bad = part.free_symbols & cset
            if bad:
                raise ModelError(where, "algebraic loop through " + ", ".join(
                    _who(bg, e) for e in els) + f" is nonlinear in its unknowns "
                    f"({', '.join(sorted(map(str, bad))[:6])}): bgc solves linear loops only")
            for k, c in C.get(d, {}).items():
                acc[k] = acc[k] + part * c if k in acc else part * c
        out = {}
        for k, v in sorted(acc.items()):
            if v == 0:
                continue
            if is_trivial(v):
                out[k] = v
            else:
                sym = real_symbol(f"_l{next(nco)}_{tag}")
                add(sym, v, "", owner[s])
                out[k] = sym
        return out

    for s in rest:
        C[s] = coeffs(s)
    a_rows = [coeffs(t) for t in tear]
    zero = {t: sp.Integer(0) for t in tear}
    for s in rest:
        z = real_symbol(f"_z_{s}".replace("__z_", "_z_"))
        add(z, defs[s].expr.xreplace(zero), defs[s].why + " (loop at zero)", owner[s])
        zero[s] = z
    n = len(tear)
    how = _solve_torn(tear, defs, owner, a_rows, zero, tag, add, symbolic_max, residual)
    # rebuild the dependency edges of everything touched
    for s in list(comp) + new:
        g.add_node(s)
        for dep in list(g.predecessors(s)):
            g.remove_edge(dep, s)
        for dep in _deps(defs[s].expr):
            if dep in defs:
                g.add_edge(dep, s)
    desc = ", ".join(_who(bg, e) for e in els)
    return (f"derivative causality: linear system in {n} unknown(s) "
            f"({', '.join(str(t).lstrip('_') for t in tear)}) solved {how}, through {desc}")


def _tear_choice(g, comp: list, index: dict, tear_sets, residual=frozenset()) -> list | None:
    """The smallest set of tear candidates (state derivatives, dependent time derivatives, or
    both) in the loop that leaves the rest of it acyclic, always with the residual unknowns;
    None if there is none."""
    cset = set(comp)
    best = None
    forced = cset & residual
    cands = [sorted((cset & ts) | forced, key=index.get) for ts in tear_sets]
    cands = [c for c in cands if c]
    if len(cands) > 1:
        cands.append(sorted(set(cands[0]) | set(cands[1]), key=index.get))
    for cand in sorted(cands, key=len):
        rest = [s for s in comp if s not in set(cand)]
        if topological(g.subgraph(rest), index) is not None:  # acyclic
            best = cand
            break
    return best


def _solve_torn(tear, defs, owner, a_rows, zero, tag, add, symbolic_max,
                residual=frozenset()) -> str:
    """(I - A) tear = b: the right-hand side and the matrix as new assignments (``add``), the
    solution symbolic while small, else one numeric solve; the tear variables redefined by it.
    A residual row (r(tear) = R tear + r0 = 0) enters as R tear = -r0.
    Returns how it was solved."""
    n = len(tear)
    bsyms, A = [], sp.zeros(n, n)
    for i, t in enumerate(tear):
        res = t in residual
        bexpr = defs[t].expr.xreplace(zero)
        if res:
            bexpr = -bexpr
        if is_trivial(bexpr):
            bsyms.append(bexpr)
        else:
            b = real_symbol(f"_b{i}_{tag}")
            add(b, bexpr, f"linear system for {', '.join(map(str, tear))}: right-hand side",
                owner[t])
            bsyms.append(b)
        for k in range(n):
            v = (sp.sympify(a_rows[i].get(k, 0)) if res
                 else (1 if i == k else 0) - a_rows[i].get(k, 0))
            if v == 0 or v.is_Number:
                A[i, k] = v
            else:
                a = real_symbol(f"_A{i}_{k}_{tag}")
                add(a, v, "linear system: matrix" if (i, k) == (0, 0) else "", owner[t])
                A[i, k] = a
    if n <= symbolic_max:
        sol = list(A.LUsolve(sp.Matrix(bsyms)))
        how = "symbolically"
    else:
        X = real_symbol(f"_X_{tag}")
        add(X, LinSolve(n, *list(A), *bsyms), f"numeric linear solve ({n} unknowns)", owner[tear[0]])
        sol = [LinSolveEntry(X, i) for i in range(n)]
        how = "numerically (np.linalg.solve)"
    for t, v in zip(tear, sol):
        defs[t] = Assignment(t, v, defs[t].why + " (linear system solved)")
    return how


def _cut_set(g, comp: list, index: dict) -> list:
    """Tear variables that leave the loop acyclic: greedily the node with the most
    in x out edges inside what is still cyclic (ties: the first in causal priority)."""
    import networkx as nx  # lazy: only models with nonlinear algebraic loops come here

    tear: list = []
    rest = set(comp)
    while True:
        sub = g.subgraph(rest)
        cyc = [c for c in nx.strongly_connected_components(sub)
               if len(c) > 1 or any(sub.has_edge(v, v) for v in c)]
        if not cyc:
            return tear
        cand = max((v for c in cyc for v in c),
                   key=lambda v: (sub.in_degree(v) * sub.out_degree(v), -index[v]))
        tear.append(cand)
        rest.discard(cand)


def _newton_loop(bg, g, defs, owner, comp, index, newton: list) -> str:
    k = len(newton)
    tear = sorted(_cut_set(g, comp, index), key=index.get)
    tset = set(tear)
    rest = schedule(g.subgraph([s for s in comp if s not in tset]).copy(), index)
    cset = set(comp)
    els = sorted({owner[s] for s in comp})
    desc = ", ".join(_who(bg, e) for e in els)
    body: list = []
    C: dict = {t: {i: sp.Integer(1)} for i, t in enumerate(tear)}
    nco = itertools.count()

    def coeffs(expr):
        acc: dict = {}
        for d in expr.free_symbols & cset:
            part = clean_derivative(sp.diff(expr, d))
            if part == 0:
                continue
            for i, c in C.get(d, {}).items():
                acc[i] = acc[i] + part * c if i in acc else part * c
        out = {}
        for i, v in sorted(acc.items()):
            if v == 0:
                continue
            if is_trivial(v):
                out[i] = v
            else:
                sym = real_symbol(f"_nc{next(nco)}")
                body.append((sym, v))
                out[i] = sym
        return out

    for s in rest:
        body.append((s, defs[s].expr))
        C[s] = coeffs(defs[s].expr)
    G = [defs[t].expr for t in tear]
    n = len(tear)
    a_rows = [coeffs(gi) for gi in G]
    residual = tuple(t - gi for t, gi in zip(tear, G))
    jac = tuple((1 if i == j else 0) - a_rows[i].get(j, 0) for i in range(n) for j in range(n))
    inner = {sym for sym, _ in body} | tset
    outside = set()
    for e in [e for _, e in body] + list(residual) + list(jac):
        outside |= sp.sympify(e).free_symbols - inner
    args = tuple(sorted(outside, key=str))
    c = _coord(bg, els[0])
    # the file's name, not its path: the message is printed into the generated module, which
    # must not depend on where the model was compiled (as its "Source:" line)
    where = f"{os.path.basename(c.file)}:{c.line}:{c.column}: " if c else ""
    X = real_symbol(f"_nl{k}")
    newton.append(NewtonLoop(f"_newton_{k}", tuple(tear), args, tuple(body), residual, jac,
                             tuple(G), tuple(rest),
                             f"{where}algebraic loop through {desc} (unknowns "
                             f"{', '.join(map(str, tear))})"))
    defs[X] = Assignment(X, NewtonSolve(k, *args), f"nonlinear algebraic loop through {desc}: "
                                                   "Newton's method")
    owner[X] = els[0]
    index[X] = len(index)
    for i, t in enumerate(tear):
        defs[t] = Assignment(t, LinSolveEntry(X, i), defs[t].why + " (Newton)")
    for v in list(comp) + [X]:
        g.add_node(v)
        for dep in list(g.predecessors(v)):
            g.remove_edge(dep, v)
        for dep in defs[v].expr.free_symbols:
            if dep in defs:
                g.add_edge(dep, v)
    return (f"nonlinear algebraic loop solved by Newton's method in {n} unknown(s) "
            f"({', '.join(map(str, tear))}), through {desc}")


def _deps(expr):
    return expr.free_symbols


def causal_order(bg: BondGraph, defs: dict, owner: dict, tear_sets=(),
                  symbolic_max: int = SYMBOLIC_MAX, newton: list | None = None,
                  residual=frozenset()):
    """Assignments in causal order; algebraic loops solved where linear (symbolically), and
    nonlinear ones by Newton's method in the generated code when ``newton`` (a list that
    receives the loops) is given. ``residual``: unknowns defined by a residual (constraint
    reactions), each of which must lie in a loop torn at it."""
    index = {s: i for i, s in enumerate(defs)}
    deps = {s: [d for d in a.expr.free_symbols if d in defs] for s, a in defs.items()}
    quick = DepGraph()
    for s, ds in deps.items():
        quick.add_node(s)
        for dep in ds:
            quick.add_edge(dep, s)
    order = topological(quick, index)  # no algebraic loop (most models): nothing to solve
    loops: list = []
    torn: set = set()
    if order is None:
        order = _solve_loops(bg, defs, owner, deps, index, tear_sets, symbolic_max, newton,
                             residual, loops, torn)
    loose = sorted(residual - torn, key=str)
    if loose:
        src = owner[loose[0]]
        raise ModelError(_coord(bg, src), f"constraint {src!r}: its reaction "
                         f"({', '.join(map(str, loose))}) does not act on the motion it "
                         "constrains (no loop from the reaction through the accelerations back "
                         "to the constraint): the constraint is singular or redundant; remove "
                         "it or make the connection compliant")
    return order, loops


def _solve_loops(bg, defs, owner, deps, index, tear_sets, symbolic_max, newton, residual,
                 loops: list, torn: set) -> list:
    """The algebraic loops (strongly connected components) solved, appending to ``loops``
    and ``torn``; returns the causal order. On networkx's graph, built as it always was (the
    order of its components names the loops)."""
    import networkx as nx  # lazy: only models with algebraic loops need its components

    g = nx.DiGraph()
    for s, ds in deps.items():
        g.add_node(s)
        for dep in ds:
            g.add_edge(dep, s)
    for comp in list(nx.strongly_connected_components(g)):
        if len(comp) == 1:
            (s,) = comp
            if not g.has_edge(s, s):
                continue
        comp = sorted(comp, key=index.get)
        if any(cset_t & set(comp) for cset_t in tear_sets) or residual & set(comp):
            done = _tear_solve(bg, g, defs, owner, comp, index, tear_sets, symbolic_max,
                               residual)
            torn |= residual & set(comp)
            if done is None:
                els = sorted({owner[s] for s in comp})
                raise ModelError(_coord(bg, els[0]), "derivative causality: the loop "
                                 "through " + ", ".join(_who(bg, e) for e in els)
                                 + " cannot be torn at the state derivatives")
            loops.append(done)
            continue
        els = sorted({owner[s] for s in comp})
        desc = ", ".join(_kind(bg.element(e)) for e in els)
        eqs = [s - defs[s].expr for s in comp]
        try:
            A, rhs = sp.linear_eq_to_matrix(eqs, comp)
        except (sp.polys.polyerrors.PolynomialError, ValueError, TypeError):
            A = None
        if (A is None or any(A.has(s) for s in comp)) and newton is not None:
            loops.append(_newton_loop(bg, g, defs, owner, comp, index, newton))
            continue
        if A is None or any(A.has(s) for s in comp):
            raise ModelError(bg.element(els[0]).coord,
                             f"algebraic loop through {desc} is nonlinear in its unknowns "
                             f"({', '.join(map(str, comp[:6]))}); bgc solves linear loops only: "
                             "add a storage element (e.g. a small C or I) to break it")
        if len(comp) > 60:
            raise ModelError(bg.element(els[0]).coord, f"algebraic loop through {desc} has "
                                                       f"{len(comp)} unknowns (limit 60)")
        try:
            sol = A.LUsolve(rhs)
        except (ValueError, ZeroDivisionError, sp.matrices.exceptions.NonInvertibleMatrixError):
            raise ModelError(bg.element(els[0]).coord,
                             f"algebraic loop through {desc} is singular: its equations do not "
                             "determine its unknowns (a law that reads the variable it "
                             "defines?)") from None
        loops.append(f"linear algebraic loop solved through {desc}")
        for s, v in zip(comp, sol):
            defs[s] = Assignment(s, v, defs[s].why + " (algebraic loop, solved)")
        for s in comp:
            for dep in list(g.predecessors(s)):
                g.remove_edge(dep, s)
            for dep in defs[s].expr.free_symbols:
                if dep in defs:
                    g.add_edge(dep, s)
    return schedule(g, index)


def _who(bg: BondGraph, oid: str) -> str:
    """An element (by kind) or an auxiliary state, for messages."""
    if oid in bg._el:
        return _kind(bg.element(oid))
    return f"state {oid!r}"


def _coord(bg: BondGraph, oid: str):
    if oid in bg._el:
        return bg.element(oid).coord
    return next((st.coord for st in bg.states if st.id == oid), None)


def _kind(el: FlatElement) -> str:
    """'R 'load'', '0-junction 'node''."""
    return f"{el.type}-junction {el.id!r}" if el.type in ("0", "1") else f"{el.type} {el.id!r}"
