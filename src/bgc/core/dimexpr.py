"""The dimension of an expression, as a :class:`~bgc.core.dimsys.Form`, from its syntax tree.

Products and quotients add and subtract dimensions; a power needs a constant exponent (``x**2``,
``x**0.5``, ``x**(1/3)``) unless base and exponent are dimensionless; ``+``, ``-``, comparisons,
``where``, ``min``, ``max``, ``atan2`` and list entries need operands of one dimension; ``sin``,
``exp``, ``log`` and the other transcendental functions need a dimensionless argument and give
a dimensionless result. The number 0 agrees with every dimension (``[0, 0, -m*g]``); other
numbers are dimensionless. A vector or matrix has one dimension for all its entries. What the
names mean is the caller's (:class:`Names`): an unknown name is a fresh unknown, so the stage
that resolves names reports it, not this one.
"""
from __future__ import annotations

import ast
from fractions import Fraction
from typing import Protocol

from bgc.base.errors import Coord
from bgc.core.dimsys import ANY, Form, System
from bgc.format.units import ZERO, dim
from bgc.format.whitelist import Expr, dotted_path, node_coord, short_text

ONE = Form(ZERO)
SECOND = Form(dim(s=1))

#: Functions of a dimensionless argument with a dimensionless value.
_TRANSCENDENTAL = ("sin", "cos", "tan", "asin", "acos", "atan", "sinh", "cosh", "tanh", "exp",
                   "log")
#: Functions whose arguments share one dimension, which is the value's.
_SAME = ("min", "max", "abs", "skew", "transpose", "norm", "diag")


class Names(Protocol):
    def value(self, path: tuple[str, ...]) -> Form | None: ...

    def bond(self, func: str, path: tuple[str, ...]) -> Form | None: ...


class DimEval:
    """Evaluates one expression's dimension; every equality it needs goes to ``system``."""

    def __init__(self, system: System, names: Names, expr: Expr, what: str):
        self.sys, self.names, self.expr, self.what = system, names, expr, what

    def run(self) -> Form | None:
        tree = self.expr.tree()
        return ANY if is_number(tree) else self.visit(tree)  # "stiffness: 200" is in N/m

    def at(self, node) -> Coord:
        return node_coord(self.expr, node)

    def same(self, node, a, b, how: str):
        """a and b must agree (``how`` says why); the result is the one that is not ANY."""
        self.sys.equate(a, b, self.at(node),
                        lambda x, y: f"{self.what}: {how} {x} and {y} (in "
                                     f"{short_text(self.expr.text)})")
        return b if a is ANY else a

    def dimensionless(self, node, a, how: str):
        self.sys.equate(a, ONE, self.at(node),
                        lambda x, _: f"{self.what}: {how} needs a dimensionless argument, "
                                     f"not {x} (in {short_text(self.expr.text)})")

    def visit(self, node):
        kind = type(node).__name__
        return getattr(self, "v_" + kind, self.v_other)(node)

    def v_other(self, node):
        return Form.var(self.sys.new_var(type(node).__name__))

    def v_Constant(self, node):
        return ANY if node.value == 0 else ONE

    def v_Name(self, node):
        if node.id == "pi":
            return ONE
        return self.names.value((node.id,))

    def v_Attribute(self, node):
        path = dotted_path(node)
        if path and path[-1] == "T" and len(path) > 1:
            path = path[:-1]
        return self.names.value(path) if path else self.v_other(node)

    def v_Subscript(self, node):
        return self.visit(node.value)

    def v_UnaryOp(self, node):
        return self.visit(node.operand)

    def v_List(self, node):
        return self.alike(node, node.elts, "entries of one list must share a dimension:")

    def alike(self, node, args, how: str):
        """Operands of one dimension; a number among them takes the others' (``t < 1``,
        ``T - 293.15``, ``[l / 2, 0, 1]``), and when all are numbers the result is
        dimensionless."""
        out = ANY
        dims = [n for n in args if not is_number(n)]
        for a in dims:
            out = self.same(a, out, self.visit(a), how)
        if len(dims) < len(args) and out is ANY and any(_constant(n) != 0 for n in args):
            return ONE
        return out

    def v_Compare(self, node):
        return self.alike(node, [node.left, node.comparators[0]], "cannot compare")

    def v_BinOp(self, node):
        op = node.op
        if isinstance(op, (ast.Add, ast.Sub)):
            word = "add" if isinstance(op, ast.Add) else "subtract"
            return self.alike(node, [node.left, node.right], f"cannot {word}")
        if isinstance(op, ast.Pow):
            return self.pow(node, self.visit(node.left), self.visit(node.right))
        a, b = self.factor(node.left), self.factor(node.right)
        if isinstance(op, (ast.Mult, ast.MatMult)):
            return ANY if a is ANY or b is ANY else a + b
        return ANY if a is ANY else a if b is ANY else a - b  # a / b

    def factor(self, node):
        """A factor of a product: a number there carries the unit its place needs (``3 * f``:
        3 N*s/m; ``sin(2 * t)``: 2 rad/s), an unknown that is 1 unless something says
        otherwise (bgc.core.dimsys.System.soft)."""
        if is_number(node) and not (isinstance(node, ast.Name) or _constant(node) == 0):
            return Form.var(self.sys.new_var("number", soft=True))
        return self.visit(node)

    def pow(self, node, a, b):
        n = _constant(node.right)
        if n is None:
            self.dimensionless(node.left, a, "a power with a variable exponent")
            self.dimensionless(node.right, b, "an exponent")
            return ONE
        return ANY if a is ANY else a.scaled(n)

    def v_Call(self, node):
        name = node.func.id
        args = node.args
        if name in ("e", "f", "p", "q", "power"):
            path = dotted_path(args[0])
            got = self.names.bond(name, path) if path else None
            return got if got is not None else self.v_other(node)
        if name in _SAME:
            return self.alike(node, args, f"{name}() of")
        if name == "where":
            self.visit(args[0])
            return self.alike(node, args[1:], "where() chooses between")
        vals = [self.visit(a) for a in args]
        return self.call(node, name, args, vals)

    def call(self, node, name, args, vals):
        if name in _TRANSCENDENTAL:
            self.dimensionless(args[0], vals[0], f"{name}()")
            return ONE
        if name == "atan2":
            self.same(node, vals[0], vals[1], "atan2() of")
            return ONE
        if name == "sqrt":
            return ANY if vals[0] is ANY else vals[0].scaled(Fraction(1, 2))
        if name in ("sign", "heaviside", "eye"):
            return ONE
        if name == "zeros":
            return ANY
        if name in ("cross", "dot"):
            return ANY if ANY in vals else vals[0] + vals[1]
        if name == "inv":
            return ANY if vals[0] is ANY else vals[0].scaled(-1)
        return self.v_other(node)  # det: its dimension depends on the matrix's size


def is_number(node) -> bool:
    """A constant: numbers and pi, with arithmetic and functions (``sqrt(2) * pi``)."""
    if isinstance(node, ast.Constant):
        return True
    if isinstance(node, ast.Call):
        return node.func.id not in ("e", "f", "p", "q", "power") and bool(node.args) and all(
            is_number(a) for a in node.args)
    if isinstance(node, ast.Name):
        return node.id == "pi"
    if isinstance(node, ast.UnaryOp):
        return is_number(node.operand)
    if isinstance(node, ast.BinOp):
        return is_number(node.left) and is_number(node.right)
    return False


def _constant(node) -> Fraction | None:
    """A constant exponent (``2``, ``-1``, ``0.5``, ``1/3``) as a fraction, else None."""
    if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)) \
            and not isinstance(node.value, bool):
        if abs(node.value) > 1000:
            return None
        return Fraction(node.value).limit_denominator(1000)
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        v = _constant(node.operand)
        return None if v is None else (-v if isinstance(node.op, ast.USub) else v)
    if isinstance(node, ast.BinOp) and isinstance(node.op, (ast.Div, ast.Mult, ast.Add, ast.Sub)):
        a, b = _constant(node.left), _constant(node.right)
        if a is None or b is None:
            return None
        if isinstance(node.op, ast.Div):
            return None if b == 0 else a / b
        return a * b if isinstance(node.op, ast.Mult) else a + b if isinstance(
            node.op, ast.Add) else a - b
    return None
