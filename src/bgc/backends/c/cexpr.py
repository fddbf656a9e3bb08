"""C text of the model's expressions and names (bgc.backends.c): the C99 printer that writes the
numpy printer's cheap forms, the C identifiers of model identifiers, and the only two ways text
from the model reaches the C sources: :func:`c_string_literal` (string literals) and
:func:`c_comment` (comments)."""
from __future__ import annotations

from typing import ClassVar

import sympy as sp
from sympy.printing.c import C99CodePrinter
from sympy.printing.precedence import PRECEDENCE

from bgc.backends.fastprint import FastPrinting, integer_text

_C_KEYWORDS = frozenset("""auto break case char const continue default do double else enum extern
float for goto if inline int long register restrict return short signed sizeof static struct
switch typedef union unsigned void volatile while _Bool _Complex _Imaginary main errno
NAN INFINITY HUGE_VAL""".split())
# names <math.h>, <stdlib.h> and <string.h> may declare (functions and macros); a local of
# the same name would hide the function the printed code calls
_C_LIBRARY = frozenset("""acos acosh asin asinh atan atan2 atanh cbrt ceil copysign cos cosh erf
erfc exp exp2 expm1 fabs fdim floor fma fmax fmin fmod frexp hypot ilogb ldexp lgamma llrint
llround log log10 log1p log2 logb lrint lround modf nan nearbyint nextafter nexttoward pow
remainder remquo rint round scalbln scalbn sin sinh sqrt tan tanh tgamma trunc j0 j1 jn y0 y1
yn gamma isfinite isnan isinf signbit fpclassify abs labs div free malloc calloc exit memcpy
memset isnormal isgreater isgreaterequal isless islessequal islessgreater isunordered float_t
double_t signgam math_errhandling MATH_ERRNO MATH_ERREXCEPT FP_NAN FP_INFINITE FP_ZERO
FP_NORMAL FP_SUBNORMAL FP_FAST_FMA FP_ILOGB0 FP_ILOGBNAN HUGE_VALF HUGE_VALL M_PI M_E NULL
EOF size_t""".split())


def c_string_literal(text) -> str:
    """A C string literal holding ``text`` (its UTF-8 bytes) exactly: every byte outside
    printable ASCII, and the quote, the backslash and the question mark (trigraphs), is a
    three-digit octal escape, so nothing in the text can end the literal or the line."""
    out = ['"']
    for b in str(text).encode("utf-8", "surrogatepass"):
        c = chr(b)
        if 0x20 <= b < 0x7F and c not in '"\\?':
            out.append(c)
        else:
            out.append(f"\\{b:03o}")
    out.append('"')
    return "".join(out)


def c_comment(text, limit: int = 200) -> str:
    """Free text made safe inside a ``/* ... */`` comment: one line of printable ASCII
    (anything else as a visible escape), no ``*/`` or ``/*``, no trigraph ``??``."""
    s = str(text).encode("ascii", "backslashreplace").decode("ascii")
    s = "".join(c if 0x20 <= ord(c) < 0x7F else f"\\x{ord(c):02x}" for c in s)
    while "*/" in s or "/*" in s or "??" in s:
        s = s.replace("*/", "* /").replace("/*", "/ *").replace("??", "? ?")
    return s if len(s) <= limit else s[:limit - 3] + "..."


def c_name(name: str) -> str:
    """The C identifier of a model identifier (validated by the parser): unchanged unless it is
    a C keyword, a C library name or in bgc's own ``bgc`` namespace, then ``bgcu_`` + name: a
    name that starts with bgc is itself renamed, so no kept name can equal a renamed one
    (``main`` beside ``m_main``)."""
    if name in _C_KEYWORDS or name in _C_LIBRARY or name.startswith("bgc") or name.startswith("__"):
        return "bgcu_" + name
    return name


def c_sym(sym) -> str:
    """:func:`c_name` of a symbol's text: a plain Symbol's name read directly (``str`` runs
    sympy's printer, about 20 us a call: a large model's C names cost a second that way)."""
    return c_name(sym.name if type(sym) is sp.Symbol else str(sym))


class CPrinter(FastPrinting, C99CodePrinter):
    """C99 printer writing the numpy printer's cheap forms; strict: an unknown function is an
    error, never a comment in the code; each expression printed without sympy's per-call
    setup (:mod:`bgc.backends.fastprint`)."""

    # as in the numpy printer: x/b**2 and x/b**3 must not come out as x/b*b or x/b*b*b
    product_powers = (2, 3)
    # no <math.h> constant macros (M_PI_2, M_SQRT1_2, M_LN2...): they are POSIX, not C99, and
    # a strict -std=c99 build does not declare them; the constants print as numbers
    math_macros: ClassVar[dict] = {}

    def __init__(self, names: dict | None = None):
        super().__init__({"strict": True, "order": "none", "allow_unknown_functions": False})
        self.names = names or {}  # symbols printed as array elements (bgc.lower.reroll)

    def renamed(self, names: dict) -> CPrinter:
        """A printer that prints the symbols of ``names`` as the C text given there (values
        that live in an array, a loop's reads); every other symbol as before."""
        return CPrinter(names) if names else self

    def _print_Symbol(self, expr):
        got = self.names.get(expr)
        return got if got is not None else c_name(expr.name)

    def _print_Dummy(self, expr):  # a loop's read (bgc.lower.reroll): its C text in names
        got = self.names.get(expr)
        return got if got is not None else super()._print_Dummy(expr)

    def _print_Float(self, expr):
        v = float(expr)
        if v != v or v in (float("inf"), float("-inf")):
            raise ValueError(f"non-finite constant {v} in the equations")
        return repr(v)

    def _print_Rational(self, expr):
        return f"({float(expr.p)!r}/{float(expr.q)!r})"

    def _print_Integer(self, expr):
        return integer_text(int(expr))

    def _print_NumberSymbol(self, expr):
        return repr(float(expr))

    _print_Pi = _print_Exp1 = _print_NumberSymbol

    def _print_Pow(self, expr, rational=False):
        b, e = expr.as_base_exp()
        base = self.parenthesize(b, PRECEDENCE["Pow"])
        if e.is_Integer:
            n = int(e)
            if n == -1:
                return f"1.0/{base}"
            if n == -2:
                return f"1.0/({base}*{base})"
            if n == 2:
                return f"{base}*{base}"
            if n == 3:
                return f"{base}*{base}*{base}"
            return f"pow({self._print(b)}, {n}.0)"
        if e == sp.Rational(1, 2):
            return f"sqrt({self._print(b)})"
        if e == -sp.Rational(1, 2):
            return f"1.0/sqrt({self._print(b)})"
        return f"pow({self._print(b)}, {self._print(e)})"

    def _print_Piecewise(self, expr):
        *pairs, last = expr.args
        if last.cond != sp.true:
            raise ValueError("Piecewise without a default branch")
        out = self._print(last.expr)
        for e, c in reversed(pairs):
            out = f"(({self._print(c)}) ? ({self._print(e)}) : ({out}))"
        return out

    def _print_Heaviside(self, expr):
        return f"(({self._print(expr.args[0])}) >= 0 ? 1.0 : 0.0)"

    def _print_LimExp(self, expr):  # only inside a Newton loop (templates/c/newton.c.j2)
        return f"bgc_lexp({self._print(expr.args[0])})"

    def _print_SlopeExp(self, expr):
        return f"bgc_sexp({self._print(expr.args[0])})"

    def _print_Relational(self, expr):
        op = {"<": "<", "<=": "<=", ">": ">", ">=": ">="}.get(expr.rel_op)
        if op is None:
            return super()._print_Relational(expr)
        return f"({self._print(expr.lhs)} {op} {self._print(expr.rhs)})"

    def _print_sign(self, expr):
        a = self._print(expr.args[0])
        return f"((double)(({a}) > 0) - (double)(({a}) < 0))"

    def _print_LinSolveEntry(self, expr):
        # component i of a numeric solve's result (a local array, or the scratch array)
        return f"{self._print(expr.args[0])}[{int(expr.args[1])}]"

    def _print_LinSolve(self, expr):  # printed as its own line by _parts, never inline
        raise ValueError("internal: a numeric linear solve inside an expression")

    _print_NewtonSolve = _print_LinSolve

    def _print_Min(self, expr):
        return self._minmax(expr, "fmin")

    def _print_Max(self, expr):
        return self._minmax(expr, "fmax")

    def _minmax(self, expr, fn):
        args = [self._print(a) for a in expr.args]
        out = args[0]
        for a in args[1:]:
            out = f"{fn}({out}, {a})"
        return out
