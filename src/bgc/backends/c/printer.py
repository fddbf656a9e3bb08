"""Stage 5c: the lowered equations (:mod:`bgc.lower.ir`) -> C99 sources and a Python wrapper.

The C backend prints the same lowered functions as the numpy module (rhs, Jacobian values on
JAC_SPARSITY, outputs, initial state) with a C99 printer that writes the same cheap forms
(``b*b``, ``1/b``, ternaries for Piecewise, ``fmin``/``fmax``: :mod:`bgc.backends.c.cexpr`).
Long bodies are cut into parts of bounded size, each its own C function, spread over several
translation units (:mod:`bgc.backends.c.parts`); this module renders the units, the model's
main file, tables and Newton loops through the C templates, and the wrapper.

The wrapper module is the numpy module of the same model printed without its equations (names,
parameters, metadata, the runtime) followed by the C binding (templates/c/binding.py, copied
below its marker): the same public API, with rhs, jacobian, outputs, initial_state and
simulate (Rodas4, Radau, DOP853) running in the shared library.

Text from the model reaches the C sources only through :func:`c_string_literal` (string
literals) and :func:`c_comment` (comments); identifiers are the model's validated identifiers,
renamed where they would collide with C keywords or the C library.
"""
from __future__ import annotations

import functools
import hashlib
from dataclasses import dataclass
from pathlib import Path

import jinja2

from bgc.backends.c.build import CUnsupported  # noqa: F401 (raised by unsupported)
from bgc.backends.c.cexpr import (  # noqa: F401 (the C text helpers, as printer.*)
    CPrinter,
    c_comment,
    c_name,
    c_string_literal,
    c_sym,
)
from bgc.backends.c.events import c_events, event_parts
from bgc.backends.c.parts import PART_LINES, UNIT_PARTS, PartContext, cut_parts
from bgc.backends.numpy.printer import TemplateBytecode, lit, template_loader
from bgc.backends.numpy.printer import comment as py_comment
from bgc.backends.skeleton import WRAPPER_MARK, binding_source, check_wrapper  # noqa: F401
from bgc.base import __version__
from bgc.base.paths import templates_dir
from bgc.core.eqtypes import LinSolve, LinSolveEntry, NewtonSolve
from bgc.lower.ir import Lowered
from bgc.lower.newton import guarded
from bgc.lower.sparse_lu import make_plan, plan_c, prefer_sparse


@dataclass(frozen=True)
class CSources:
    """The generated C sources (file name -> text) and what the wrapper needs to know."""
    files: tuple[tuple[str, str], ...]
    digest: str  # sha256 of the sources: the wrapper checks the library it loads against it

    def __getitem__(self, name):
        return dict(self.files)[name]


def has_solves(eq) -> bool:
    """Does the model solve equations numerically (numeric linear solves of derivative
    causality, Newton loops of nonlinear algebraic loops)?"""
    kinds = (LinSolve, LinSolveEntry, NewtonSolve)
    return bool(getattr(eq, "newton", ())) or any(
        isinstance(a.expr, kinds) for a in eq.assignments + eq.jac_assignments)


def has_linear_solves(eq) -> bool:
    """Does the model solve linear systems numerically (derivative causality's LinSolve)?"""
    return any(isinstance(a.expr, LinSolve) for a in eq.assignments + eq.jac_assignments)


def table_data(ctx) -> list[dict]:
    """The table inputs as tables.c.j2 prints them (the FMU's model_tables.c too)."""
    return _tables(ctx)


def newton_protos(ctx) -> list[str]:
    """The Newton loops' prototypes (the FMU's parts declare them too)."""
    return _newton_protos(ctx)


def newton_loops(ctx, printer) -> list[dict]:
    """The Newton loops as newton.c.j2 prints them (the FMU's model_newton.c too)."""
    return _newton_loops(ctx, printer)


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
    ctx = PartContext(low)
    fns = {name: cut_parts(name, fn, printer, ctx, PART_LINES) for name, fn in
           (("rhs", low.rhs), ("jac", low.jac), ("outputs", low.outs), ("init", low.init))
           + ((("cons", low.cons),) if getattr(low, "cons", None) is not None else ())}
    events = c_events(eq, lambda name, fn: cut_parts(name, fn, printer, ctx, PART_LINES))
    names = [c_sym(s) for s in ctx.param_syms + ctx.state_syms + ctx.input_syms]
    names += [c_sym(a.symbol) for a in eq.assignments + eq.jac_assignments]
    for nm in names:
        assert nm.isidentifier() and nm.isascii(), nm
    if len(set(c_sym(s) for s in ctx.param_syms + ctx.state_syms + ctx.input_syms)) != \
            len(ctx.param_syms) + len(ctx.state_syms) + len(ctx.input_syms):
        raise AssertionError("two model identifiers map to one C name")
    all_parts = [p for f in fns.values() for p in f.parts] + event_parts(events)
    units = [all_parts[i:i + UNIT_PARTS] for i in range(0, len(all_parts), UNIT_PARTS)]
    env = template_env()
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
        ncons=len(low.cons.results) if getattr(low, "cons", None) is not None else 0,
        states=[sv.name for sv in eq.states], outputs=[o[0] for o in eq.outputs],
        nout=sum(olens), all_parts=all_parts, events=events,
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
        args = "".join(f"double {c_sym(a)}, " for a in nl.args)
        out.append(f"int bgcm_newton_{k}({args}double *restrict bgc_warm, "
                   "double *restrict bgc_z)")
    return out


def _newton_loops(ctx, printer) -> list[dict]:
    """The Newton loops as the template prints them: one C function each."""
    protos = _newton_protos(ctx)
    loops = []
    for k, nl in enumerate(ctx.newton):
        gd = guarded(nl)  # exponentials guarded and listed (bgc.lower.newton)
        loops.append({
            "proto": protos[k], "n": len(nl.tear), "where": nl.where,
            "args": [c_sym(a) for a in nl.args],
            "tear": [c_sym(t) for t in nl.tear],
            "body": [(c_sym(sym), printer.doprint(e)) for sym, e in gd["body"]],
            "residual": [printer.doprint(e) for e in gd["residual"]],
            "jac": [printer.doprint(e) for e in gd["jac"]],
            "exponents": [printer.doprint(e) for e in gd["exponents"]]})
    return loops


def _lu_plan(n: int, keys) -> str:
    """The C text of a sparse LU plan for the iteration matrices, when bgc.lower.sparse_lu (the C
    runtime's planner) has one that beats the dense LU; "" for the dense LU."""
    if not keys:
        return ""
    plan = make_plan(n, [k[0] for k in keys], [k[1] for k in keys])
    return plan_c(plan, "bgcm_lu_plan") if prefer_sparse(plan) else ""


@functools.lru_cache(maxsize=None)
def template_env():
    """The jinja environment of the C templates, with the C text filters (cstr, ccomment), made
    once per process; their compiled code kept in templates/__pycache__ as the numpy
    templates' (:class:`bgc.backends.numpy.printer.TemplateBytecode`)."""
    return make_template_env(templates_dir() / "__pycache__")


def make_template_env(bytecode_folder: Path):
    """A jinja environment of the C templates, their compiled code kept in
    ``bytecode_folder``."""
    env = jinja2.Environment(loader=template_loader(), keep_trailing_newline=True, trim_blocks=True,
                             lstrip_blocks=True, undefined=jinja2.StrictUndefined,
                             autoescape=False, bytecode_cache=TemplateBytecode(bytecode_folder))
    env.filters.update(cstr=c_string_literal, ccomment=c_comment, lit=lit, comment=py_comment)
    return env


def render_wrapper(low: Lowered, numpy_source: str, csrc: CSources, lib_name: str) -> str:
    """The wrapper module: the numpy module printed without its equations (``numpy_source``:
    :func:`bgc.backends.numpy.printer.render` with ``equations=False``), then the C part
    (constants and the binding); the whole text checked once (:func:`check_wrapper`)."""
    eq = low.eq
    olens = [len(vals) for _, _, vals in eq.outputs]
    text = template_env().get_template("c/wrapper.py.j2").render(
        numpy_source=numpy_source.rstrip("\n"), mark=WRAPPER_MARK.rstrip("\n"),
        lib_name=lib_name, digest=csrc.digest, nws=PartContext(low).nws,
        np=len(PartContext(low).param_syms),
        nnz=len(low.jac_keys), nout=sum(olens), binding=binding_source(),
        ncons=len(low.cons.results) if getattr(low, "cons", None) is not None else 0)
    check_wrapper(text)
    return text
