"""Stage 5b: the lowered equations (:mod:`bgc.lower.ir`) -> one standalone numpy module, through
the jinja2 templates.

The expression printer is sympy's ``NumPyPrinter`` (strict: an unknown function is an error,
never silently printed) with a few overrides for speed and readability; the generated import
block lists what the printer actually used. Pruning, CSE and scheduling happen before, in the
backend-neutral lowering that the C printer (:mod:`bgc.backends.c.printer`) shares.
"""
from __future__ import annotations

import ast
import contextlib
import functools
import keyword
import sys
from dataclasses import dataclass
from pathlib import Path

import jinja2
import sympy as sp
from sympy.printing.numpy import NumPyPrinter

from bgc.backends.fastprint import FastPrinting, integer_text
from bgc.backends.numpy.events import events_part
from bgc.backends.numpy.rolled import Tables, rolled_function
from bgc.backends.skeleton import (  # noqa: F401 (re-exported)
    ALLOWED_IMPORTS,
    SkeletonError,
    check_skeleton,
    events_runtime_source,
    runtime_source,
)
from bgc.base import __version__
from bgc.base.errors import oneline
from bgc.base.paths import templates_dir
from bgc.core.eqtypes import Equations, T
from bgc.core.forward import linear_labels
from bgc.core.signals import input_periods
from bgc.lower import ir as lower
from bgc.lower.newton import guarded

_IDENT_OK = set("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_")
_TEMPLATES = "numpy"  # this backend's folder in templates/


# ---------------------------------------------------------------------------------------------
# The one door for text: every string from a model or scene reaches generated code through
# exactly one of these three functions, and nowhere else.

def lit(value) -> str:
    """A Python literal for a value from the model: str (escaped by ``repr``: quotes,
    backslashes, control characters, line separators and lone surrogates all come out as
    escapes), int, float, bool, None, or tuples/lists of them. Anything else is a bug."""
    if isinstance(value, (list, tuple)):
        return ("[" if isinstance(value, list) else "(") + ", ".join(lit(v) for v in value) + (
            "]" if isinstance(value, list) else ("," if len(value) == 1 else "") + ")")
    if value is None or isinstance(value, (bool, int, str)):
        out = repr(value)
    elif isinstance(value, float):
        out = repr(value)
        if out in ("inf", "-inf", "nan"):
            raise ValueError(f"non-finite constant {out} cannot be written as a literal")
    else:
        raise TypeError(f"no literal for {type(value).__name__}")
    return out


def comment(text) -> str:
    """Text for a ``# comment``: one line (see :func:`oneline`)."""
    return oneline(text, 300)


def docstring(text: str) -> str:
    """A triple-quoted literal holding ``text`` exactly: backslashes, a quote that could end
    the literal and every unprintable character are escaped; line breaks stay line breaks."""
    out = []
    for i, c in enumerate(text):
        if c == "\\":
            out.append("\\\\")
        elif c == '"' and (i + 1 == len(text) or text[i + 1] == '"'):
            out.append('\\"')
        elif c == "\n" or c.isprintable():
            out.append(c)
        else:
            out.append(repr(c)[1:-1])
    s = '"""' + "".join(out) + '"""'
    if ast.literal_eval(s) != text:  # the literal must mean exactly the text
        raise AssertionError("docstring escaping failed")
    return s


# numpy's names for functions whose array-API standard name differs (numpy >= 2 has both)
_STANDARD_NAMES = {"arcsin": "asin", "arccos": "acos", "arctan": "atan", "arctan2": "atan2",
                   "arcsinh": "asinh", "arccosh": "acosh", "arctanh": "atanh", "power": "pow",
                   "absolute": "abs", "amax": "max", "amin": "min", "conjugate": "conj"}
# names of the array API standard (2023.12) the printer may emit: elementwise functions,
# where, and the constants
_STANDARD = frozenset("""abs acos acosh asin asinh atan atan2 atanh ceil clip conj copysign
    cos cosh exp expm1 floor hypot imag isfinite isinf isnan log log1p log2 log10 logaddexp
    logical_and logical_not logical_or logical_xor maximum minimum nextafter pow real
    remainder round sign signbit sin sinh sqrt square tan tanh trunc where max min sum prod
    pi e inf nan""".split())


class BgcPrinter(FastPrinting, NumPyPrinter):
    """NumPyPrinter writing the array API's functions as ``xp.`` (the namespace of the
    inputs), numpy's others as ``np.``, and cheap forms of common operations; each expression
    printed without sympy's per-call setup (:mod:`bgc.backends.fastprint`)."""

    # _print_Pow writes b**2 as the product b*b, so x/b**2 would come out as x/b*b (= x):
    # that lone denominator is parenthesised
    product_powers = (2,)

    def __init__(self):
        # order="none": print terms in sympy's canonical argument order (deterministic, and
        # far cheaper than sorting every sum for display)
        super().__init__({"fully_qualified_modules": True, "strict": True, "order": "none",
                          "allow_unknown_functions": False})

    def _module_format(self, fqn, register=True):
        if register:
            parts = fqn.split(".")
            self.module_imports[".".join(parts[:-1])].add(parts[-1])
        if fqn.startswith("numpy."):
            name = fqn[len("numpy."):]
            name = _STANDARD_NAMES.get(name, name)
            # the array API standard's functions through the namespace xp (numpy itself for
            # numpy inputs, else the inputs' own, see templates/numpy/runtime.py); anything
            # else stays numpy's
            return ("xp." if name in _STANDARD else "np.") + name
        return fqn

    def _print_Pow(self, expr, rational=False):
        b, e = expr.as_base_exp()
        if e.is_Integer:
            n = int(e)
            base = self.parenthesize(b, sp.printing.precedence.PRECEDENCE["Pow"])
            if n == -1:
                return f"1/{base}"
            if n < 0:
                return f"{base}**({n})" if n != -2 else f"1/({base}*{base})"
            if n == 2:
                return f"{base}*{base}"
        if e == sp.Rational(1, 2):
            return f"{self._module_format('numpy.sqrt')}({self._print(b)})"
        if e == -sp.Rational(1, 2):
            return f"1/{self._module_format('numpy.sqrt')}({self._print(b)})"
        return super()._print_Pow(expr, rational=rational)

    def _print_Piecewise(self, expr):
        # where(c0, a0, where(c1, a1, ... default))
        *pairs, last = expr.args
        if last.cond != sp.true:
            return super()._print_Piecewise(expr)
        out = self._print(last.expr)
        w = self._module_format("numpy.where")
        for e, c in reversed(pairs):
            out = f"{w}({self._print(c)}, {self._print(e)}, {out})"
        return out

    def _print_Heaviside(self, expr):
        arg = self._print(expr.args[0])
        w = self._module_format("numpy.where")
        return f"{w}({arg} >= 0, 1.0, 0.0)"

    def _print_Relational(self, expr):
        op = {"<": "<", "<=": "<=", ">": ">", ">=": ">="}.get(expr.rel_op)
        if op is None:
            return super()._print_Relational(expr)
        return f"({self._print(expr.lhs)} {op} {self._print(expr.rhs)})"

    def _print_Min(self, expr):
        return self._minmax(expr, "numpy.minimum")

    def _print_Max(self, expr):
        return self._minmax(expr, "numpy.maximum")

    def _minmax(self, expr, fn):
        f = self._module_format(fn)
        args = [self._print(a) for a in expr.args]
        out = args[0]
        for a in args[1:]:
            out = f"{f}({out}, {a})"
        return out

    def _print_LinSolve(self, expr):
        # x = A^-1 b, batched (derivative causality's linear system, too large for symbols)
        n = int(expr.args[0])
        a = ", ".join(self._print(v) for v in expr.args[1:1 + n * n])
        b = ", ".join(self._print(v) for v in expr.args[1 + n * n:])
        self.uses_linsolve = True
        return f"_bgc_linsolve({n}, ({a},), ({b},))"

    def _print_NewtonSolve(self, expr):
        k = int(expr.args[0])
        # the first argument is the time of the call (the failure message says when)
        return f"_newton_{k}(t, {', '.join(self._print(a) for a in expr.args[1:])})"

    def _print_LimExp(self, expr):
        return f"_bgc_lexp({self._print(expr.args[0])})"

    def _print_SlopeExp(self, expr):
        return f"_bgc_sexp({self._print(expr.args[0])})"

    def _print_LinSolveEntry(self, expr):
        return f"{self._print(expr.args[0])}[{int(expr.args[1])}]"

    def _print_Float(self, expr):
        return repr(float(expr))

    def _print_Integer(self, expr):
        return integer_text(int(expr))


@dataclass(frozen=True)
class Line:
    target: str
    code: str
    comment: str = ""


@dataclass(frozen=True)
class Function:
    params: tuple[str, ...]  # parameter identifiers the body uses
    inputs: tuple[str, ...]
    states: tuple[str, ...]
    lines: tuple[Line, ...]
    results: tuple[tuple[object, str], ...]  # (key, code)
    ops: int  # operation count after CSE
    rolled: bool = False  # vectorised (bgc.backends.numpy.rolled): results are in the lines
    nresults: int = 0  # (rolled) how many results the lines write


def printed(fn: lower.Function, printer) -> Function:
    """One lowered function with its expressions printed (lines first, then results)."""
    lines = tuple(Line(_name(ln.target), printer.doprint(ln.expr), ln.comment)
                  for ln in fn.lines)
    results = tuple((k, printer.doprint(r)) for k, r in fn.results)
    return Function(fn.params, fn.inputs, fn.states, lines, results, fn.ops)


def _name(sym) -> str:
    """str(sym), without making a StrPrinter for a plain Symbol (whose text is its name)."""
    return sym.name if type(sym) is sp.Symbol else str(sym)


def _pyrepr(v) -> str:
    if isinstance(v, tuple):
        if all(len(r) == 1 for r in v):
            return "[" + ", ".join(repr(float(r[0])) for r in v) + "]"
        return "[" + ", ".join("[" + ", ".join(repr(float(c)) for c in r) + "]" for r in v) + "]"
    return repr(float(v))


def render(eq: Equations, *, source: str, source_hash: str, description: str = "",
           header_notes: tuple[str, ...] = (), progress=None,
           output_units: dict | None = None, input_units: dict | None = None,
           lowered=None, equations: bool = True, check: bool = True,
           linear: bool = True) -> str:
    """The numpy module's text; ``lowered`` (the model's :func:`bgc.lower.ir.lower`) is made
    here unless given, so that several backends can share one lowering.

    ``equations=False``: the module without its equation functions (rhs, jacobian, outputs,
    initial_state, input_jacobian, output_jacobian and what only they call): names,
    parameters, metadata and the runtime, for the C backend's wrapper, whose binding supplies
    those functions. ``check=False``: the caller checks the text (the wrapper's one check).
    ``linear=False``: input_jacobian and output_jacobian (so linearize) only raise an error
    that names the fix (a scene's runs never call them; B, C, D cost a fair share of the
    compile)."""
    printer = BgcPrinter()
    low = lowered if lowered is not None else lower.lower(eq, progress)
    fns = _printed_functions(eq, low, printer, progress, equations, linear)
    events = events_part(eq, printer, printed)  # None without events: the module is unchanged
    newton = _newton_parts(eq, printer) if equations or events else []
    if newton:
        printer.uses_linsolve = True
    derived = [Line(_name(a.symbol), printer.doprint(a.expr), a.why) for a in eq.derived]
    inputs, tables = _inputs_and_tables(eq, printer, input_units or {})
    input_params = sorted({str(s) for iv in eq.inputs for d in iv.default for s in d.free_symbols
                           if s != T})
    params = []
    for pv in eq.params:
        params.append({"id": pv.id, "code": pv.code, "shape": pv.shape,
                       "symbols": [str(s) for s in pv.symbols], "default": _pyrepr(pv.value),
                       "unit": pv.unit, "description": pv.description})
    imports = sorted(m for m in printer.module_imports if m and m != "numpy")
    ounits = output_units or {}
    outputs = [{"name": name, "shape": shp, "size": len(vals), "unit": ounits.get(name, "")}
               for name, shp, vals in eq.outputs]
    # does the rhs read t itself? (inputs are signals of t; a law may name t directly)
    rhs_uses_t = bool(eq.inputs) or any(T in ln.expr.free_symbols for ln in low.rhs.lines) \
        or any(T in r.free_symbols for _, r in low.rhs.results)
    text = _environment().get_template(f"{_TEMPLATES}/module.py.j2").render(
        rhs_uses_t=rhs_uses_t, equations=equations, with_inputs=bool(equations or events),
        name=eq.name, version=__version__, source=source, source_hash=source_hash,
        description=description, notes=list(header_notes) + list(eq.loops),
        states=eq.states, params=params, derived=derived, inputs=inputs,
        constraint_states=getattr(eq, "constraint_states", ()),
        constraint_alpha=repr(float(getattr(eq, "constraint_alpha", 0.0))),
        constraint_closed=getattr(eq, "constraint_closed", ()),
        momentum_states=getattr(eq, "momentum_states", ()),
        closure_states=getattr(eq, "closure_states", ()),
        constraint_dropped=getattr(eq, "constraint_dropped", ()),
        input_params=input_params, outputs=outputs, **fns,
        jac_keys=list(low.jac_keys), n=len(eq.states), imports=imports,
        tables=tables, input_periods=input_periods(eq),
        linsolve=getattr(printer, "uses_linsolve", False), newton=newton,
        all_param_symbols=[s for p in params for s in p["symbols"]] + [d.target for d in derived],
        runtime=runtime_source() + (f"\n\n\n{events_runtime_source()}" if events else ""),
        events=events, rolled_any=any(f is not None and f.rolled for f in (
            fns["rhs"], fns["jac"], fns["outs"], fns["init"], fns["ujac"], fns["yjac"])),
    )
    for ident in _identifiers(eq):
        assert ident.isidentifier() and not keyword.iskeyword(ident) and set(ident) <= _IDENT_OK
    if check:
        check_skeleton(text)  # the module's top level is exactly the template's, nothing else
    return text


def _printed_functions(eq: Equations, low, printer, progress, equations: bool,
                       linear: bool = True) -> dict:
    """The template's functions, printed (None each without ``equations``; ujac and yjac None
    without ``linear``), and the labels of the linearisation's inputs and outputs."""
    if not equations:
        ilabels, olabels = linear_labels(eq)
        return dict(rhs=None, jac=None, outs=None, init=None, ujac=None, yjac=None, cons=None,
                    input_labels=ilabels, output_labels=olabels, index_tables=[],
                    jac_index=None, lin_index=None,
                    out_ranges=None)
    tables = Tables()
    rhs, jac, outs = (_maybe_rolled(eq, f, printer, kind, tables)
                      for f, kind in ((low.rhs, "rhs"), (low.jac, "jac"), (low.outs, "outs")))
    big = any(f.rolled for f in (rhs, jac, outs))
    if big:  # a large model: read only the states used
        rhs, jac, outs = (f if f.rolled else _state_reads(f) for f in (rhs, jac, outs))

    def rest(fn, kind):  # the other functions vectorised only in a module of repeated structure
        return _maybe_rolled(eq, fn, printer, kind, tables) if big else printed(fn, printer)
    init = rest(low.init, "init")
    # a vectorised Jacobian's values scattered into the dense matrix at JAC_SPARSITY's entries
    jac_index = (tables.ref(tuple(k[0] for k in low.jac_keys)),
                 tables.ref(tuple(k[1] for k in low.jac_keys))) if jac.rolled else None
    cons = printed(low.cons, printer) if getattr(low, "cons", None) is not None else None
    lin_index = None
    if linear:
        lin = low.linear if low.linear is not None else lower.lower_linear(eq, progress, low.jac)
        ujac, yjac = rest(lin.ujac, "ujac"), rest(lin.yjac, "yjac")
        lin_index = _lin_index(lin, ujac, yjac, tables)
        ilabels, olabels = lin.input_labels, lin.output_labels
    else:
        ujac = yjac = None
        ilabels, olabels = linear_labels(eq)
    return dict(rhs=rhs, jac=jac, outs=outs, init=init, cons=cons, ujac=ujac,
                yjac=yjac, input_labels=ilabels,
                output_labels=olabels, index_tables=tables.literals,
                jac_index=jac_index, lin_index=lin_index,
                out_ranges=_out_ranges(eq, low.outs))


def _lin_index(lin, ujac: Function, yjac: Function, tables) -> dict:
    """Where vectorised B, C, D values go: "B": (rows, columns) of ``_B`` for ``_Bv`` in
    order; "C", "D": (rows, columns, positions in ``_Yv``) of each matrix's entries (None
    where that function is printed line by line, or the matrix has no entries)."""
    out: dict = {"B": None, "C": None, "D": None}
    if ujac.rolled:
        keys = [k for k, _ in lin.ujac.results]
        out["B"] = (tables.ref(tuple(k[0] for k in keys)), tables.ref(tuple(k[1] for k in keys)))
    if yjac.rolled:
        keys = [k for k, _ in lin.yjac.results]
        for part in ("C", "D"):
            pos = [i for i, k in enumerate(keys) if k[0] == part]
            if pos:
                out[part] = (tables.ref(tuple(keys[i][1] for i in pos)),
                             tables.ref(tuple(keys[i][2] for i in pos)), tables.ref(tuple(pos)))
    return out


def _maybe_rolled(eq: Equations, fn: lower.Function, printer, kind: str, tables) -> Function:
    """The function printed vectorised where it is mostly repeated structure
    (:mod:`bgc.backends.numpy.rolled`), else line by line."""
    if kind != "outs" or _out_ranges(eq, fn) is not None:
        states = [sv.symbol for sv in eq.states]
        params = [s for pv in eq.params for s in pv.symbols] + [d.symbol for d in eq.derived]
        got = rolled_function(fn, printer, Line, Function, states, params, kind, tables)
        if got is not None:
            return got
    return printed(fn, printer)


def _state_reads(fn: Function) -> Function:
    """The function reading each state it uses by its index, not unpacking the whole state."""
    reads = tuple(Line(name, f"x[{k}]") for k, name in enumerate(fn.states) if name != "_")
    return Function(fn.params, fn.inputs, tuple("_" for _ in fn.states), reads + fn.lines,
                    fn.results, fn.ops)


def _out_ranges(eq: Equations, outs: lower.Function) -> dict | None:
    """Output name -> (first, end) of its results' positions, where every output's results
    are one run of positions in order (else None: the outputs are not rolled)."""
    ranges: dict = {}
    for pos, (key, _) in enumerate(outs.results):
        first, end = ranges.get(key[0], (pos, pos))
        if end != pos:
            return None
        ranges[key[0]] = (first, pos + 1)
    if [name for name, _, _ in eq.outputs if name in ranges] != list(ranges):
        return None
    return ranges


def _newton_parts(eq: Equations, printer) -> list[dict]:
    """The nonlinear algebraic loops as the template prints them: a Newton solver each."""
    newton = []
    for nl in eq.newton:
        gd = guarded(nl)  # exponentials guarded and listed (bgc.lower.newton)
        newton.append({
            "name": nl.name, "n": len(nl.tear), "args": [str(a) for a in nl.args],
            "tear": [str(t) for t in nl.tear], "message": nl.where,
            "body": [Line(str(sym), printer.doprint(e)) for sym, e in gd["body"]],
            "residual": [printer.doprint(e) for e in gd["residual"]],
            "jac": [printer.doprint(e) for e in gd["jac"]],
            "exponents": [printer.doprint(e) for e in gd["exponents"]]})
    return newton


def _inputs_and_tables(eq: Equations, printer, input_units: dict) -> tuple[list, list]:
    """The inputs (their default signals printed) and the table inputs' data."""
    inputs, tables = [], []
    for iv in eq.inputs:
        tb = getattr(iv, "table", None)
        if tb is not None:  # data: numbers only, through lit; evaluated by the runtime
            tables.append({"input": iv.name, "t": [float(v) for v in tb.t],
                           "v": [float(v) for v in tb.v], "interp": tb.interp})
            inputs.append({"name": iv.name, "symbols": [str(s) for s in iv.symbols],
                           "shape": iv.shape, "unit": input_units.get(iv.name, ""),
                           "default": [f"_table_eval(t, {len(tables) - 1}, "
                                       f"{lit(tb.interp)}, {lit(tb.extrapolate)}, "
                                       f"{lit(iv.name)})"]})
            continue
        inputs.append({"name": iv.name, "symbols": [str(s) for s in iv.symbols],
                       "shape": iv.shape, "unit": input_units.get(iv.name, ""),
                       "default": [printer.doprint(d) for d in iv.default]})
    return inputs, tables


class TemplateBytecode(jinja2.FileSystemBytecodeCache):
    """The templates' compiled code kept where Python keeps bgc's own: ``__pycache__`` of the
    templates folder. jinja's file cache (an entry only for the very template text it came
    from, by jinja's checksum, and the same Python, by its magic header; written beside its
    place and renamed), with the jinja version in the file's name, and the rules of Python's
    own bytecode: written only where Python writes ``.pyc`` files (not under
    ``PYTHONDONTWRITEBYTECODE``), a folder that cannot be written simply not used, a damaged
    entry compiled again (and rewritten). Compiling the numpy module's template costs a
    process about 0.15 s of CPU; loading it from here is a read and ``marshal``. Like a
    ``.pyc``, it is trusted as much as the folder it lies in, bgc's own code."""

    def __init__(self, folder: Path):
        super().__init__(str(folder), f"%s.jinja2-{jinja2.__version__}.cache")
        self.folder = folder

    def load_bytecode(self, bucket) -> None:
        try:
            super().load_bytecode(bucket)
        except Exception:  # noqa: BLE001 - a damaged entry: compiled again (and rewritten)
            bucket.reset()

    def dump_bytecode(self, bucket) -> None:
        if sys.dont_write_bytecode:
            return
        with contextlib.suppress(OSError):
            self.folder.mkdir(exist_ok=True)
            super().dump_bytecode(bucket)


@functools.lru_cache(maxsize=None)
def _environment():
    """The jinja environment of the numpy templates (made once per process; its templates'
    compiled code kept in templates/__pycache__ by :class:`TemplateBytecode`)."""
    return make_environment(templates_dir() / "__pycache__")


def make_environment(bytecode_folder: Path):
    """A jinja environment of the numpy templates, their compiled code kept in
    ``bytecode_folder``."""
    env = jinja2.Environment(loader=template_loader(), keep_trailing_newline=True,
                             trim_blocks=True, lstrip_blocks=True,
                             undefined=jinja2.StrictUndefined, autoescape=False,
                             bytecode_cache=TemplateBytecode(bytecode_folder))
    env.filters.update(lit=lit, oneline=oneline, comment=comment, docstring=docstring)
    return env


def _identifiers(eq: Equations):
    for sv in eq.states:
        yield str(sv.symbol)
    for pv in eq.params:
        yield from (str(s) for s in pv.symbols)
    for a in eq.assignments:
        yield str(a.symbol)


def template_loader():
    """The jinja loader of bgc's templates (every backend's)."""
    return jinja2.FileSystemLoader(str(templates_dir()))
