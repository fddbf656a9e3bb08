"""Stage 5c: the lowered equations (:mod:`bgc.lower.ir`) -> C99 sources and a Python wrapper.

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

from bgc.backends.numpy.printer import _loader, lit
from bgc.backends.numpy.printer import comment as py_comment
from bgc.backends.skeleton import WRAPPER_MARK, binding_source, check_wrapper  # noqa: F401
from bgc.base import __version__
from bgc.base.errors import ModelError
from bgc.core.equations import T
from bgc.lower.ir import Lowered

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
    a C keyword, a C library name or in bgc's own ``bgc`` namespace, then ``bgcu_`` + name: a
    name that starts with bgc is itself renamed, so no kept name can equal a renamed one
    (``main`` beside ``m_main``)."""
    if name in _C_KEYWORDS or name in _C_LIBRARY or name.startswith("bgc") or name.startswith("__"):
        return "bgcu_" + name
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


# ---------------------------------------------------------------------------------------------
# Parts: a function body cut into C functions of bounded size

@dataclass(frozen=True)
class CLine:
    target: str  # a local (const double NAME = ...) or an output slot ("" then)
    code: str
    comment: str = ""
    out: int = -1  # result slot, or -1
    export: int = -1  # scratch slot the value is stored to for later parts, or -1
    # numeric solves: kind "linsolve" (x = A^-1 b: a = A's entries row-major, b = b's),
    # "newton" (code: the loop function's call arguments; ws: its warm start's offset in the
    # instance workspace) or "alias" (another solve's result under a second name); size: the
    # result's length; fail: the failure code the part returns
    kind: str = ""
    size: int = 0
    a: tuple = ()
    b: tuple = ()
    ws: int = 0
    fail: int = 0
    lu: str = ""  # linsolve: the LU (a local of the part) it solves with
    factor: bool = False  # linsolve: this line factors A into lu (the first with this A)


@dataclass(frozen=True)
class Part:
    name: str  # C function name
    params: tuple[tuple[str, int], ...]  # (C name, index into p)
    inputs: tuple[tuple[str, str], ...]  # (C name, C expression of t and parameters)
    states: tuple[tuple[str, int], ...]  # (C name, index into x)
    imports: tuple[tuple[str, int], ...]  # (C name, scratch slot)
    lines: tuple[CLine, ...]
    vimports: tuple[tuple[str, int], ...] = ()  # solve results: (C name, first scratch slot)
    tables: tuple[tuple[str, int, int], ...] = ()  # table inputs: (C name, table, fail code)
    fallible: bool = False  # holds a numeric solve or a table that may fail: returns int
    newton: bool = False  # calls a Newton loop's function


@dataclass(frozen=True)
class CFunction:
    name: str  # rhs, jac, outputs, init
    parts: tuple[Part, ...]
    nscratch: int
    nout: int
    uses_t: bool


def _parts(name: str, fn, printer: CPrinter, ctx: "_Ctx", limit: int = PART_LINES
           ) -> CFunction:
    from bgc.core.eqtypes import LinSolve, NewtonSolve

    items = [(ln.target, ln.expr, ln.comment, -1) for ln in fn.lines]
    items += [(None, r, "", k) for k, (_, r) in enumerate(fn.results)]
    # the results of numeric solves are arrays: their lengths
    vsize: dict = {}
    for tgt, e, _, _ in items:
        if isinstance(e, LinSolve):
            vsize[tgt] = int(e.args[0])
        elif isinstance(e, NewtonSolve):
            vsize[tgt] = len(ctx.newton[int(e.args[0])].tear)
        elif isinstance(e, sp.Symbol) and e in vsize:
            vsize[tgt] = vsize[e]
    defined_in: dict = {}  # symbol -> part index
    chunks = [items[i:i + limit] for i in range(0, len(items), limit)] or [[]]
    for ci, chunk in enumerate(chunks):
        for tgt, _, _, _ in chunk:
            if tgt is not None:
                defined_in[tgt] = ci
    frees = [[e.free_symbols for _, e, _, _ in chunk] for chunk in chunks]
    # which definitions a later part needs: those get a scratch slot (a solve: one per entry)
    slots: dict = {}
    for ci, chunk in enumerate(chunks):
        for fs in frees[ci]:
            for s in fs:
                if s in defined_in and defined_in[s] < ci and s not in slots:
                    slots[s] = None
    order = sorted(slots, key=lambda s: (defined_in[s], str(s)))
    slots, nslot = {}, 0
    for s in order:
        slots[s] = nslot
        nslot += vsize.get(s, 1)
    parts = []
    uses_t = False
    for ci, chunk in enumerate(chunks):
        used = set().union(*frees[ci]) if frees[ci] else set()
        # inputs used (directly); their defaults bring t and parameters; a table input is
        # its table's function of t
        inputs = [s for s in ctx.input_syms if s in used and s not in ctx.table_of]
        tabs = tuple((c_name(str(s)), ctx.table_of[s], ctx.table_fail(ctx.table_of[s]))
                     for s in ctx.input_syms if s in used and s in ctx.table_of)
        need_p = set(used)
        for s in inputs:
            need_p |= ctx.input_default[s].free_symbols
        uses_t = uses_t or T in need_p or bool(tabs)
        params = tuple((c_name(str(s)), k) for k, s in enumerate(ctx.param_syms) if s in need_p)
        ins = tuple((c_name(str(s)), printer.doprint(ctx.input_default[s])) for s in inputs)
        states = tuple((c_name(str(s)), k) for k, s in enumerate(ctx.state_syms) if s in used)
        imports = tuple((c_name(str(s)), slots[s]) for s in order
                        if s in used and defined_in[s] < ci and s not in vsize)
        vimports = tuple((c_name(str(s)), slots[s]) for s in order
                         if s in used and defined_in[s] < ci and s in vsize)
        lines = []
        fallible, newton = any(f for _, _, f in tabs), False
        lus: dict = {}  # A's entries -> the part's LU of it (one factorisation per matrix)
        for tgt, e, why, k in chunk:
            if tgt is not None and tgt in vsize:
                lines.append(_solve_line(tgt, e, why, slots.get(tgt, -1), vsize[tgt], printer,
                                         ctx, lus))
                fallible = True
                newton = newton or isinstance(e, NewtonSolve)
                continue
            code = printer.doprint(e)
            if tgt is None:
                lines.append(CLine("", code, "", k))
            else:
                lines.append(CLine(c_name(str(tgt)), code, why, -1, slots.get(tgt, -1)))
        parts.append(Part(f"bgcm_{name}_{ci}", params, ins, states, imports, tuple(lines),
                          vimports, tabs, fallible, newton))
    return CFunction(name, tuple(parts), nslot, len(fn.results), uses_t)


def _solve_line(tgt, e, why, export, n, printer, ctx, lus: dict) -> CLine:
    """The C line of a numeric solve's result (an array of n values). Solves with the same
    matrix in one part (the Jacobian's columns through a solve: d(A^-1 b) = A^-1 (db - dA x))
    share one LU."""
    from bgc.core.eqtypes import LinSolve, NewtonSolve

    target = c_name(str(tgt))
    if isinstance(e, LinSolve):
        a = tuple(printer.doprint(v) for v in e.args[1:1 + n * n])
        b = tuple(printer.doprint(v) for v in e.args[1 + n * n:])
        factor = a not in lus
        if factor:
            lus[a] = f"bgc_lu{len(lus)}"
        return CLine(target, "", why, -1, export, "linsolve", n, a if factor else (), b, 0,
                     ctx.fail_code(ctx.linsolve_message(e)), lus[a], factor)
    if isinstance(e, NewtonSolve):
        k = int(e.args[0])
        args = ", ".join(printer.doprint(v) for v in e.args[1:])
        return CLine(target, f"bgcm_newton_{k}({args}{', ' if args else ''}"
                             f"bgc_ws ? bgc_ws + {ctx.newton_ws[k]} : NULL, {target})",
                     why, -1, export, "newton", n, (), (), ctx.newton_ws[k],
                     ctx.fail_code(ctx.newton_message(k)))
    return CLine(target, c_name(str(e)), why, -1, export, "alias", n)


class _Ctx:
    def __init__(self, low: Lowered):
        eq = low.eq
        self.param_syms = [s for pv in eq.params for s in pv.symbols] + [d.target
                                                                          for d in low.derived]
        self.state_syms = [sv.symbol for sv in eq.states]
        self.input_syms = [s for iv in eq.inputs for s in iv.symbols]
        self.input_default = {s: d for iv in eq.inputs for s, d in zip(iv.symbols, iv.default)}
        # numeric solves: Newton loops (their warm starts' offsets in the instance
        # workspace) and the failure codes the model functions return (1-based, the index
        # of their message in fail_messages)
        self.newton = tuple(getattr(eq, "newton", ()))
        self.newton_ws, off = [], 0
        for nl in self.newton:
            self.newton_ws.append(off)
            off += len(nl.tear)
        self.nws = off
        self.fail_messages: list[str] = []
        self._eq = eq
        self._lin_msgs = None
        # table inputs: input symbol -> table index; the tables (bgc.format.tables.Table, input name)
        self.tables = [(iv.table, iv.name) for iv in eq.inputs
                       if getattr(iv, "table", None) is not None]
        self.table_of = {}
        k = 0
        for iv in eq.inputs:
            if getattr(iv, "table", None) is not None:
                for s in iv.symbols:
                    self.table_of[s] = k
                k += 1

    def table_fail(self, k: int) -> int:
        """The failure code of table k outside its knots (extrapolate: error), else 0."""
        tb, name = self.tables[k]
        if tb.extrapolate != "error":
            return 0
        return self.fail_code(f"input {name!r}: t is outside its table [{tb.t[0]:g}, "
                              f"{tb.t[-1]:g}] (extrapolate: error)")

    def fail_code(self, message: str) -> int:
        if message not in self.fail_messages:
            self.fail_messages.append(message)
        return self.fail_messages.index(message) + 1

    def newton_message(self, k: int) -> str:
        # exactly the numpy module's message (templates/numpy/module.py.j2)
        return self.newton[k].where + " did not converge (Newton, 50 iterations)"

    def linsolve_message(self, e) -> str:
        """What a singular numeric solve says: derivative causality's system (named by its
        unknowns and the elements it runs through), the same system's solves for the
        Jacobian, or a Newton loop's Jacobian at its solution."""
        from bgc.core.eqtypes import LinSolve, LinSolveEntry

        if self._lin_msgs is None:
            eq = self._eq
            tears: dict = {}
            for a in eq.assignments:
                if isinstance(a.expr, LinSolveEntry):
                    tears.setdefault(a.expr.args[0], []).append(str(a.symbol).lstrip("_"))
            self._lin_msgs = {}
            for a in eq.assignments:
                if not isinstance(a.expr, LinSolve):
                    continue
                n = int(a.expr.args[0])
                names = ", ".join(tears.get(a.symbol, ()))
                through = ""
                for note in eq.loops:
                    if f"({names})" in note and ", through " in note:
                        through = " through " + note.split(", through ", 1)[1]
                        break
                self._lin_msgs[tuple(a.expr.args[1:1 + n * n])] = (
                    f"derivative causality: the linear system in {n} unknown(s) ({names})"
                    f"{through} is singular")
        n = int(e.args[0])
        msg = self._lin_msgs.get(tuple(e.args[1:1 + n * n]))
        if msg is not None:
            return msg
        loops = "; ".join(nl.where for nl in self.newton)
        return ("the Jacobian through a nonlinear algebraic loop: the loop's linear system "
                f"(I - dg/dz) is singular at its solution ({loops})")


@dataclass(frozen=True)
class CSources:
    """The generated C sources (file name -> text) and what the wrapper needs to know."""
    files: tuple[tuple[str, str], ...]
    digest: str  # sha256 of the sources: the wrapper checks the library it loads against it

    def __getitem__(self, name):
        return dict(self.files)[name]


class CUnsupported(ModelError):
    """The model needs something the C printer does not write yet (see :func:`unsupported`)."""


def has_solves(eq) -> bool:
    """Does the model solve equations numerically (numeric linear solves of derivative
    causality, Newton loops of nonlinear algebraic loops)?"""
    from bgc.core.eqtypes import LinSolve, LinSolveEntry, NewtonSolve

    kinds = (LinSolve, LinSolveEntry, NewtonSolve)
    return bool(getattr(eq, "newton", ())) or any(
        isinstance(a.expr, kinds) for a in eq.assignments + eq.jac_assignments)


def unsupported(eq) -> None:
    """What the C backend cannot print is one clear error, never wrong code. Today it prints
    everything bgc generates: numeric linear solves (a dense LU per instance), Newton loops (a
    C function per loop) and table inputs (the data as arrays, the numpy module's
    interpolation); the check stays for what may come."""
    what: list[str] = []
    if what:
        raise CUnsupported(None, f"model {eq.name!r}: the C backend does not support "
                               f"{' and '.join(what)} yet; use the numpy backend "
                               "(--backend numpy, or target numpy)")


def render_c(low: Lowered, *, source: str, source_hash: str, description: str = "",
             header_notes: tuple[str, ...] = ()) -> CSources:
    """The model's C sources: model.c (drivers, pattern, entry points) and the parts."""
    eq = low.eq
    unsupported(eq)
    printer = CPrinter()
    ctx = _Ctx(low)
    fns = {name: _parts(name, fn, printer, ctx, PART_LINES) for name, fn in
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
            parts=unit, unit=k, newton=_newton_protos(ctx), ntables=len(ctx.tables),
            **common)))
    if ctx.tables:
        files.append(("model_tables.c", env.get_template("c/tables.c.j2").render(
            tables=_tables(ctx), **common)))
    if ctx.newton:
        files.append(("model_newton.c", env.get_template("c/newton.c.j2").render(
            loops=_newton_loops(ctx, printer), **common)))
    olens = [len(vals) for _, _, vals in eq.outputs]
    lu_plan = _lu_plan(len(eq.states), low.jac_keys)
    main = env.get_template("c/model.c.j2").render(
        lu_plan=lu_plan, nws=ctx.nws, fail_messages=ctx.fail_messages,
        value_errors=[ctx.table_fail(k) for k in range(len(ctx.tables))
                      if ctx.table_fail(k)],
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


def _tables(ctx) -> list[dict]:
    """The table inputs as the template prints them: numbers only (float literals)."""
    out = []
    for tb, name in ctx.tables:
        out.append({"name": name, "n": len(tb.t), "t": [repr(float(v)) for v in tb.t],
                    "v": [repr(float(v)) for v in tb.v], "interp": tb.interp,
                    "error": tb.extrapolate == "error"})
    return out


def _newton_protos(ctx) -> list[str]:
    """The prototypes of the Newton loops' functions (model_newton.c)."""
    out = []
    for k, nl in enumerate(ctx.newton):
        args = "".join(f"double {c_name(str(a))}, " for a in nl.args)
        out.append(f"int bgcm_newton_{k}({args}double *restrict bgc_warm, "
                   "double *restrict bgc_z)")
    return out


def _newton_loops(ctx, printer) -> list[dict]:
    """The Newton loops as the template prints them: one C function each."""
    protos = _newton_protos(ctx)
    loops = []
    for k, nl in enumerate(ctx.newton):
        loops.append({
            "proto": protos[k], "n": len(nl.tear), "where": nl.where,
            "tear": [c_name(str(t)) for t in nl.tear],
            "body": [(c_name(str(sym)), printer.doprint(e)) for sym, e in nl.body],
            "residual": [printer.doprint(e) for e in nl.residual],
            "jac": [printer.doprint(e) for e in nl.jac]})
    return loops


def _lu_plan(n: int, keys) -> str:
    """The C text of a sparse LU plan for the iteration matrices, when bgc.lower.sparse_lu (the C
    runtime's planner) has one that beats the dense LU; "" for the dense LU."""
    try:
        from bgc.lower.sparse_lu import make_plan, plan_c, prefer_sparse
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
        lib_name=lib_name, digest=csrc.digest, nws=_Ctx(low).nws,
        np=len(_Ctx(low).param_syms),
        nnz=len(low.jac_keys), nout=sum(olens), binding=binding_source())
    check_wrapper(text)
    return text
