"""Consistent initial conditions of closed kinematic loops (issue 24).

A constraint (bgc.core.constraints) holds a loop at velocity and acceleration level; its
position level is the user's ``closure:`` residual Phi(x) where one is given. At compile time,
at the model's initial state and parameters:

- positions: Phi(x0) must vanish (to 1e-9 of the residual's terms), else a located error at the
  source naming the loop and the residual;
- velocities: q'(0) = f - s must vanish (to 1e-9 of the velocities along the loop), else the
  same kind of error;
- with ``constraints: {initial: project}`` the initial state is first projected
  (bgc.core.projection): the positions by Newton's method with the minimum-norm correction
  (least squares on the closure residuals' Jacobian, over the states they read), then the
  momenta onto the velocity constraints (affine in the momenta at fixed positions) by the
  change of least kinetic-energy distance (a physical impulse). What changed is returned as
  notes (``bgc check`` and the compile print them); the states' initial values become the
  projected numbers.

``constraint_values`` gives what a projection at run start reads from the generated module
(its ``constraint_residuals`` and ``kinetic_energy``): the position and velocity residuals of
every constraint component and the kinetic energy (1/2 p.f over the I elements, integral and
derivative causality: exact for linear inertias).

Skipped where a value cannot be evaluated at compile time (an input table, a Newton loop on the
way), as the velocity check always was.
"""
from __future__ import annotations

from dataclasses import replace as dc_replace

import sympy as sp

from bgc.base.errors import ModelError
from bgc.core.constraints import closure_of, initial_values, lock_of, loop_text, number_of
from bgc.core.context import Context
from bgc.core.eqtypes import T, flat

_TOL = 1e-9  # relative tolerance of the checks


def kinetic_energy(ctx: Context, subs: dict | None = None):
    """1/2 p.f summed over the I elements (states and those in derivative causality), in the
    kept assignments' symbols (``subs``: the inlined copies)."""
    total = sp.Integer(0)
    for el in ctx.bg.elements:
        p = ctx.states.get(el.id) if el.type == "I" else None
        if p is None:
            continue
        (b,) = ctx.bg.bonds_of(el.id)
        for pk, fk in zip(flat(p), flat(ctx.f[b.id])):
            total += pk * fk / 2
    return total.xreplace(subs) if subs else total


def constraint_values(ctx: Context, state_vars, kept, subs, derivatives) -> dict:
    """The Equations fields a projection at run start reads (empty without constraints): the
    position residuals (the closure, else the violation q), the velocity residuals (q' = f - s)
    and the kinetic energy; which components have a closure; the momenta's and the closures'
    states by name."""
    if not ctx.constraints:
        return {}
    index = {sv.symbol: k for k, sv in enumerate(state_vars)}
    pos, vel, closed = [], [], []
    for c in ctx.constraints:
        for k, q in enumerate(c.q):
            pos.append(sp.sympify(c.closure[k]) if c.closure else q)
            vel.append(derivatives[index[q]])
            closed.append(bool(c.closure))
    energy = kinetic_energy(ctx, subs)
    known = set(index) | {T} | {a.symbol for a in kept} | {a.symbol for a in ctx.derived.values()}
    known |= {s for pv in ctx.params.values() for s in pv.symbols}
    known |= {s for iv in ctx.inputs.values() for s in iv.symbols}
    if sp.sympify(energy).free_symbols - known:
        energy = sp.Integer(0)  # not from the kept assignments: the projection says so
    types = {el.id: el.type for el in ctx.bg.elements}
    read = {s for c in ctx.constraints for phi in (c.closure or ()) for s in
            sp.sympify(phi).free_symbols}
    return dict(constraint_values=tuple(pos + vel + [energy]), constraint_closed=tuple(closed),
                momentum_states=tuple(sv.name for sv in state_vars if types.get(sv.owner) == "I"),
                closure_states=tuple(sv.name for sv in state_vars if sv.symbol in read))


def consistent_initial(ctx: Context, state_vars: list, kept, derivatives,
                       project: bool, energy=None) -> list[str]:
    """Check (and, where ``project``, first project) the initial state against the
    constraints. ``state_vars`` is updated in place when projecting; ``energy``: the kinetic
    energy (``kinetic_energy``), the velocity projection's metric. Returns the notes."""
    if not ctx.constraints:
        return []
    vals = initial_values(ctx, state_vars)
    if vals is None:
        return []
    notes: list[str] = []
    closing = [c for c in ctx.constraints if c.closure]
    if closing and project:
        notes += _project_positions(ctx, state_vars, vals, closing)
    for c in closing:
        _check_positions(ctx, vals, c)
    velocity = _Velocity(ctx, state_vars, kept, derivatives, energy if project else None)
    if project:
        notes += _project_velocities(ctx, state_vars, vals, velocity)
    res = velocity.residuals(vals)
    if res is None:
        return notes
    scale = velocity.scale
    for c in ctx.constraints:
        worst = max(abs(r) for r in res[c.source])
        if worst > _TOL * max(1.0, scale):
            raise ModelError(ctx.bg.element(c.source).coord, _message(
                ctx, c, "the initial velocities violate it: the flow of bond "
                f"{c.bond!r} differs from the source's by [{_shown(res[c.source])}] (SI units of "
                "the bond's flow); give initial velocities (momenta) that satisfy the loop"))
    return notes


def _message(ctx, c, what: str) -> str:
    return (f"constraint {c.source!r} closing the kinematic loop {loop_text(ctx.bg, c.source)}: "
            f"{what}, or set `constraints: {{initial: project}}`")


def _shown(values) -> str:
    return ", ".join(f"{float(v):.6g}" for v in values)


def _check_positions(ctx, vals, c) -> None:
    res, scale = [], 1.0
    for phi in c.closure:
        v = number_of(phi, vals)
        if v is None:
            return
        res.append(float(v))
        terms = sp.Add.make_args(sp.expand(phi, deep=False, mul=False, power_exp=False))
        for term in terms:
            tv = number_of(term, vals)
            scale = max(scale, abs(float(tv)) if tv is not None else 0.0)
    if max(abs(r) for r in res) > _TOL * scale:
        raise ModelError(ctx.bg.element(c.source).coord, _message(
            ctx, c, f"the initial positions violate its closure: the residual is [{_shown(res)}] "
            "(SI units of the bond's displacement); give initial positions that close the loop"))


def _name_of(state_vars, sym) -> str:
    return next(sv.name for sv in state_vars if sv.symbol == sym)


def _set_initial(state_vars, vals, sym, value: float) -> None:
    for k, sv in enumerate(state_vars):
        if sv.symbol == sym:
            state_vars[k] = dc_replace(sv, initial=sp.Float(value))
    vals[sym] = sp.Float(value)


def _project_positions(ctx, state_vars, vals, closing) -> list[str]:
    """Newton's method on Phi(x) = 0 over the states the closures read; each step the
    minimum-norm correction (least squares)."""
    # lazy: numpy, which only closed loops' numerics need (not on this module's import)
    import numpy as np

    from bgc.core.projection import NEWTON_ITER, changes, newton_positions  # lazy: numpy

    phis = [phi for c in closing for phi in c.closure]
    states = {sv.symbol for sv in state_vars}
    xs = sorted({s for phi in phis for s in phi.free_symbols if s in states}, key=str)
    if not xs:
        return []
    fixed = {s: v for s, v in vals.items() if s not in set(xs)}
    phi_x = [phi.xreplace(fixed) for phi in phis]
    if any(f.free_symbols - set(xs) for f in phi_x):
        return []
    f = sp.lambdify(xs, phi_x, "numpy")
    jac = sp.lambdify(xs, sp.Matrix(phi_x).jacobian(xs), "numpy")
    x0 = np.array([float(vals[s]) for s in xs])
    x, r = newton_positions(lambda v: f(*v), x0, lambda v: jac(*v))
    if not np.isfinite(x).all() or np.abs(r).max() > 1e-12 * max(1.0, np.abs(x).max()):
        c = closing[0]
        raise ModelError(ctx.bg.element(c.source).coord, f"constraint {c.source!r}: "
                         "`initial: project` found no configuration that closes the loop near "
                         f"the given one (residual [{_shown(r)}] after {NEWTON_ITER} Newton "
                         "steps); give initial positions closer to an assembled one")
    for s, a, b in zip(xs, x0, x):
        if a != b:
            _set_initial(state_vars, vals, s, float(b))
    text = changes([_name_of(state_vars, s) for s in xs], x0, x)
    return [f"initial positions projected onto the loop closure: {text}"] if text else []


class _Velocity:
    """The velocity constraints q' = f - s (and the kinetic energy) at given values: the kept
    assignments they read, evaluated in causal order."""

    def __init__(self, ctx, state_vars, kept, derivatives, energy=None):
        index = {sv.symbol: k for k, sv in enumerate(state_vars)}
        self.ctx = ctx
        self.exprs = {c.source: [derivatives[index[q]] for q in c.q] for c in ctx.constraints}
        self.energy_expr = sp.sympify(energy if energy is not None else 0)
        need = closure_of({a.symbol: a for a in kept},
                          [s for es in self.exprs.values() for e in es
                           for s in sp.sympify(e).free_symbols]
                          + list(self.energy_expr.free_symbols))
        self.kept = [a for a in kept if a.symbol in need]
        states = {sv.symbol: sv for sv in state_vars}
        types = {el.id: el.type for el in ctx.bg.elements}
        self.momenta = sorted((s for s in need if s in states
                               and types.get(states[s].owner) == "I"), key=str)
        self.scale = 0.0
        self.energy = 0.0

    def residuals(self, vals) -> dict | None:
        vals = dict(vals)
        scale = 0.0
        for a in self.kept:
            v = number_of(a.expr, vals)
            if v is None:
                return None
            vals[a.symbol] = v
            if str(a.symbol).startswith("f_"):
                scale = max(scale, abs(float(v)))
        self.scale = scale
        out = {}
        for src, es in self.exprs.items():
            rs = [number_of(e, vals) for e in es]
            if any(r is None for r in rs):
                return None
            out[src] = [float(r) for r in rs]
        ke = number_of(self.energy_expr, vals)
        self.energy = float(ke) if ke is not None else 0.0
        return out


def _project_velocities(ctx, state_vars, vals, velocity: _Velocity) -> list[str]:
    """The momenta moved onto the velocity constraints (affine in the momenta at fixed
    positions) by the change of least kinetic-energy distance (bgc.core.projection)."""
    # lazy: numpy, which only closed loops' numerics need (not on this module's import)
    import numpy as np

    from bgc.core.projection import (  # lazy: numpy, as above
        affine_rows, changes, kinetic_projection, quadratic_hessian)

    ps = velocity.momenta
    base = velocity.residuals(vals)
    if base is None or not ps:
        return []
    srcs = [c.source for c in ctx.constraints]
    failed = []

    def at(pv, what):
        trial = dict(vals)
        trial.update({p: sp.Float(float(v)) for p, v in zip(ps, pv)})
        r = velocity.residuals(trial)
        if r is None:
            failed.append(True)
            return np.zeros(1) if what == "r" else 0.0
        return np.array([x for s in srcs for x in r[s]]) if what == "r" else velocity.energy

    p0 = np.array([float(vals[p]) for p in ps])
    r0, g = affine_rows(lambda pv: at(pv, "r"), p0)
    h = quadratic_hessian(lambda pv: at(pv, "e"), p0)
    if failed:
        return []
    dp, metric = kinetic_projection(r0, g, h)
    new = p0 + dp
    text = changes([_name_of(state_vars, p) for p in ps], p0, new)
    for p, a, b in zip(ps, p0, new):
        if a != b:
            _set_initial(state_vars, vals, p, float(b))
    how = ("least kinetic-energy change" if metric else
           "minimum-norm change: no kinetic energy known")
    return [f"initial momenta projected onto the velocity constraints ({how}): {text}"] \
        if text else []


def numeric_redundancy(ctx: Context, defs: dict, state_vars) -> set:
    """The constraint components that are redundant at the model's initial state: the rows of
    the velocity constraints' Jacobian G = d(f - s)/d(momenta) (numeric: the flows are linear
    in the momenta at fixed positions) that add nothing to its rank (SVD, relative tolerance
    1e-9), taken greedily: first the locks of partly determined multibonds (a revolute joint's
    two locked rotations), then the sources that close loops, each in the order causality
    chose them. The locks fix the bodies' out-of-plane rotations joint by joint from the
    ground, so in a planar loop written with 3-D joints what is dropped is the out-of-plane
    part: the last lock of a closed chain of locks and the loop closure's component along the
    joint axes (docs/closed_loops.md).
    Their reactions are then 0 (bgc.core.constraints.stabilise) instead of a singular solve
    at run time. Empty where the initial state cannot be evaluated at compile time."""
    if not ctx.constraints:
        return set()
    # lazy: numpy, which only closed loops' numerics need (not on this module's import)
    import numpy as np

    vals = initial_values(ctx, state_vars)
    if vals is None:
        return set()
    types = {el.id: el.type for el in ctx.bg.elements}
    momenta = [sv.symbol for sv in state_vars if types.get(sv.owner) == "I"]
    locks = [c for c in ctx.constraints if lock_of(ctx.bg, c.source) is not None]
    rows = [(c.source, k, f - s) for c in locks + [c for c in ctx.constraints if c not in locks]
            for k, (f, s) in enumerate(zip(c.flow, c.target))]

    def residuals(at):
        memo: dict = {}
        out = []
        for _, _, e in rows:
            v = _evaluate(e, at, defs, memo)
            if v is None:
                return None
            out.append(v)
        return np.array(out)

    r0 = residuals(vals)
    if r0 is None or not momenta:
        return set()
    cols = []
    for p in momenta:
        trial = dict(vals)
        trial[p] = vals[p] + 1
        rk = residuals(trial)
        if rk is None:
            return set()
        cols.append(rk - r0)
    g = np.array(cols).T
    top = np.linalg.svd(g, compute_uv=False)[0] if g.size else 0.0
    tol = 1e-9 * max(top, 1e-300)
    kept: list = []
    redundant = set()
    for i, (src, k, _) in enumerate(rows):
        trial = np.array(kept + [g[i]])
        if np.linalg.matrix_rank(trial, tol=tol) > len(kept):
            kept.append(g[i])
        else:
            redundant.add((src, k))
    return redundant


def _evaluate(expr, vals: dict, defs: dict, memo: dict) -> float | None:
    """The value of ``expr`` with its defined symbols evaluated through ``defs`` (memoised)."""
    stack = [s for s in sp.sympify(expr).free_symbols if s not in vals]
    while stack:
        s = stack[-1]
        if s in memo or s in vals:
            stack.pop()
            continue
        if s not in defs:
            return None
        todo = [d for d in defs[s].expr.free_symbols if d not in vals and d not in memo]
        if todo:
            stack.extend(todo)
            continue
        v = number_of(defs[s].expr, {**vals, **memo})
        if v is None:
            return None
        memo[s] = v
        stack.pop()
    v = number_of(expr, {**vals, **memo})
    return None if v is None else float(v)
