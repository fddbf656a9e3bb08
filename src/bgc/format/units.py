"""Unit strings -> SI base-dimension exponent vectors (and a scale factor).

A unit is untrusted text, read by a small tokenizer and recursive-descent parser of its own (no
``eval``, no units library): symbols from a fixed table (``N``, ``kg``, ``Ohm``, ``rad``...),
optionally with an SI prefix (``mm``, ``kN``, ``MPa``), joined by ``*``, ``/``, ``·`` or a
space (``N s/m`` is ``N*s/m``), with powers ``^n`` or ``**n`` (an integer, a decimal such as
``0.5`` or a fraction in parentheses, ``^(1/2)``) and parentheses. ``1`` (or ``-`` alone) is
dimensionless.
Left to right: ``a/b*c`` is ``(a/b)*c``, ``a/b/c`` is ``a/(b*c)``.

A dimension is a tuple of seven exponents (ints, Fractions where not whole) of :data:`BASE`
(m, kg, s, A, K, mol, cd). Radians and steradians are dimensionless. The scale is the factor to
SI (``mm`` -> 0.001); bgc converts no value, the scale is only reported.
"""
from __future__ import annotations

import math
from fractions import Fraction

from bgc.base.limits import LIMITS

#: The base dimensions, in the order of a dimension tuple.
BASE = ("m", "kg", "s", "A", "K", "mol", "cd")
#: Longest unit string read, largest magnitude of an exponent, deepest parentheses.
MAX_CHARS = LIMITS.unit_chars
MAX_EXPONENT = LIMITS.unit_exponent
MAX_NESTING = LIMITS.unit_depth

Dim = tuple  # tuple[Fraction, ...] of length 7

ZERO: Dim = (0,) * 7


def num(x):
    """An exponent: an int when it is whole (fast), else a Fraction."""
    if type(x) is int:  # (first: isinstance of Fraction goes through the ABC machinery)
        return x
    if isinstance(x, Fraction) and x.denominator == 1:
        return x.numerator
    return x


def dim(**exps) -> Dim:
    """``dim(kg=1, m=1, s=-2)``: a dimension from named base exponents (ints, or Fractions
    where they are not whole)."""
    return tuple(num(Fraction(exps.get(b, 0))) for b in BASE)


def mul(a: Dim, b: Dim) -> Dim:
    if b == ZERO:
        return a
    if a == ZERO:
        return b
    return tuple(num(x + y) for x, y in zip(a, b))


def power(a: Dim, n) -> Dim:
    if n == 1 or a == ZERO:
        return a
    return tuple(num(x * n) for x in a)


def div(a: Dim, b: Dim) -> Dim:
    if b == ZERO:
        return a
    return tuple(num(x - y) for x, y in zip(a, b))


_NEWTON = dim(kg=1, m=1, s=-2)
_JOULE = mul(_NEWTON, dim(m=1))
_WATT = div(_JOULE, dim(s=1))
_VOLT = div(_WATT, dim(A=1))
_OHM = div(_VOLT, dim(A=1))
_COULOMB = dim(A=1, s=1)

#: Symbol -> (scale to SI, dimension). Prefixable symbols are in _PREFIXABLE.
SYMBOLS: dict[str, tuple[float, Dim]] = {
    "1": (1.0, ZERO), "m": (1.0, dim(m=1)), "kg": (1.0, dim(kg=1)), "g": (1e-3, dim(kg=1)),
    "s": (1.0, dim(s=1)), "A": (1.0, dim(A=1)), "K": (1.0, dim(K=1)), "mol": (1.0, dim(mol=1)),
    "cd": (1.0, dim(cd=1)), "rad": (1.0, ZERO), "sr": (1.0, ZERO),
    "deg": (math.pi / 180, ZERO), "rpm": (math.pi / 30, dim(s=-1)), "Hz": (1.0, dim(s=-1)),
    "min": (60.0, dim(s=1)), "h": (3600.0, dim(s=1)),
    "N": (1.0, _NEWTON), "Pa": (1.0, div(_NEWTON, dim(m=2))), "bar": (1e5, div(_NEWTON, dim(m=2))),
    "J": (1.0, _JOULE), "W": (1.0, _WATT), "V": (1.0, _VOLT), "C": (1.0, _COULOMB),
    "Ohm": (1.0, _OHM), "ohm": (1.0, _OHM), "\u03a9": (1.0, _OHM), "S": (1.0, power(_OHM, -1)),
    "F": (1.0, div(_COULOMB, _VOLT)), "H": (1.0, mul(_OHM, dim(s=1))),
    "Wb": (1.0, mul(_VOLT, dim(s=1))), "T": (1.0, div(mul(_VOLT, dim(s=1)), dim(m=2))),
    "L": (1e-3, dim(m=3)), "l": (1e-3, dim(m=3)),
}
_PREFIXABLE = ("m", "g", "s", "A", "K", "mol", "N", "Pa", "J", "W", "V", "C", "Ohm", "ohm",
               "S", "F", "H", "Wb", "T", "Hz", "L", "l", "rad", "bar")
PREFIXES = {"G": 1e9, "M": 1e6, "k": 1e3, "c": 1e-2, "m": 1e-3, "u": 1e-6, "\u00b5": 1e-6,
            "n": 1e-9, "p": 1e-12}


class UnitError(ValueError):
    """A unit string bgc cannot read; the message says why (the caller adds the place)."""


def symbol(name: str) -> tuple[float, Dim]:
    """One symbol, with an optional prefix: ``kN`` -> (1000.0, N's dimension)."""
    if name in SYMBOLS:
        return SYMBOLS[name]
    if len(name) > 1 and name[0] in PREFIXES and name[1:] in _PREFIXABLE:
        scale, d = SYMBOLS[name[1:]]
        return PREFIXES[name[0]] * scale, d
    raise UnitError(f"unknown unit {name!r}")


def parse_unit(text: str) -> tuple[float, Dim]:
    """``"N*s/m"`` -> (1.0, (-1, 1, -1, 0, 0, 0, 0)): the scale to SI and the dimension."""
    if not isinstance(text, str):
        raise UnitError("a unit must be text")
    if len(text) > MAX_CHARS:
        raise UnitError(f"unit is longer than {MAX_CHARS} characters")
    if not text.strip():
        raise UnitError("empty unit (write 1 for a dimensionless quantity)")
    if text.strip() == "-":  # the engineers' mark of a dimensionless quantity, as 1
        return 1.0, ZERO
    p = _Parser(_tokens(text), text)
    scale, d = p.product(0)
    if p.peek() is not None:
        raise UnitError(f"unexpected {p.peek()!r}")
    return scale, d


def _tokens(text: str) -> list[str]:
    """Symbols, numbers, operators and parentheses; a blank between two operands is ``*``."""
    out: list[str] = []
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if c in " \t":
            i += 1
            continue
        if text.startswith("**", i):
            out.append("^")
            i += 2
            continue
        if c in "*/^()\u00b7.-+":
            tok = "*" if c == "\u00b7" else c
            if tok == "(" and out and (out[-1] == ")" or _operand(out[-1])) and out[-1] != "^":
                out.append("*")  # N (m/s)  ->  N * (m/s)
            if tok in "-+." and not (out and out[-1] in "^(" or tok == "." and out
                                     and out[-1].isdigit()):
                raise UnitError(f"unexpected {c!r}")
            out.append(tok)
            i += 1
            continue
        j = i
        if c.isdigit():
            while j < n and text[j].isdigit():
                j += 1
        elif c.isalpha() or c in "\u03a9\u00b5":
            while j < n and (text[j].isalpha() or text[j] in "\u03a9\u00b5"):
                j += 1
        else:
            raise UnitError(f"unexpected {c!r}")
        tok = text[i:j]
        if out and (out[-1] == ")" or _operand(out[-1])) and not (
                tok.isdigit() and out[-1] in ("^",)):
            out.append("*")  # N m  ->  N * m
        out.append(tok)
        i = j
    return out


def _operand(tok: str) -> bool:
    return tok[:1].isalnum() or tok[:1] in "\u03a9\u00b5"


class _Parser:
    def __init__(self, toks: list[str], text: str):
        self.toks, self.i, self.text = toks, 0, text

    def peek(self):
        return self.toks[self.i] if self.i < len(self.toks) else None

    def take(self) -> str:
        tok = self.peek()
        if tok is None:
            raise UnitError(f"the unit ends too early")
        self.i += 1
        return tok

    def product(self, depth: int) -> tuple[float, Dim]:
        scale, d = self.factor(depth)
        while self.peek() in ("*", "/"):
            op = self.take()
            s2, d2 = self.factor(depth)
            if op == "*":
                scale, d = scale * s2, mul(d, d2)
            else:
                scale, d = scale / s2, div(d, d2)
        return scale, d

    def factor(self, depth: int) -> tuple[float, Dim]:
        tok = self.take()
        if tok == "(":
            if depth >= MAX_NESTING:
                raise UnitError(f"the unit is nested too deeply")
            scale, d = self.product(depth + 1)
            if self.take() != ")":
                raise UnitError(f"missing ')'")
        elif tok.isdigit():
            if tok != "1":
                raise UnitError(f"a number in a unit must be 1 or an exponent, got {tok!r}")
            scale, d = 1.0, ZERO
        elif _operand(tok):
            scale, d = symbol(tok)
        else:
            raise UnitError(f"unexpected {tok!r}")
        if self.peek() == "^":
            self.take()
            n = self.exponent()
            scale, d = scale ** float(n), power(d, n)
        return scale, d

    def exponent(self) -> Fraction:
        if self.peek() == "(":
            self.take()
            num = self.signed()
            den = Fraction(1)
            if self.peek() == "/":
                self.take()
                den = self.signed()
            if self.take() != ")" or den == 0:
                raise UnitError(f"bad exponent")
            n = num / den
        else:
            n = self.signed()
        if abs(n) > MAX_EXPONENT or n.denominator > MAX_EXPONENT:
            raise UnitError(f"exponent {n} in unit {self.text!r} is out of range (at most "
                            f"{MAX_EXPONENT} in size)")
        return n

    def signed(self) -> Fraction:
        sign = 1
        if self.peek() in ("-", "+"):
            sign = -1 if self.take() == "-" else 1
        tok = self.take()
        if not tok.isdigit() or len(tok) > 3:
            raise UnitError(f"bad exponent {tok!r}")
        value = Fraction(int(tok))
        if self.peek() == ".":
            self.take()
            frac = self.take()
            if not frac.isdigit() or len(frac) > 3:
                raise UnitError(f"bad exponent")
            value += Fraction(int(frac), 10 ** len(frac))
        return sign * value


# ---------------------------------------------------------------------------------------------
# Showing a dimension

#: Named dimensions shown beside the base form (the first name of a dimension wins).
NAMES = (("N", _NEWTON), ("N*m", _JOULE), ("W", _WATT), ("Pa", div(_NEWTON, dim(m=2))),
         ("V", _VOLT), ("Ohm", _OHM), ("F", div(_COULOMB, _VOLT)), ("H", mul(_OHM, dim(s=1))),
         ("S", power(_OHM, -1)), ("C", _COULOMB), ("W/K", div(_WATT, dim(K=1))),
         ("J/K", div(_JOULE, dim(K=1))), ("N*s/m", div(mul(_NEWTON, dim(s=1)), dim(m=1))),
         ("N/m", div(_NEWTON, dim(m=1))), ("N*m*s", mul(_JOULE, dim(s=1))),
         ("N*m/A", div(_JOULE, dim(A=1))), ("m^3/s", dim(m=3, s=-1)))


def _pow_text(name: str, n: Fraction) -> str:
    if n == 1:
        return name
    if n.denominator == 1:
        return f"{name}^{n.numerator}"
    return f"{name}^({n})"


def base_form(d: Dim) -> str:
    """``kg*m/s^2``: the dimension in base units (``1`` when dimensionless)."""
    order = (1, 0, 2, 3, 4, 5, 6)  # kg first, as people write kg*m^2
    num = [_pow_text(BASE[i], d[i]) for i in order if d[i] > 0]
    den = [_pow_text(BASE[i], -d[i]) for i in order if d[i] < 0]
    top = "*".join(num) or "1"
    if not den:
        return top
    bottom = den[0] if len(den) == 1 else "(" + "*".join(den) + ")"
    return f"{top}/{bottom}"


def show(d: Dim) -> str:
    """A dimension for messages: a familiar name when one fits (``N``, ``N*s/m``), else its
    base form (``kg*m^2``)."""
    for name, nd in NAMES:
        if nd == d:
            return name
    return base_form(d)
