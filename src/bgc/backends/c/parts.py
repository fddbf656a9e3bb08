"""A lowered function's body cut into C functions ("parts") of bounded size (bgc.backends.c).

Long bodies are cut into parts of at most :data:`PART_LINES` lines, each its own C function,
and the parts are spread over translation units of :data:`UNIT_PARTS` parts so that ``gcc
-O2`` stays fast and the units build in parallel; values that cross from one part to a later
one travel through a scratch array. :class:`PartContext` says where each symbol lives (the
parameter vector, the state, an input's default, a table, a numeric solve); the C backend and
the FMU export print the same parts from it."""
from __future__ import annotations

from dataclasses import dataclass

import sympy as sp

from bgc.backends.c.cexpr import CPrinter, c_comment, c_sym
from bgc.core.eqtypes import LinSolve, LinSolveEntry, NewtonSolve
from bgc.core.equations import T
from bgc.lower.ir import Lowered
from bgc.lower.reroll import Index, Loop, Result, Rolled, reroll

#: lines (definitions plus results) per generated C function, and functions per unit
PART_LINES = 250
UNIT_PARTS = 4


#: The end of a Newton loop's failure message (the C step loop appends the method and time).
NEWTON_FAILURE = (" did not converge (damped Newton, 100 iterations). Check the laws' parameters"
                  " and units for a solution there; a smaller max_step keeps the warm start"
                  " close; a small compliance (C) or inertance (I) in the loop makes it a state")


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
    # a loop's index tables (bgc.lower.reroll): (C name, the initialiser's text)
    index_tables: tuple[tuple[str, str], ...] = ()


@dataclass(frozen=True)
class CFunction:
    name: str  # rhs, jac, outputs, init
    parts: tuple[Part, ...]
    nscratch: int
    nout: int
    uses_t: bool


def _items(rolled: Rolled) -> list:
    """(target, expression or loop, comment, result slot) per line, result and loop."""
    out = []
    for it in rolled.items:
        if isinstance(it, Loop):
            out.append((None, it, "", -2))
        elif isinstance(it, Result):
            out.append((None, it.expr, "", it.key))
        else:
            out.append((it.target, it.expr, it.comment, -1))
    return out


def _chunks(items: list, limit: int) -> list:
    """The items cut into parts of at most ``limit`` lines (a loop weighs its body's length)."""
    chunks, cur, weight = [], [], 0
    for item in items:
        w = len(item[1].body) if isinstance(item[1], Loop) else 1
        if cur and weight + w > limit:
            chunks.append(cur)
            cur, weight = [], 0
        cur.append(item)
        weight += w
    chunks.append(cur)
    return chunks


def cut_parts(name: str, fn, printer: CPrinter, ctx: PartContext, limit: int = PART_LINES
              ) -> CFunction:
    # repeated structure as loops over the value array (bgc.lower.reroll), whose values are
    # printed as its elements everywhere
    rolled = reroll(fn, ctx.state_syms, ctx.param_syms)
    printer = printer.renamed({s: f"bgc_w[{k}]" for s, k in rolled.values.items()})
    items = _items(rolled)
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
    chunks = _chunks(items, limit)
    for ci, chunk in enumerate(chunks):
        for tgt, _, _, _ in chunk:
            if tgt is not None and tgt not in rolled.values:
                defined_in[tgt] = ci
    frees = [[e.symbols if isinstance(e, Loop) else e.free_symbols for _, e, _, _ in chunk]
             for chunk in chunks]
    # which definitions a later part needs: those get a scratch slot (a solve: one per entry)
    slots: dict = {}
    for ci, chunk in enumerate(chunks):
        for fs in frees[ci]:
            for s in fs:
                if s in defined_in and defined_in[s] < ci and s not in slots:
                    slots[s] = None
    order = sorted(slots, key=lambda s: (defined_in[s], str(s)))
    slots, nslot = {}, rolled.nvalues  # the value array first, then the parts' exports
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
        tabs = tuple((c_sym(s), ctx.table_of[s], ctx.table_fail(ctx.table_of[s]))
                     for s in ctx.input_syms if s in used and s in ctx.table_of)
        need_p = set(used)
        for s in inputs:
            need_p |= ctx.input_default[s].free_symbols
        uses_t = uses_t or T in need_p or bool(tabs)
        params = tuple((c_sym(s), k) for k, s in enumerate(ctx.param_syms) if s in need_p)
        ins = tuple((c_sym(s), printer.doprint(ctx.input_default[s])) for s in inputs)
        states = tuple((c_sym(s), k) for k, s in enumerate(ctx.state_syms) if s in used)
        imports = tuple((c_sym(s), slots[s]) for s in order
                        if s in used and defined_in[s] < ci and s not in vsize)
        vimports = tuple((c_sym(s), slots[s]) for s in order
                         if s in used and defined_in[s] < ci and s in vsize)
        lines = []
        fallible, newton = any(f for _, _, f in tabs), False
        lus: dict = {}  # A's entries -> the part's LU of it (one factorisation per matrix)
        tables: dict = {}  # a loop's index tables in this part: values -> name
        for tgt, e, why, k in chunk:
            if isinstance(e, Loop):
                lines.append(CLine("", loop_code(e, printer, tables, f"bgcm_{name}_{ci}"),
                                   kind="loop"))
                continue
            if tgt is not None and tgt in rolled.values:
                lines.append(CLine("", printer.doprint(e), why, -1, rolled.values[tgt],
                                   kind="store"))
                continue
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
                lines.append(CLine(c_sym(tgt), code, why, -1, slots.get(tgt, -1)))
        parts.append(Part(f"bgcm_{name}_{ci}", params, ins, states, imports, tuple(lines),
                          vimports, tabs, fallible, newton,
                          tuple((nm, _table_text(v)) for v, nm in tables.items())))
    return CFunction(name, tuple(parts), nslot, len(fn.results), uses_t)


def _index(ix: Index, tables: dict, prefix: str) -> str:
    """The C text of a loop's index at iteration bgc_i: affine, or a static table's entry."""
    if ix.table:
        if ix.table not in tables:
            tables[ix.table] = f"{prefix}_ix{len(tables)}"
        return f"{tables[ix.table]}[bgc_i]"
    step = "bgc_i" if ix.stride == 1 else f"{abs(ix.stride)}*bgc_i"
    if ix.start == 0 and ix.stride >= 0:
        return step
    return f"{ix.start} {'+' if ix.stride >= 0 else '-'} {step}"


_ARRAY = {"x": "bgc_x", "p": "bgc_p", "v": "bgc_w", "out": "bgc_out"}


def loop_code(loop: Loop, printer: CPrinter, tables: dict, prefix: str) -> str:
    """A loop's C text: one ``for`` over its iterations, each statement one assignment into
    the value array (or the results) from the arrays it reads at its indices."""
    out = [f"    for (int bgc_i = 0; bgc_i < {loop.count}; ++bgc_i) {{"]
    for st in loop.body:
        pr = printer.renamed({**printer.names, **{
            r.name: f"{_ARRAY[r.array]}[{_index(r.index, tables, prefix)}]" for r in st.reads}})
        if st.comment:
            out.append(f"        /* {c_comment(st.comment)} (the first of {loop.count}) */")
        out.append(f"        {_ARRAY[st.array]}[{_index(st.index, tables, prefix)}] = "
                   f"{pr.doprint(st.expr)};")
    out.append("    }")
    return "\n".join(out)


def _table_text(values: tuple) -> str:
    """A static index table's initialiser: its entries, twenty to a line."""
    rows = [", ".join(str(v) for v in values[i:i + 20]) for i in range(0, len(values), 20)]
    return ",\n    ".join(rows)


def _solve_line(tgt, e, why, export, n, printer, ctx, lus: dict) -> CLine:
    """The C line of a numeric solve's result (an array of n values). Solves with the same
    matrix in one part (the Jacobian's columns through a solve: d(A^-1 b) = A^-1 (db - dA x))
    share one LU."""
    target = c_sym(tgt)
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
    return CLine(target, c_sym(e), why, -1, export, "alias", n)


class PartContext:
    """Where the parts find each symbol: the parameter vector (parameters, then the derived
    ones), the state, the inputs (their defaults or tables), numeric solves; and the failure
    codes and messages the parts return."""

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

    @classmethod
    def inputs_as_params(cls, low: Lowered) -> PartContext:
        """The FMU's context: every input is a value in the parameter vector, after the
        derived parameters (set through fmi2SetReal), so that no part reads an input's default
        or a table. (The FMU export refuses linear solves and tables before printing; its
        Newton loops are the C backend's, called without a workspace: cold-started.)"""
        ctx = cls(low)
        ctx.param_syms = ctx.param_syms + ctx.input_syms
        ctx.input_syms, ctx.input_default, ctx.table_of = [], {}, {}
        return ctx

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
        # the numpy module's message (templates/numpy/module.py.j2); the step loop adds when
        return self.newton[k].where + NEWTON_FAILURE

    def linsolve_message(self, e) -> str:
        """What a singular numeric solve says: derivative causality's system (named by its
        unknowns and the elements it runs through), the same system's solves for the
        Jacobian, or a Newton loop's Jacobian at its solution."""
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
