"""Dimensions with unknowns: linear forms over dimension variables, and the system they obey.

A quantity whose dimension is not declared (a bond's effort, a parameter without a unit) is a
*variable*; every dimension met while checking a model is a :class:`Form`: a constant dimension
(SI base exponents, bgc.format.units) plus a rational combination of variables (``e(b1) + s -
kg``: the dimension of the momentum of an I on bond b1). Laws say two forms are equal; a
:class:`System` keeps those equalities solved (Gaussian elimination, one variable at a time,
over the rationals), so a variable is known as soon as the laws fix it and a law that
contradicts the others is found when it is added: it is the one reported. ``ANY`` is the
dimension of the number 0, which agrees with everything.
"""
from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction

from bgc.base.errors import Coord, ModelError
from bgc.format.units import ZERO, Dim, div, mul, num, power, show


@dataclass(frozen=True)
class Form:
    """``const + sum(coef * var)``; ``terms`` is a tuple of (var, coef), sorted, coef != 0."""

    const: Dim
    terms: tuple = ()

    @staticmethod
    def of(d: Dim) -> "Form":
        return Form(d)

    @staticmethod
    def var(name) -> "Form":
        return Form(ZERO, ((name, 1),))

    def __add__(self, other: "Form") -> "Form":  # product of quantities: dimensions add
        return _combine(self, other, 1)

    def __sub__(self, other: "Form") -> "Form":
        return _combine(self, other, -1)

    def scaled(self, n) -> "Form":
        n = n if type(n) is int else num(Fraction(n))
        if n == 1:
            return self
        if n == 0:
            return Form(ZERO)
        return Form(power(self.const, n), tuple((v, num(c * n)) for v, c in self.terms))

    @property
    def known(self) -> bool:
        return not self.terms


ANY = None  # the dimension of 0 (and of zeros(n)): equal to anything


_TEXT: dict = {}  # variable -> str(variable): the terms' order, computed once per variable


def _order(term) -> str:
    """A term's sort key: its variable's text (memoised: str of a tuple per comparison was a
    third of a large model's unit check)."""
    v = term[0]
    try:
        return _TEXT[v]
    except KeyError:
        if len(_TEXT) > 1_000_000:  # (bounded: one process may check many models)
            _TEXT.clear()
        _TEXT[v] = text = str(v)
        return text


def _combine(a: Form, b: Form, sign: int) -> Form:
    if not b.terms:
        terms = a.terms
    else:
        coefs: dict = dict(a.terms)
        for v, c in b.terms:
            coefs[v] = num(coefs.get(v, 0) + sign * c)
        terms = tuple(sorted(((v, c) for v, c in coefs.items() if c != 0),
                             key=_order))
    const = mul(a.const, b.const) if sign > 0 else div(a.const, b.const)
    return Form(const, terms)


def show_form(f: Form | None) -> str:
    """A form in words: its dimension when known, else with the unknowns named."""
    if f is None:
        return "any dimension (zero)"
    if f.known:
        return show(f.const)
    parts = [show(f.const)] if any(f.const) else []
    for v, c in f.terms:
        name = v if isinstance(v, str) else "".join(map(str, v))
        parts.append(f"[{name}]" if c == 1 else f"[{name}]^({c})")
    return "*".join(parts) + " (not all known)"


class System:
    """Equalities of forms, kept solved: ``rows`` maps a pivot variable to the form it equals
    (in variables that are not pivots)."""

    def __init__(self):
        self.rows: dict = {}
        self.uses: dict = {}  # variable -> the pivots whose rows mention it
        self.fresh = 0
        self.soft: list = []  # unknowns that are 1 unless the laws say otherwise

    def new_var(self, hint: str, soft: bool = False):
        self.fresh += 1
        var = (f"?{hint}", self.fresh)
        if soft:
            self.soft.append(var)
        return var

    def settle(self) -> None:
        """The soft unknowns the laws leave open become dimensionless."""
        for var in self.soft:
            try:
                self.equate(Form.var(var), Form(ZERO), None, lambda a, b: "")
            except ModelError:
                pass

    def resolve(self, f: Form | None) -> Form | None:
        """``f`` in the variables that are not pivots: each pivot's row substituted, summed in
        one pass (exact rationals: the same form as adding the scaled rows one by one)."""
        if f is None or not f.terms:
            return f
        coefs: dict = {}
        return self._form(self._substituted(f, 1, f.const, coefs), coefs)

    def _difference(self, a: Form, b: Form) -> Form:
        """``resolve(a - b)`` in one pass over both (the same exact sums, one sort)."""
        coefs: dict = {}
        const = self._substituted(a, 1, div(a.const, b.const), coefs)
        return self._form(self._substituted(b, -1, const, coefs), coefs)

    def _substituted(self, f: Form, sign: int, const, coefs: dict):
        """Adds sign * f's terms to ``coefs``, each pivot replaced by its row; returns the
        constant times the pivots' constants."""
        rows = self.rows
        for v, c in f.terms:
            c = c * sign
            row = rows.get(v)
            if row is None:
                coefs[v] = coefs.get(v, 0) + c
                continue
            const = mul(const, power(row.const, c))
            for w, d in row.terms:
                coefs[w] = coefs.get(w, 0) + d * c
        return const

    @staticmethod
    def _form(const, coefs: dict) -> Form:
        return Form(const, tuple(sorted(((v, num(c)) for v, c in coefs.items() if c != 0),
                                        key=_order)))

    def equate(self, a: Form | None, b: Form | None, coord: Coord, message) -> None:
        """Record a == b; a contradiction raises ``message(shown a, shown b)`` at ``coord``."""
        if a is None or b is None:
            return
        diff = self._difference(a, b)
        if not diff.terms:
            if any(diff.const):
                raise ModelError(coord, message(show_form(self.resolve(a)),
                                                show_form(self.resolve(b))))
            return
        # the variable fewest rows mention: a chain of equalities stays linear in time
        pivot, coef = min(diff.terms, key=lambda t: len(self.uses.get(t[0], ())))
        rest = Form(diff.const, tuple(t for t in diff.terms if t[0] != pivot)).scaled(
            -1 if coef == 1 else 1 if coef == -1 else Fraction(-1) / coef)
        for v in self.uses.pop(pivot, ()):
            row = self.rows[v]
            c = dict(row.terms).get(pivot)
            if c is None:  # (the row no longer mentions it)
                continue
            self.rows[v] = Form(row.const, tuple(t for t in row.terms if t[0] != pivot)) \
                + rest.scaled(c)
            for w, _ in rest.terms:
                self.uses.setdefault(w, set()).add(v)
        self.rows[pivot] = rest
        for w, _ in rest.terms:
            self.uses.setdefault(w, set()).add(pivot)

    def value(self, f: Form | None) -> Dim | None:
        """The dimension of ``f`` when the laws fix it, else None."""
        r = self.resolve(f)
        return r.const if r is not None and r.known else None
