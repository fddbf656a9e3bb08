"""Stage 5c: the lowered equations (:mod:`bgc.lower`) -> C99 sources and a Python wrapper.

The C backend prints the same lowered functions as the numpy module (rhs, Jacobian values on
JAC_SPARSITY, outputs, initial state) with a C99 printer that writes the same cheap forms
(``b*b``, ``1/b``, ternaries for Piecewise, ``fmin``/``fmax``). Long bodies are cut into parts
of bounded size, each its own C function, and the parts are spread over several translation
units so that ``gcc -O2`` stays fast and the units build in parallel; values that cross from
one part to a later one travel through a scratch array.

The wrapper module is the numpy module of the same model followed by the C binding
(templates/c/binding.py, copied below its marker): the same public API, with rhs, jacobian,
outputs, initial_state and simulate (Rodas4, Radau) running in the shared library.

Text from the model reaches the C sources only through :func:`c_string_literal` (string
literals) and :func:`c_comment` (comments); identifiers are the model's validated identifiers,
renamed where they would collide with C keywords or the C library.
"""
from __future__ import annotations

import functools
import hashlib
from dataclasses import dataclass

import jinja2
import sympy as sp
from sympy.printing.c import C99CodePrinter
from sympy.printing.precedence import PRECEDENCE

from . import __version__
from .emit import _loader, comment as py_comment, lit
from .skeleton import WRAPPER_MARK, binding_source, check_wrapper  # noqa: F401
from .equations import T
from .lower import Lowered

_TEMPLATES = "c"
#: lines (definitions plus results) per generated C function, and functions per unit
PART_LINES = 250
UNIT_PARTS = 4

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
    a C keyword, a C library name or in bgc's own ``bgc`` namespace."""
    if name in _C_KEYWORDS or name in _C_LIBRARY or name.startswith("bgc") or name.startswith("__"):
        return "m_" + name
    return name


class CPrinter(C99CodePrinter):
    """C99 printer writing the numpy printer's cheap forms; strict: an unknown function is an
    error, never a comment in the code."""

    def __init__(self):
        super().__init__({"strict": True, "order": "none", "allow_unknown_functions": False})

    def _print_Symbol(self, expr):
        return c_name(expr.name)

    def _print_Float(self, expr):
        v = float(expr)
        if v != v or v in (float("inf"), float("-inf")):
            raise ValueError(f"non-finite constant {v} in the equations")
        return repr(v)

    def _print_Rational(self, expr):
        return f"({float(expr.p)!r}/{float(expr.q)!r})"

    def _print_Integer(self, expr):
        return str(int(expr))

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

    def _print_Mul(self, expr):
        # as in the numpy printer: x/b**2 must not come out as x/b*b
        s = super()._print_Mul(expr)
        den = [f for f in sp.Mul.make_args(expr) if f.is_commutative and f.is_Pow
               and f.exp.is_Rational and f.exp.is_negative]
        if len(den) == 1 and den[0].exp in (-2, -3):
            d = self._print(sp.Pow(den[0].base, -den[0].exp, evaluate=False))
            if s.endswith("/" + d):
                s = f"{s[:-len(d)]}({d})"
        return s

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

    def _print_Relational(self, expr):
        op = {"<": "<", "<=": "<=", ">": ">", ">=": ">="}.get(expr.rel_op)
        if op is None:
            return super()._print_Relational(expr)
        return f"({self._print(expr.lhs)} {op} {self._print(expr.rhs)})"

    def _print_sign(self, expr):
        a = self._print(expr.args[0])
        return f"((double)(({a}) > 0) - (double)(({a}) < 0))"

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


# ---------------------------------------------------------------------------------------------
# Parts: a function body cut into C functions of bounded size

@dataclass(frozen=True)
class CLine:
    target: str  # a local (const double NAME = ...) or an output slot ("" then)
    code: str
    comment: str = ""
    out: int = -1  # result slot, or -1
    export: int = -1  # scratch slot the value is stored to for later parts, or -1


@dataclass(frozen=True)
class Part:
    name: str  # C function name
    params: tuple[tuple[str, int], ...]  # (C name, index into p)
    inputs: tuple[tuple[str, str], ...]  # (C name, C expression of t and parameters)
    states: tuple[tuple[str, int], ...]  # (C name, index into x)
    imports: tuple[tuple[str, int], ...]  # (C name, scratch slot)
    lines: tuple[CLine, ...]


@dataclass(frozen=True)
class CFunction:
    name: str  # rhs, jac, outputs, init
    parts: tuple[Part, ...]
    nscratch: int
    nout: int
    uses_t: bool


def _parts(name: str, fn, printer: CPrinter, ctx: "_Ctx", limit: int = PART_LINES
           ) -> CFunction:
    items = [(ln.target, ln.expr, ln.comment, -1) for ln in fn.lines]
    items += [(None, r, "", k) for k, (_, r) in enumerate(fn.results)]
    defined_in: dict = {}  # symbol -> part index
    chunks = [items[i:i + limit] for i in range(0, len(items), limit)] or [[]]
    for ci, chunk in enumerate(chunks):
        for tgt, _, _, _ in chunk:
            if tgt is not None:
                defined_in[tgt] = ci
    frees = [[e.free_symbols for _, e, _, _ in chunk] for chunk in chunks]
    # which definitions a later part needs: those get a scratch slot
    slots: dict = {}
    for ci, chunk in enumerate(chunks):
        for fs in frees[ci]:
            for s in fs:
                if s in defined_in and defined_in[s] < ci and s not in slots:
                    slots[s] = None
    order = sorted(slots, key=lambda s: (defined_in[s], str(s)))
    slots = {s: k for k, s in enumerate(order)}
    parts = []
    uses_t = False
    for ci, chunk in enumerate(chunks):
        used = set().union(*frees[ci]) if frees[ci] else set()
        # inputs used (directly); their defaults bring t and parameters
        inputs = [s for s in ctx.input_syms if s in used]
        need_p = set(used)
        for s in inputs:
            need_p |= ctx.input_default[s].free_symbols
        uses_t = uses_t or T in need_p
        params = tuple((c_name(str(s)), k) for k, s in enumerate(ctx.param_syms) if s in need_p)
        ins = tuple((c_name(str(s)), printer.doprint(ctx.input_default[s])) for s in inputs)
        states = tuple((c_name(str(s)), k) for k, s in enumerate(ctx.state_syms) if s in used)
        imports = tuple((c_name(str(s)), slots[s]) for s in order
                        if s in used and defined_in[s] < ci)
        lines = []
        for tgt, e, why, k in chunk:
            code = printer.doprint(e)
            if tgt is None:
                lines.append(CLine("", code, "", k))
            else:
                lines.append(CLine(c_name(str(tgt)), code, why, -1, slots.get(tgt, -1)))
        parts.append(Part(f"bgcm_{name}_{ci}", params, ins, states, imports, tuple(lines)))
    return CFunction(name, tuple(parts), len(slots), len(fn.results), uses_t)


class _Ctx:
    def __init__(self, low: Lowered):
        eq = low.eq
        self.param_syms = [s for pv in eq.params for s in pv.symbols] + [d.target
                                                                          for d in low.derived]
        self.state_syms = [sv.symbol for sv in eq.states]
        self.input_syms = [s for iv in eq.inputs for s in iv.symbols]
        self.input_default = {s: d for iv in eq.inputs for s, d in zip(iv.symbols, iv.default)}


@dataclass(frozen=True)
class CSources:
    """The generated C sources (file name -> text) and what the wrapper needs to know."""
    files: tuple[tuple[str, str], ...]
    digest: str  # sha256 of the sources: the wrapper checks the library it loads against it

    def __getitem__(self, name):
        return dict(self.files)[name]


def render_c(low: Lowered, *, source: str, source_hash: str, description: str = "",
             header_notes: tuple[str, ...] = ()) -> CSources:
    """The model's C sources: model.c (drivers, pattern, entry points) and the parts."""
    eq = low.eq
    printer = CPrinter()
    ctx = _Ctx(low)
    fns = {name: _parts(name, fn, printer, ctx) for name, fn in
           (("rhs", low.rhs), ("jac", low.jac), ("outputs", low.outs), ("init", low.init))}
    names = [c_name(str(s)) for s in ctx.param_syms + ctx.state_syms + ctx.input_syms]
    names += [c_name(str(a.symbol)) for a in eq.assignments + eq.jac_assignments]
    for nm in names:
        assert nm.isidentifier() and nm.isascii(), nm
    if len(set(c_name(str(s)) for s in ctx.param_syms + ctx.state_syms + ctx.input_syms)) != \
            len(ctx.param_syms) + len(ctx.state_syms) + len(ctx.input_syms):
        raise AssertionError("two model identifiers map to one C name")
    all_parts = [p for f in fns.values() for p in f.parts]
    units = [all_parts[i:i + UNIT_PARTS] for i in range(0, len(all_parts), UNIT_PARTS)]
    env = _env()
    common = dict(name=eq.name, version=__version__, source=source, source_hash=source_hash,
                  description=description, notes=list(header_notes) + list(eq.loops))
    files = []
    for k, unit in enumerate(units):
        files.append((f"model_part{k}.c", env.get_template("c/part.c.j2").render(
            parts=unit, unit=k, **common)))
    olens = [len(vals) for _, _, vals in eq.outputs]
    lu_plan = _lu_plan(len(eq.states), low.jac_keys)
    main = env.get_template("c/model.c.j2").render(
        lu_plan=lu_plan,
        fns=fns, n=len(eq.states), np=len(ctx.param_syms), jac_keys=low.jac_keys,
        states=[sv.name for sv in eq.states], outputs=[o[0] for o in eq.outputs],
        nout=sum(olens), all_parts=all_parts,
        has_t=int(fns["rhs"].uses_t or fns["jac"].uses_t), **common)
    files.insert(0, ("model.c", main))
    h = hashlib.sha256()
    for fname, text in files:
        h.update(fname.encode() + b"\0" + text.encode() + b"\0")
    digest = h.hexdigest()[:32]
    # the digest is compiled into the library: the wrapper refuses a library of other sources
    files = [(f, t.replace("@BGC_DIGEST@", digest)) for f, t in files]
    return CSources(tuple(files), digest)


def _lu_plan(n: int, keys) -> str:
    """The C text of a sparse LU plan for the iteration matrices, when bgc.sparse_lu (the C
    runtime's planner) has one that beats the dense LU; "" for the dense LU."""
    try:
        from .sparse_lu import make_plan, plan_c, prefer_sparse
    except ImportError:
        return ""
    if not keys:
        return ""
    plan = make_plan(n, [k[0] for k in keys], [k[1] for k in keys])
    return plan_c(plan, "bgcm_lu_plan") if prefer_sparse(plan) else ""


@functools.lru_cache(maxsize=None)
def _env():
    env = jinja2.Environment(loader=_loader(), keep_trailing_newline=True, trim_blocks=True,
                             lstrip_blocks=True, undefined=jinja2.StrictUndefined,
                             autoescape=False)
    env.filters.update(cstr=c_string_literal, ccomment=c_comment, lit=lit, comment=py_comment)
    return env


def render_wrapper(low: Lowered, numpy_source: str, csrc: CSources, lib_name: str) -> str:
    """The wrapper module: the numpy module, then the C part (constants and the binding)."""
    eq = low.eq
    olens = [len(vals) for _, _, vals in eq.outputs]
    text = _env().get_template("c/wrapper.py.j2").render(
        numpy_source=numpy_source.rstrip("\n"), mark=WRAPPER_MARK.rstrip("\n"),
        lib_name=lib_name, digest=csrc.digest,
        np=len(_Ctx(low).param_syms),
        nnz=len(low.jac_keys), nout=sum(olens), binding=binding_source())
    check_wrapper(text)
    return text
