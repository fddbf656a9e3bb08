"""The skeleton checks of generated modules (a light module: no sympy, no jinja2, so that a
warm run can check a cached module before it runs it).

After rendering (or before a module is loaded, for a text that was not checked in this
process), its top-level statements must be exactly the template's. Model text can only ever
appear inside literals; if escaping were ever wrong, a stray statement would show here and
nothing would be written or run. Each text is checked once per process (a digest memo); only
its model part is parsed into a syntax tree, the template's verbatim parts (the runtime, a C
wrapper's binding) are compared as text, and :func:`checked_code` compiles the module from
its text.
"""
from __future__ import annotations

import ast
import functools
import hashlib
import re

from bgc.base.paths import templates_dir

_TEMPLATES = "numpy"
_RUNTIME_MARK = "# ==== bgc numpy runtime: copied below this line ====\n"
# Modules the generated code may import (numpy always; the printer may ask for these).
ALLOWED_IMPORTS = frozenset({"numpy", "scipy", "scipy.special", "math"})
_BINDING_MARK = "# ==== bgc C binding: copied below this line ====\n"
#: the line that separates the numpy part of a C-backend wrapper module from its C part
WRAPPER_MARK = "# ==== bgc C backend ====\n"


@functools.lru_cache(maxsize=None)
def runtime_source(backend: str = _TEMPLATES) -> str:
    """The part of templates/<backend>/runtime.py copied into every generated module."""
    text = (templates_dir() / backend / "runtime.py").read_text(encoding="utf-8")
    head, sep, body = text.partition(_RUNTIME_MARK)
    if not sep:
        raise AssertionError(f"runtime.py has no marker line {_RUNTIME_MARK!r}")
    return body.strip("\n")


_EVENTS_MARK = "# ==== bgc numpy events runtime: copied below this line ====\n"


@functools.lru_cache(maxsize=None)
def events_runtime_source() -> str:
    """The part of templates/numpy/events.py copied after the runtime into the module of a
    model with events (its simulate locates the events; a model without events never has it)."""
    text = (templates_dir() / _TEMPLATES / "events.py").read_text(encoding="utf-8")
    head, sep, body = text.partition(_EVENTS_MARK)
    if not sep:
        raise AssertionError(f"events.py has no marker line {_EVENTS_MARK!r}")
    return body.strip("\n")


# ---------------------------------------------------------------------------------------------
# The skeleton check: after rendering, the module's top-level statements must be exactly the
# template's. Model text can only ever appear inside literals; if escaping were ever wrong, a
# stray statement would show here and nothing would be written.

#: Names the model part of the template binds at top level, with the statement kind.
_MODEL_TOP = {
    "Assign": {"xp", "BGC_VERSION", "MODEL_HASH", "N_STATES", "STATE_NAMES", "STATE_OWNERS",
               "PARAM_DEFAULTS",
               "PARAM_UNITS", "_PARAM_NDIM", "INPUT_NAMES", "OUTPUT_NAMES", "OUTPUT_SHAPES",
               "JAC_SPARSITY", "_P0", "X0", "INPUT_LABELS", "OUTPUT_LABELS", "_TABLES",
               "TABLE_BREAKPOINTS", "TABLE_MAX_STEP", "OUTPUT_UNITS", "INPUT_UNITS",
               "_NEWTON_WARM", "_NEWTON_ITERATIONS", "RHS_USES_T", "INPUT_PERIODS", "N_EVENTS",
               "EVENT_NAMES", "EVENT_DIRECTIONS", "EVENT_TIMED", "EVENT_WHERE", "MODE_NAMES",
               "_RESETS", "_BGC_EXP_CAP", "_BGC_EXP_STEP", "CONSTRAINT_STATES",
               "CONSTRAINT_ALPHA", "CONSTRAINT_CLOSED", "MOMENTUM_STATES", "CLOSURE_STATES",
               "_IX", "_PARAM_ARRAY", "CONSTRAINT_DROPPED", "_NO_LINEAR"},
    "FunctionDef": {"_unpack", "_floats", "_params", "_inputs", "initial_state", "rhs", "jacobian",
                    "outputs", "input_jacobian", "output_jacobian", "_bgc_linsolve",
                    "event_values", "apply_event", "_bgc_newton", "_bgc_norm",
                    "_bgc_line_search", "_bgc_newton_failure", "_bgc_lexp", "_bgc_sexp",
                    "_bgc_exp_limit", "constraint_residuals", "kinetic_energy",
                    "_constraint_values", "_param_array", "_jacobian_values"},
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


#: sha256 digests of the texts that passed a check in this process, each with what the check
#: found: for a module, its model part's top-level functions, name -> (first line, last line)
#: as the check's tree has them (what :func:`checked_code` may leave out); for a wrapper, an
#: empty dict. Rendering checks a module and loading it would check it again; the second check
#: of the same text is a lookup (parsing the 3R2S module takes 0.4 s). One map, so a pass and
#: its spans are remembered together or not at all. In memory only, never persisted.
_PASSED: dict[tuple[str, bytes], dict[str, tuple[int, int]]] = {}


def _digest(text: str, kind: str) -> tuple[str, bytes]:
    return kind, hashlib.sha256(text.encode("utf-8", "surrogatepass")).digest()


def check_skeleton(text: str, backend: str = _TEMPLATES) -> None:
    """Parse the generated module and check its top-level statements: a docstring, the
    imports the printer may ask for, the model part's own definitions (each name once at most,
    except JAC_SPARSITY's pattern assignment) and then, statement for statement, the runtime."""
    digest = _digest(text, backend)
    if digest in _PASSED:
        return
    _PASSED[digest] = _check_skeleton(text, backend)


def checked_code(text: str, filename: str, wrapper: bool = False, without=()):
    """The code object of a generated module (``wrapper``: a C wrapper), its text checked
    first (a lookup when rendering checked it already in this process). Only the model's part
    is parsed into a syntax tree for the check (the template's verbatim parts are compared as
    text); the code is compiled from the text, which costs a fraction of building the tree.
    Raises SkeletonError for a text whose top level is not the template's.

    ``without``: names of the model part's top-level functions the caller never calls (a
    start check: bgc.run.runner.check_module_start), compiled as blank lines: the same text
    less whole top-level statements of the checked tree, so its top level is still the
    template's, and every line keeps its number. (The 3R2S's Jacobian and its linearisation
    are four fifths of its text.) A text with a carriage return, whose lines Python may count
    apart from ``\\n``, is compiled whole."""
    (check_wrapper if wrapper else check_skeleton)(text)
    spans = None if wrapper or not without or "\r" in text else \
        _PASSED.get(_digest(text, _TEMPLATES))
    if not spans:
        return compile(text, filename, "exec")
    lines = text.split("\n")
    for name in without:
        if name in spans:
            first, last = spans[name]
            lines[first - 1:last] = [""] * (last - first + 1)
    return compile("\n".join(lines), filename, "exec")


def _parse(text: str, what: str) -> ast.Module:
    try:
        return ast.parse(text)
    except SyntaxError as exc:
        raise SkeletonError(f"{what} does not parse: {exc}") from None


def _check_skeleton(text: str, backend: str) -> dict[str, tuple[int, int]]:
    runtime = runtime_source(backend)
    body = text.rstrip("\n")  # (a C wrapper continues after the module: see check_wrapper)
    if backend == _TEMPLATES and "\nEVENT_NAMES = (" in body:  # a hybrid model's events
        runtime += "\n\n\n" + events_runtime_source()
    if not body.endswith("\n\n\n" + runtime):  # the runtime, verbatim, at the end
        raise SkeletonError(f"the runtime part differs from templates/{backend}/runtime.py")
    # the model part must parse on its own: nothing in it can reach into the runtime
    head = body[:-len(runtime)]
    passed, runs = _plain_runs_passed(head)
    if runs:
        try:
            spans = _check_head(_parse(passed, "generated module").body)
        except SkeletonError:  # (a run inside brackets does not parse as pass: the whole
            pass               # tree decides, so the runs never refuse a text by themselves)
        else:
            for name, (first, last) in spans.items():  # a function ends with its last run
                spans[name] = (first, max([last] + [e for at, e in runs if first <= at <= last]))
            return spans
    return _check_head(_parse(head, "generated module").body)


# ---------------------------------------------------------------------------------------------
# Plain runs: the bulk of a large module's model part (its equations) parsed as one statement
#
# Only the model part's top level is checked; a function's body is not looked into. A long run
# of *plain* lines (each indented by spaces, its code holding no quote, backslash or tab, its
# brackets closed on the line, then at most a comment) is given to the parser as one ``pass``
# at its first code line's indentation, the other lines left blank (every line keeps its
# number). No string can start, and no line break other than "\n" can hide, in plain lines, so
# where the run starts outside brackets and strings, all of it lies in an indented block,
# and its top level is the text's top level with the run in it: the same statements, or a
# refusal. Inside a triple-quoted string the run is string content (the statements around
# it are the same); inside brackets, ``pass`` does not parse. A text the runs' tree refuses
# is checked again whole, so only the whole tree refuses a text. A text with a carriage
# return or a NUL byte is parsed whole. Runs of a literal's integer items (_LITERAL) are
# given as one item; :func:`_opens` and :func:`_block_end` keep runs out of brackets and
# blocks they would cut (guesses that only spare the second parse). (The 3R2S's model part:
# a tree of 0.3 s, against 0.05 s for the scan and a tree without its equations.) What the
# check does not do, before as now, is look into a function's body: a syntax error there is
# the compile's.

#: a plain line: spaces, code without quotes, backslashes, tabs or other line breaks, and
#: at most a comment
_PLAIN = re.compile(r"( +)([^'\"\\#\t\f\v\x00\r]*)(#[^\f\v\x00\r]*)?\Z")
_BRACKETS = re.compile(r"[()\[\]{}]")
_CLOSE = {")": "(", "]": "[", "}": "{"}
#: a line of a literal's items: a list of integers on one line (as Python writes them), or
#: numpy's array of one, and a comma; _LAST_ITEM: the same without the comma. The index tables
#: ``_IX`` and JAC_SPARSITY's pattern are such lines (a link chain of 9,996 states: 5.5 MB, a
#: parse of 5.6 s). Two or more of them after a line that opens a bracket are given to the
#: parser as one item, ``0,`` (the last one's comma may be left out where the bracket closes
#: on the next line): a run of such items is valid wherever ``0,`` is, nothing but integers
#: can be in it, and the statement around it is the same statement.
_INT = r"-?(?:0|[1-9][0-9]*)"
_INTS = rf"\[(?:{_INT}(?:, {_INT})*(?:, )?)?\]"
_ITEM = rf" +(?:{_INTS}|np\.array\({_INTS}, dtype=np\.intp\))"
_LITERAL = re.compile(_ITEM + r",\Z")
_LAST_ITEM = re.compile(_ITEM + r"\Z")
#: the fewest lines in a row left to the scan (fewer are parsed as they are)
MIN_PLAIN_RUN = 50


def _plain(line: str) -> int | None:
    """The line's indentation where it is plain (a blank line: 0), else None."""
    if not line or line.isspace() and not line.strip(" "):
        return 0
    m = _PLAIN.match(line)
    if m is None:
        return None
    open_: list = []
    for b in _BRACKETS.findall(m.group(2)):
        if b in "([{":
            open_.append(b)
        elif not open_ or open_.pop() != _CLOSE[b]:
            return None
    return None if open_ else len(m.group(1))


def _plain_runs_passed(head: str) -> tuple[str, list[tuple[int, int]]]:
    """The model part with each run of :data:`MIN_PLAIN_RUN` or more plain lines given as
    ``pass`` (see above), and the runs as (line of the pass, last line of code), 1-based."""
    if "\r" in head or "\x00" in head:
        return head, []
    lines = head.split("\n")
    runs: list[tuple[int, int]] = []
    i, n = 0, len(lines)
    while i < n:
        if i and _opens(lines[i - 1]) and _LITERAL.match(lines[i]):
            j = i + 1
            while j < n and _LITERAL.match(lines[j]):
                j += 1
            if j + 1 < n and _LAST_ITEM.match(lines[j]) and lines[j + 1][:1] in _CLOSE:
                j += 1  # the last item, its bracket closed on the next line: ``0,`` there too
            if j - i > 1:  # a literal's items: one item (inside brackets, any indentation)
                lines[i:j] = [""] * (j - i)
                lines[i] = "    0,"
                runs.append((i + 1, j))
            i = j
            continue
        j, first, last = i, None, None
        while j < n:
            ind = _plain(lines[j])
            if ind is None:
                break
            if _has_code(lines[j]):
                last = j
                if first is None:
                    first = (j, ind)
            j += 1
        if first is not None and j - i >= MIN_PLAIN_RUN and not _opens(lines[i - 1] if i else ""):
            end, last = _block_end(lines, first, j, last)
            if end > first[0] and end - i >= MIN_PLAIN_RUN:
                lines[i:end] = [""] * (end - i)
                lines[first[0]] = " " * first[1] + "pass"
                runs.append((first[0] + 1, last + 1))
        i = j + 1
    return ("\n".join(lines) if runs else head), runs


def _opens(line: str) -> bool:
    """Whether the line before a run leaves a bracket open or a list going (``_IX = (``): a run
    there is the bracket's content, not a block, and would only make the parse of the passes
    fail and the text be parsed twice (a link chain of 9,996 states: 11 s). A guess that
    saves time only: the whole tree still decides wherever the runs do not parse."""
    code = line.rstrip()
    return code.endswith(("(", "[", "{", ","))


def _block_end(lines: list, first: tuple, j: int, last: int) -> tuple[int, int]:
    """Where a run from line ``first`` up to (not including) line ``j`` may end, and its last
    code line then: before its last statement at the run's own indentation or less where the
    line after the run is indented deeper (``if x.shape[1:] != _bs:`` whose body is not
    plain: a run to its end would leave that body hanging). Another guess that saves time
    only, as :func:`_opens`."""
    nxt = lines[j] if j < len(lines) else ""
    if not nxt.strip() or len(nxt) - len(nxt.lstrip(" ")) <= first[1]:
        return j, last
    header = None  # the run's last statement at its own indentation or less
    for k in range(last, first[0], -1):
        ln = lines[k]
        if not _has_code(ln):
            continue
        if header is not None:
            return header, k  # the run ends before it; its last code line is k
        if len(ln) - len(ln.lstrip(" ")) <= first[1]:
            header = k
    return (header, first[0]) if header is not None else (first[0], first[0])


def _has_code(line: str) -> bool:
    """Whether a plain line holds code (not only spaces and a comment)."""
    code = line.lstrip(" ")
    return bool(code) and not code.startswith("#")


def _check_head(head: list) -> dict[str, tuple[int, int]]:
    """The model part's statements: the docstring, allowed imports, the template's names.
    Returns the lines of its undecorated top-level functions (name -> (first, last))."""
    if not head:
        raise SkeletonError("the generated module has no model part")
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
        if kind == "FunctionDef":  # one Newton solver per nonlinear algebraic loop
            allowed = allowed | {n for n in names if re.fullmatch(r"_(newton|reset)_[0-9]+", n)}
        if not names or not names <= allowed:
            raise SkeletonError(f"unexpected top-level {kind} {sorted(names)} at line "
                                f"{getattr(node, 'lineno', '?')}")
        for nm in names:
            seen[nm] = seen.get(nm, 0) + 1
            if seen[nm] > (2 if nm == "JAC_SPARSITY" else 1):
                raise SkeletonError(f"{nm} bound twice at top level")
    return {node.name: (node.lineno, node.end_lineno) for node in head[1:]
            if isinstance(node, ast.FunctionDef) and not node.decorator_list}


# ---------------------------------------------------------------------------------------------
# The C backend's wrapper module: the numpy module, then the C constants, then the binding

@functools.lru_cache(maxsize=None)
def binding_source() -> str:
    """The part of templates/c/binding.py copied into every wrapper module."""
    text = (templates_dir() / "c" / "binding.py").read_text(encoding="utf-8")
    head, sep, body = text.partition(_BINDING_MARK)
    if not sep:
        raise AssertionError(f"binding.py has no marker line {_BINDING_MARK!r}")
    return body.strip("\n")


#: names the C part of a wrapper binds at top level (before the binding)
_C_TOP = {"C_LIBRARY", "C_DIGEST", "_C_NP", "_C_NNZ", "_C_NOUT", "_C_NWS", "_C_NCONS"}


def check_wrapper(text: str) -> None:
    """The wrapper's skeleton: the numpy module (checked as such), then the C constants, then
    exactly templates/c/binding.py's part (compared as text)."""
    digest = _digest(text, "wrapper")
    if digest in _PASSED:
        return
    _check_wrapper(text)
    _PASSED[digest] = {}


def _check_wrapper(text: str) -> None:
    head, sep, tail = text.rpartition(WRAPPER_MARK)
    if not sep:
        raise SkeletonError("the wrapper has no C part")
    _check_skeleton(head, _TEMPLATES)  # its numpy part (printed without the equations)
    binding, tail = binding_source(), tail.rstrip("\n")
    if not tail.endswith("\n" + binding):
        raise SkeletonError("the wrapper's binding differs from templates/c/binding.py")
    # the C constants must parse on their own: nothing in them can reach into the binding
    top = _parse(tail[:-len(binding)], "the wrapper's C part").body
    seen = set()
    for node in top:
        if not (isinstance(node, ast.Assign) and len(node.targets) == 1
                and isinstance(node.targets[0], ast.Name) and node.targets[0].id in _C_TOP
                and isinstance(node.value, ast.Constant)):
            raise SkeletonError(f"unexpected statement in the wrapper's C part at line "
                                f"{getattr(node, 'lineno', '?')}")
        if node.targets[0].id in seen:
            raise SkeletonError(f"{node.targets[0].id} bound twice")
        seen.add(node.targets[0].id)
