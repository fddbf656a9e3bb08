"""What the input signals tell the integrator: the periods of periodic inputs, and the
instants where an input jumps (input_breakpoints: comparisons of time with a constant).

An integrator with a loose tolerance may step over the part of a period where a model does
something sharp (a diode that conducts for a millisecond of each 20 ms cycle) and never see it:
the error estimate only samples where the steps land. A scene's periodic inputs therefore bound
the step by default (bgc.run.runner.scene_max_step, from the module's INPUT_PERIODS). The periods are read off the inputs' expressions: every
sin, cos or tan whose argument is a*t + b (a and b of parameters), evaluated at the parameters'
values. Table inputs are bounded by their knots already (TABLE_BREAKPOINTS, TABLE_MAX_STEP).
"""
from __future__ import annotations

import math

import sympy as sp

from bgc.core.eqtypes import T


def _values(eq) -> dict:
    """The parameters' values (symbol -> sympy number), derived parameters included."""
    vals = {}
    for pv in eq.params:
        flat = pv.value
        while isinstance(flat, (list, tuple)) and flat and isinstance(flat[0], (list, tuple)):
            flat = [v for row in flat for v in row]
        flat = flat if isinstance(flat, (list, tuple)) else [flat]
        for s, v in zip(pv.symbols, flat):
            if isinstance(v, (int, float)):
                vals[s] = sp.Float(v)
    for d in eq.derived:
        if isinstance(d.symbol, sp.Symbol):
            try:
                vals[d.symbol] = d.expr.xreplace(vals)
            except (TypeError, AttributeError):
                pass
    return vals


def _period(arg, vals) -> float | None:
    """2 pi / |a| for an argument a*t + b, None for anything else."""
    if T not in arg.free_symbols:
        return None
    a = sp.diff(arg, T)
    if T in a.free_symbols:
        return None
    try:
        a = abs(float(a.xreplace(vals)))
    except (TypeError, ValueError):
        return None
    return 2 * math.pi / a if math.isfinite(a) and a > 0 else None


def input_periods(eq) -> dict[str, float]:
    """The shortest period (s) of each periodic input signal of eq, by input name."""
    vals = _values(eq)
    out = {}
    for iv in eq.inputs:
        if getattr(iv, "table", None) is not None:
            continue
        periods = [p for d in iv.default if isinstance(d, sp.Basic)
                   for f in d.atoms(sp.sin, sp.cos, sp.tan)
                   for p in [_period(f.args[0], vals)] if p is not None]
        if periods:
            out[iv.name] = min(periods)
    return out


def _crossing(rel, vals) -> float | None:
    """The instant where a condition on time flips: c for t < c, t >= c, c - t > 0, ... (a
    side linear in t, its coefficients of parameters), None for anything else."""
    d = rel.lhs - rel.rhs
    if T not in d.free_symbols:
        return None
    a = sp.diff(d, T)
    if T in a.free_symbols:
        return None
    try:
        a = float(a.xreplace(vals))
        b = float(d.subs(T, 0).xreplace(vals))
    except (TypeError, ValueError):
        return None
    if not (math.isfinite(a) and math.isfinite(b)) or a == 0:
        return None
    c = -b / a
    return c if math.isfinite(c) else None


def input_breakpoints(eq) -> tuple[float, ...]:
    """The instants where an input signal may jump, read off its expressions: every
    comparison of time with a constant (``where(t < 1, 0, F0)`` jumps at t = 1), evaluated at
    the parameters' values. An integrator that is not told steps into the jump and, at a tight
    tolerance, shrinks its step until it fails there."""
    vals = _values(eq)
    out = set()
    for iv in eq.inputs:
        if getattr(iv, "table", None) is not None:
            continue
        for d in iv.default:
            if not isinstance(d, sp.Basic):
                continue
            for rel in d.atoms(sp.core.relational.Relational):
                c = _crossing(rel, vals)
                if c is not None:
                    out.add(c)
            for h in d.atoms(sp.Heaviside):
                c = _crossing(sp.Gt(h.args[0], 0), vals)
                if c is not None:
                    out.add(c)
    return tuple(sorted(out))
