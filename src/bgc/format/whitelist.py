"""The expression parser and its whitelist: what an expression in a model or scene may say.

A model's expressions are untrusted text. They are parsed with Python's :mod:`ast` and every
node is checked against a whitelist (numbers, names, arithmetic, indexing, list literals and a
fixed set of functions); nothing is ever evaluated or passed to ``sympify``. This module knows
only text and syntax trees (no sympy), so reading and checking a model stays light; the meaning
of a checked tree, as sympy objects, is bgc.format.expr's.
"""
from __future__ import annotations

import ast
import math
import warnings
from dataclasses import dataclass

from bgc.base.errors import Coord, ModelError
from bgc.base.limits import LIMITS

#: Functions an expression may call, with their number of arguments (None: any, at least one).
FUNCTIONS: dict[str, tuple[int, int | None]] = {
    "sin": (1, 1), "cos": (1, 1), "tan": (1, 1), "asin": (1, 1), "acos": (1, 1),
    "atan": (1, 1), "atan2": (2, 2), "sinh": (1, 1), "cosh": (1, 1), "tanh": (1, 1),
    "exp": (1, 1), "log": (1, 1), "sqrt": (1, 1), "abs": (1, 1), "sign": (1, 1),
    "min": (2, None), "max": (2, None), "where": (3, 3), "heaviside": (1, 1),
    "skew": (1, 1), "cross": (2, 2), "dot": (2, 2), "norm": (1, 1), "transpose": (1, 1),
    "eye": (1, 1), "zeros": (1, 2), "diag": (1, None), "inv": (1, 1), "det": (1, 1),
}
#: Functions whose argument names a bond, element or junction rather than a value.
BOND_FUNCTIONS = ("e", "f", "p", "q", "power")


class _Constants:
    """Named constants: the names are known without sympy, the values built on use."""

    def __contains__(self, name):
        return name == "pi"

    def __getitem__(self, name):
        if name != "pi":
            raise KeyError(name)
        import sympy

        return sympy.pi


CONSTANTS = _Constants()

#: Deepest nesting of an expression tree (a guard against stack exhaustion in later stages).
MAX_DEPTH = LIMITS.expr_depth
#: Largest magnitude of a number an expression may produce (10**MAX_EXPONENT).
MAX_EXPONENT = LIMITS.number_exponent

#: Names people write from other languages, with what bgc calls them.
HINTS = {"signum": "sign", "sgn": "sign", "ln": "log", "pow": "** (a ** b)",
         "arctan": "atan", "arctan2": "atan2", "arcsin": "asin", "arccos": "acos",
         "fabs": "abs", "minimum": "min", "maximum": "max", "exp10": "10 ** x",
         "ifelse": "where", "if_else": "where", "step": "heaviside", "identity": "eye"}

_BINOPS = (ast.Add, ast.Sub, ast.Mult, ast.Div, ast.Pow, ast.MatMult)
_CMPOPS = (ast.Lt, ast.LtE, ast.Gt, ast.GtE)


@dataclass(frozen=True)
class Expr:
    """An expression as written in the model, with the place of its first character."""

    text: str
    coord: Coord

    def tree(self) -> ast.expr:
        return check(self)

    def names(self) -> set[tuple[str, ...]]:
        """Dotted name paths used as values (not as arguments of e/f/p/q/power)."""
        out: set[tuple[str, ...]] = set()
        _collect(self.tree(), out)
        return out


def _collect(node: ast.AST, out: set) -> None:
    if isinstance(node, ast.Call):
        name = node.func.id  # checked: a plain name
        if name in BOND_FUNCTIONS:
            return
        for a in node.args:
            _collect(a, out)
        return
    path = dotted_path(node)
    if path is not None:
        if path[-1] == "T" and len(path) > 1:
            path = path[:-1]
        if path[0] not in CONSTANTS:
            out.add(path)
        return
    for child in ast.iter_child_nodes(node):
        _collect(child, out)


def dotted_path(node: ast.AST) -> tuple[str, ...] | None:
    """`a.b.c` -> ("a", "b", "c"); None for anything but a (dotted) name."""
    if isinstance(node, ast.Name):
        return (node.id,)
    if isinstance(node, ast.Attribute):
        head = dotted_path(node.value)
        return None if head is None else head + (node.attr,)
    return None


def _source(text: str) -> tuple[str, int]:
    """The text as one line (line breaks become spaces, so character offsets are kept) without
    its leading blanks, and the number of blanks removed."""
    src = text.replace("\r", " ").replace("\n", " ")
    body = src.lstrip(" \t")
    return body, len(src) - len(body)


def _at(expr: Expr, offset: int) -> Coord:
    """The place of the character at ``offset`` (0-based) in the expression's text."""
    text = expr.text
    line = text.count("\n", 0, offset)
    col = offset - (text.rfind("\n", 0, offset) + 1)
    return expr.coord.shifted(line, col)


def node_coord(expr: Expr, node: ast.AST) -> Coord:
    body, lead = _source(expr.text)
    col = getattr(node, "col_offset", 0)  # UTF-8 bytes into ``body``
    chars = len(body.encode("utf-8")[:col].decode("utf-8", "ignore"))
    return _at(expr, lead + chars)


def short_text(text: str) -> str:
    return repr(text) if len(text) <= 60 else repr(text[:57]) + "..."


#: Checked trees by text: whether a text passes depends on the text alone, and a large model
#: writes the same few laws ("R", "C") on thousands of elements, each read by several stages.
#: The trees are only read, never changed; an error is raised each time (its place is the
#: caller's Expr's). Bounded: cleared when full.
_CHECKED: dict[str, ast.expr] = {}
_CHECKED_MAX = 4096


def check(expr: Expr) -> ast.expr:
    """Parse ``expr`` and verify every node against the whitelist; return the tree."""
    text = expr.text
    tree = _CHECKED.get(text)
    if tree is not None:
        return tree
    tree = _checked(expr)
    if len(_CHECKED) >= _CHECKED_MAX:
        _CHECKED.clear()
    _CHECKED[text] = tree
    return tree


def _checked(expr: Expr) -> ast.expr:
    text = expr.text
    if len(text) > LIMITS.expr_chars:
        raise ModelError(expr.coord, f"expression is too long (over {LIMITS.expr_chars} "
                                     "characters, the limit of expression length)")
    body, lead = _source(text)
    if not body.strip():
        raise ModelError(expr.coord, "empty expression")
    try:
        with warnings.catch_warnings():  # e.g. "invalid decimal literal" for 1if: never shown
            warnings.simplefilter("ignore")
            tree = ast.parse(body, mode="eval")
    except SyntaxError as exc:
        off = lead + max((exc.offset or 1) - 1, 0) if (exc.lineno or 1) == 1 else lead
        raise ModelError(_at(expr, min(off, len(text))),
                         f"invalid expression {short_text(text)}: {_why(exc.msg)}") from None
    except (RecursionError, MemoryError):
        raise ModelError(expr.coord, "expression is nested too deeply") from None
    except ValueError as exc:  # e.g. null bytes, on some Python versions
        raise ModelError(expr.coord, f"invalid expression {short_text(text)}: {_why(exc)}") \
            from None
    _check_depth(expr, tree.body)
    _check_node(expr, tree.body)
    return tree.body


def _why(exc) -> str:
    """Python's reason, except for its limit on the digits of an integer literal, whose advice
    (sys.set_int_max_str_digits) is not the model's."""
    why = str(exc)
    if "integer string conversion" in why:
        return "a number with thousands of digits (numbers are doubles: at most about 1e308)"
    return why


def _check_depth(expr: Expr, root: ast.AST) -> None:
    stack = [(root, 1)]
    count = 0
    while stack:
        node, depth = stack.pop()
        count += 1
        if count > LIMITS.expr_nodes:
            raise ModelError(expr.coord, f"expression is too large (more than "
                                         f"{LIMITS.expr_nodes} syntax nodes, the limit of "
                                         "expression size)")
        if depth > MAX_DEPTH:
            raise ModelError(node_coord(expr, node), f"expression is nested too deeply "
                                                 f"(more than {MAX_DEPTH} levels)")
        stack.extend((child, depth + 1) for child in ast.iter_child_nodes(node))


def _check_node(expr: Expr, node: ast.AST, in_where: bool = False) -> None:
    bad = lambda msg: ModelError(node_coord(expr, node), msg)  # noqa: E731
    if isinstance(node, ast.Constant):
        v = node.value
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            r = repr(v)
            raise bad(f"only numbers are allowed as constants, not "
                      f"{r if len(r) <= 60 else r[:57] + '...'}")
        if isinstance(v, float) and not math.isfinite(v) or (
                isinstance(v, int) and abs(v) > 10 ** MAX_EXPONENT):
            raise bad(f"number {str(v)[:40]} is out of range")
        return
    if isinstance(node, ast.Name):
        return
    if isinstance(node, ast.Attribute):
        if dotted_path(node) is None:
            raise bad("attribute access is only allowed on names (component paths, .T)")
        for part in dotted_path(node):
            if part.startswith("_"):
                raise bad(f"name {part!r} is not allowed (leading underscore)")
        return
    if isinstance(node, ast.BinOp):
        if isinstance(node.op, ast.BitXor):
            raise bad("operator ^ is not allowed: write ** for a power (a ** b)")
        if not isinstance(node.op, _BINOPS):
            raise bad(f"operator {type(node.op).__name__} is not allowed")
        _check_node(expr, node.left)
        _check_node(expr, node.right)
        return
    if isinstance(node, ast.UnaryOp):
        if not isinstance(node.op, (ast.USub, ast.UAdd)):
            raise bad(f"operator {type(node.op).__name__} is not allowed")
        _check_node(expr, node.operand)
        return
    if isinstance(node, ast.Compare):
        if not in_where:
            raise bad("comparisons are only allowed as the condition of where(...)")
        if len(node.ops) != 1 or not isinstance(node.ops[0], _CMPOPS):
            raise bad("a condition is one comparison with <, <=, > or >=")
        _check_node(expr, node.left)
        _check_node(expr, node.comparators[0])
        return
    if isinstance(node, ast.List):
        if not node.elts:
            raise bad("empty list")
        for e in node.elts:
            _check_node(expr, e)
        return
    if isinstance(node, ast.Subscript):
        _check_node(expr, node.value)
        idx = node.slice
        parts = idx.elts if isinstance(idx, ast.Tuple) else [idx]
        if len(parts) > 2:
            raise bad("at most two indices")
        for part in parts:
            if isinstance(part, ast.Slice):
                for bound in (part.lower, part.upper):
                    if bound is not None:
                        int_const(expr, bound)
                if part.step is not None:
                    raise bad("slices with a step are not allowed")
            else:
                int_const(expr, part)
        return
    if isinstance(node, ast.Call):
        if not isinstance(node.func, ast.Name):
            raise bad("only the built-in functions may be called")
        name = node.func.id
        if node.keywords or any(isinstance(a, ast.Starred) for a in node.args):
            raise bad(f"{name}(): keyword and starred arguments are not allowed")
        if name in BOND_FUNCTIONS:
            if len(node.args) != 1 or dotted_path(node.args[0]) is None:
                raise bad(f"{name}() takes one name: a bond, element or junction")
            return
        if name not in FUNCTIONS:
            hint = f" (did you mean {HINTS[name]}?)" if name in HINTS else ""
            raise bad(f"unknown function {name!r}{hint}")
        lo, hi = FUNCTIONS[name]
        n = len(node.args)
        if n < lo or (hi is not None and n > hi):
            want = str(lo) if lo == hi else f"{lo} or more" if hi is None else f"{lo} to {hi}"
            raise bad(f"{name}() takes {want} argument(s), got {n}")
        for i, a in enumerate(node.args):
            _check_node(expr, a, in_where=(name == "where" and i == 0))
        return
    raise bad(f"{type(node).__name__} is not allowed in an expression")


def int_const(expr: Expr, node: ast.AST) -> int:
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
        return -int_const(expr, node.operand)
    if isinstance(node, ast.Constant) and type(node.value) is int:
        return node.value
    raise ModelError(node_coord(expr, node), "an index must be an integer constant")
