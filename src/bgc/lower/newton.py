"""A Newton loop's expressions as the printers write them: exponentials guarded and listed.

Circuit laws are exponential (Shockley's diode, i = Is (exp(v / n Vt) - 1)). Plain Newton on
such a loop fails in two ways when it starts far from the solution (a state tens of volts
off): exp() overflows to inf at the start or at a trial point, and a full step moves the
exponent by hundreds of units, far past the solution. The generated loops (templates/numpy,
templates/c/newton.c.j2) therefore

* evaluate every exp(a) of the loop as ``LimExp(a)``: exp(a) up to a = EXP_CAP, continued by
  its tangent beyond (so the residual stays finite and grows only linearly there), and the
  Jacobian's exponentials as ``SlopeExp(a)``, that continuation's derivative exp(min(a, cap));
  the two agree with exp() wherever a <= EXP_CAP, which is where any physical solution lies
  (e^200 is about 7e86);
* list the exponents (``exponents``), so that a Newton step that would raise one by more than
  EXP_STEP is shortened to raise it only logarithmically (a + log(1 + growth): the idea of
  circuit simulators' junction-voltage limiting) before the line search on the residual.
"""
from __future__ import annotations

import sympy as sp

#: The exponent beyond which a loop's exp() is continued by its tangent.
EXP_CAP = 200.0
#: How far one Newton step may raise an exponent before it is limited logarithmically.
EXP_STEP = 2.0


class LimExp(sp.Function):
    """exp(a) for a <= EXP_CAP, exp(cap) (1 + a - cap) beyond: finite, C1, increasing."""

    nargs = 1


class SlopeExp(sp.Function):
    """The derivative of LimExp: exp(min(a, EXP_CAP))."""

    nargs = 1


def _swap(expr, cls):
    expr = sp.sympify(expr)
    return expr.replace(lambda e: isinstance(e, sp.exp), lambda e: cls(e.args[0])) \
        if expr.has(sp.exp) else expr


def guarded(nl) -> dict:
    """The loop's body, residual and Jacobian with their exponentials guarded, and its
    exponents: {"body": [(symbol, expr)], "residual": [...], "jac": [...], "exponents": [...]}.
    The body's derivative coefficients (symbols _nc*, parts of the Jacobian) take SlopeExp,
    its values LimExp."""
    body = [(sym, _swap(e, SlopeExp if str(sym).startswith("_nc") else LimExp))
            for sym, e in nl.body]
    exps = []
    for e in [e for _, e in nl.body] + list(nl.residual):
        for a in sorted(sp.sympify(e).atoms(sp.exp), key=sp.default_sort_key):
            arg = a.args[0]
            if arg not in exps and arg.free_symbols and not arg.is_number:
                exps.append(arg)
    return {"body": body, "residual": [_swap(e, LimExp) for e in nl.residual],
            "jac": [_swap(e, SlopeExp) for e in nl.jac], "exponents": exps}
