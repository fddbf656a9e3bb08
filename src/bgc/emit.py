"""Stage 5: equations -> one standalone numpy module, through the jinja2 templates.

The expression printer is sympy's ``NumPyPrinter`` (strict: an unknown function is an error,
never silently printed) with a few overrides for speed and readability; the generated import
block lists what the printer actually used. Each function computes only what its results need:
the assignments are pruned backwards from the results, common subexpressions are eliminated,
and the definitions are scheduled in causal order.
"""
from __future__ import annotations

import ast
import functools
import itertools
import keyword
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import jinja2
import networkx as nx
import sympy as sp
from sympy.printing.numpy import NumPyPrinter

from . import __version__
from .equations import Assignment, Equations, T, schedule

_IDENT_OK = set("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_")
_TEMPLATES = "numpy"  # this backend's folder in templates/
_RUNTIME_MARK = "# ==== bgc numpy runtime: copied below this line ====\n"
# Modules the generated code may import (numpy always; the printer may ask for these).
ALLOWED_IMPORTS = frozenset({"numpy", "scipy", "scipy.special", "math"})


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


def oneline(text, limit: int = 200) -> str:
    """Free text made safe for one line inside a docstring or a comment: control characters,
    line breaks and unprintable characters become visible escapes; long text is cut."""
    s = "".join(c if c.isprintable() else repr(c)[1:-1] for c in str(text))
    return s if len(s) <= limit else s[:limit - 3] + "..."


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


class BgcPrinter(NumPyPrinter):
    """NumPyPrinter writing the array API's functions as ``xp.`` (the namespace of the
    inputs), numpy's others as ``np.``, and cheap forms of common operations."""

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

    def _print_Mul(self, expr):
        # CodePrinter._print_Mul writes a lone denominator factor after "/" without
        # parentheses, trusting that a power binds tighter than "/". _print_Pow writes b**2 as
        # the product b*b, so x/b**2 would come out as x/b*b (= x): parenthesise it.
        s = super()._print_Mul(expr)
        den = [f for f in sp.Mul.make_args(expr) if f.is_commutative and f.is_Pow
               and f.exp.is_Rational and f.exp.is_negative]
        if len(den) == 1 and den[0].exp == -2:
            d = self._print(sp.Pow(den[0].base, 2, evaluate=False))
            if s.endswith("/" + d):
                s = f"{s[:-len(d)]}({d})"
        return s

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

    def _print_Float(self, expr):
        return repr(float(expr))


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


def _prune(results: list, assigns: list[Assignment]) -> list[Assignment]:
    need = set()
    for r in results:
        need |= r.free_symbols
    keep = []
    for a in reversed(assigns):
        if a.symbol in need:
            keep.append(a)
            need |= a.expr.free_symbols
    keep.reverse()
    return keep


def _function(eq: Equations, printer: BgcPrinter, results: list, assigns: list[Assignment],
              keys: list, cse: bool = True) -> Function:
    """Prune, CSE and schedule one generated function's body."""
    assigns = _prune(results, assigns)
    exprs = [a.expr for a in assigns] + list(results)
    if cse and exprs:
        repl, reduced = sp.cse(exprs, symbols=(sp.Symbol(f"_c{i}", real=True)
                                               for i in itertools.count()),
                               order="none", list=True)
    else:
        repl, reduced = [], exprs
    defs = [(s, e, "") for s, e in repl]
    defs += [(a.symbol, r, a.why) for a, r in zip(assigns, reduced[:len(assigns)])]
    res = reduced[len(assigns):]
    # schedule: cse temporaries just before their first use, assignments in causal order
    g = nx.DiGraph()
    index = {}
    byname = {}
    defined = {s for s, _, _ in defs}
    for s, e, why in defs:
        g.add_node(s)
        byname[s] = (e, why)
        for d in e.free_symbols:
            if d in defined:
                g.add_edge(d, s)
    pos = {a.symbol: i for i, a in enumerate(assigns)}
    first_use: dict = {}
    for s, e, _ in defs:
        if s in pos:
            for d in e.free_symbols:
                if d in defined:
                    first_use[d] = min(first_use.get(d, 10 ** 9), pos[s])
    for s, e, _ in reversed(defs[:len(repl)]):  # temporaries used by later temporaries
        for d in e.free_symbols:
            if d in defined and s in first_use:
                first_use[d] = min(first_use.get(d, 10 ** 9), first_use[s])
    for s, _, _ in defs:
        if s in pos:
            index[s] = 2 * pos[s] + 1
        else:
            index[s] = 2 * first_use.get(s, len(assigns)) if s in first_use else 2 * len(assigns)
    order = schedule(g, index)
    lines = []
    for s in order:
        e, why = byname[s]
        lines.append(Line(str(s), printer.doprint(e), why))
    results_code = []
    for k, r in zip(keys, res):
        results_code.append((k, printer.doprint(r)))
    used = set()
    for s, e, _ in defs:
        used |= e.free_symbols
    for r in res:
        used |= r.free_symbols
    pnames = tuple(str(s) for pv in eq.params for s in pv.symbols if s in used)
    pnames += tuple(str(a.symbol) for a in eq.derived if a.symbol in used)
    inames = tuple(str(s) for iv in eq.inputs for s in iv.symbols if s in used)
    snames = tuple(str(sv.symbol) if sv.symbol in used else "_" for sv in eq.states)
    ops = _count_ops([e for _, e, _ in defs] + list(res))
    return Function(pnames, inames, snames, tuple(lines), tuple(results_code), ops)


def _count_ops(exprs) -> int:
    """Arithmetic operations and function calls, counted on the expression trees (cheap)."""
    n = 0
    for e in exprs:
        for node in sp.preorder_traversal(e):
            if node.is_Add or node.is_Mul:
                n += len(node.args) - 1
            elif node.is_Pow or node.is_Function or isinstance(node, sp.Piecewise):
                n += 1
    return n


def _pyrepr(v) -> str:
    if isinstance(v, tuple):
        if all(len(r) == 1 for r in v):
            return "[" + ", ".join(repr(float(r[0])) for r in v) + "]"
        return "[" + ", ".join("[" + ", ".join(repr(float(c)) for c in r) + "]" for r in v) + "]"
    return repr(float(v))


def render(eq: Equations, *, source: str, source_hash: str, description: str = "",
           header_notes: tuple[str, ...] = (), progress=None) -> str:
    printer = BgcPrinter()
    n = len(eq.states)
    say = progress or (lambda msg: None)
    say("emitting rhs")
    rhs = _function(eq, printer, list(eq.derivatives), list(eq.assignments), list(range(n)))
    say("emitting jacobian")
    jkeys = sorted(eq.jacobian)
    jac = _function(eq, printer, [eq.jacobian[k] for k in jkeys],
                    list(eq.assignments) + list(eq.jac_assignments), jkeys)
    say("emitting outputs")
    oexprs, okeys = [], []
    for name, shp, vals in eq.outputs:
        for k, v in enumerate(vals):
            oexprs.append(v)
            okeys.append((name, k))
    outs = _function(eq, printer, oexprs, list(eq.assignments), okeys)
    init = _function(eq, printer, [sv.initial for sv in eq.states], [], list(range(n)),
                     cse=False)
    derived = [Line(str(a.symbol), printer.doprint(a.expr), a.why) for a in eq.derived]
    inputs = []
    for iv in eq.inputs:
        inputs.append({"name": iv.name, "symbols": [str(s) for s in iv.symbols],
                       "shape": iv.shape,
                       "default": [printer.doprint(d) for d in iv.default]})
    input_params = sorted({str(s) for iv in eq.inputs for d in iv.default for s in d.free_symbols
                           if s != T})
    params = []
    for pv in eq.params:
        params.append({"id": pv.id, "code": pv.code, "shape": pv.shape,
                       "symbols": [str(s) for s in pv.symbols], "default": _pyrepr(pv.value),
                       "unit": pv.unit, "description": pv.description})
    imports = sorted(m for m in printer.module_imports if m and m != "numpy")
    env = jinja2.Environment(loader=_loader(), keep_trailing_newline=True,
                             trim_blocks=True, lstrip_blocks=True,
                             undefined=jinja2.StrictUndefined, autoescape=False)
    env.filters.update(lit=lit, oneline=oneline, comment=comment, docstring=docstring)
    tpl = env.get_template(f"{_TEMPLATES}/module.py.j2")
    outputs = [{"name": name, "shape": shp, "size": len(vals)} for name, shp, vals in eq.outputs]
    text = tpl.render(
        name=eq.name, version=__version__, source=source, source_hash=source_hash,
        description=description, notes=list(header_notes) + list(eq.loops),
        states=eq.states, params=params, derived=derived, inputs=inputs,
        input_params=input_params, outputs=outputs, rhs=rhs, jac=jac, outs=outs, init=init,
        jac_keys=jkeys, n=n, imports=imports,
        all_param_symbols=[s for p in params for s in p["symbols"]] + [d.target for d in derived],
        runtime=runtime_source(),
    )
    for ident in _identifiers(eq):
        assert ident.isidentifier() and not keyword.iskeyword(ident) and set(ident) <= _IDENT_OK
    check_skeleton(text)  # the module's top level is exactly the template's, nothing else
    return text


def _identifiers(eq: Equations):
    for sv in eq.states:
        yield str(sv.symbol)
    for pv in eq.params:
        yield from (str(s) for s in pv.symbols)
    for a in eq.assignments:
        yield str(a.symbol)


def templates_dir() -> Path:
    """templates/ of the source tree, else the installed package's copy (bgc.templates)."""
    here = Path(__file__).resolve().parent
    repo_templates = here.parent.parent / "templates"
    if (repo_templates / _TEMPLATES / "module.py.j2").is_file():
        return repo_templates
    return Path(str(resources.files("bgc.templates")))


def _loader():
    return jinja2.FileSystemLoader(str(templates_dir()))


@functools.lru_cache(maxsize=None)
def runtime_source(backend: str = _TEMPLATES) -> str:
    """The part of templates/<backend>/runtime.py copied into every generated module."""
    text = (templates_dir() / backend / "runtime.py").read_text(encoding="utf-8")
    head, sep, body = text.partition(_RUNTIME_MARK)
    if not sep:
        raise AssertionError(f"runtime.py has no marker line {_RUNTIME_MARK!r}")
    return body.strip("\n")


# ---------------------------------------------------------------------------------------------
# The skeleton check: after rendering, the module's top-level statements must be exactly the
# template's. Model text can only ever appear inside literals; if escaping were ever wrong, a
# stray statement would show here and nothing would be written.

#: Names the model part of the template binds at top level, with the statement kind.
_MODEL_TOP = {
    "Assign": {"xp", "BGC_VERSION", "MODEL_HASH", "N_STATES", "STATE_NAMES", "PARAM_DEFAULTS",
               "PARAM_UNITS", "_PARAM_NDIM", "INPUT_NAMES", "OUTPUT_NAMES", "OUTPUT_SHAPES",
               "JAC_SPARSITY", "_P0", "X0"},
    "FunctionDef": {"_unpack", "_params", "_inputs", "initial_state", "rhs", "jacobian",
                    "outputs"},
    "ClassDef": {"_Unpacked"},
}


class SkeletonError(AssertionError):
    """The rendered module's top level is not the template's (a bug, never written out)."""


def _top_names(node) -> tuple[str, set]:
    kind = type(node).__name__
    if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
        return kind, {node.name}
    if isinstance(node, ast.Assign):
        names = set()
        for tgt in node.targets:
            base = tgt.value if isinstance(tgt, ast.Subscript) else tgt
            if not isinstance(base, ast.Name):
                return kind, {"<complex target>"}
            names.add(base.id)
        return kind, names
    return kind, set()


def check_skeleton(text: str, backend: str = _TEMPLATES) -> None:
    """Parse the generated module and check its top-level statements: a docstring, the
    imports the printer may ask for, the model part's own definitions (each name once at most,
    except JAC_SPARSITY's pattern assignment) and then, statement for statement, the runtime."""
    try:
        tree = ast.parse(text)
    except SyntaxError as exc:
        raise SkeletonError(f"generated module does not parse: {exc}") from None
    body = tree.body
    rt = ast.parse(runtime_source(backend)).body
    if len(body) < len(rt) + 2:
        raise SkeletonError("generated module is shorter than its runtime")
    head, tail = body[:len(body) - len(rt)], body[len(body) - len(rt):]
    if [ast.dump(s) for s in tail] != [ast.dump(s) for s in rt]:
        raise SkeletonError("the runtime part differs from templates/numpy/runtime.py")
    doc = head[0]
    if not (isinstance(doc, ast.Expr) and isinstance(doc.value, ast.Constant)
            and isinstance(doc.value.value, str)):
        raise SkeletonError("the module does not start with its docstring")
    seen: dict[str, int] = {}
    for node in head[1:]:
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name not in ALLOWED_IMPORTS or a.asname not in (None, "np"):
                    raise SkeletonError(f"unexpected import {a.name!r}")
            continue
        kind, names = _top_names(node)
        allowed = _MODEL_TOP.get(kind, set())
        if not names or not names <= allowed:
            raise SkeletonError(f"unexpected top-level {kind} {sorted(names)} at line "
                                f"{getattr(node, 'lineno', '?')}")
        for nm in names:
            seen[nm] = seen.get(nm, 0) + 1
            if seen[nm] > (2 if nm == "JAC_SPARSITY" else 1):
                raise SkeletonError(f"{nm} bound twice at top level")
