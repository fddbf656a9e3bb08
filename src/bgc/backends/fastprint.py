"""What every expression printer of bgc shares: sympy's code printers made cheap per
expression, with the same text (issue 27: printing the 3R2S module called sympy's ``doprint``
8,700 times, and a third of that time went on work the text does not need).

:class:`FastPrinting` goes in front of a sympy code printer (``class P(FastPrinting,
NumPyPrinter)``) and changes no character of what it prints:

* ``doprint`` prints a sympy expression with ``_print`` straight away. sympy's ``doprint``
  first sympifies it, rebuilds it to drop ``re()`` around an ``UnevaluatedExpr`` (a walk and
  a rebuild of the whole tree per call; bgc never makes an ``UnevaluatedExpr``, and
  :meth:`FastPrinting._print_re` does the same thing where one appears) and sets up its
  bookkeeping; anything else (a target to assign to, a list, a number symbol to declare)
  goes the long way, through sympy's own ``doprint``.
* precedence, which sympy recomputes by walking the class hierarchy for every operand (and a
  product's by trying to pull a minus sign out of it), is worked out once per class where the
  class alone decides it, and once per product;
* the method that prints a class is looked up once per class, not along its hierarchy per
  node;
* sums and products are printed by sympy's rules (written here with the cached precedence):
  terms in the printer's order (bgc's printers use ``order="none"``: sympy's argument order),
  a leading minus pulled out, negative powers as a denominator; a lone denominator that a
  subclass prints as a product (``b*b`` for ``b**2``) in parentheses.
"""
from __future__ import annotations

from sympy import Basic, Mul, Pow, S
from sympy.core.expr import UnevaluatedExpr
from sympy.core.function import AppliedUndef, Function, UndefinedFunction
from sympy.core.mul import _keep_coeff
from sympy.printing.precedence import (
    PRECEDENCE,
    PRECEDENCE_FUNCTIONS,
    PRECEDENCE_VALUES,
    precedence,
)

_MUL = PRECEDENCE["Mul"]
_UNARY_MINUS = 0.5 * (PRECEDENCE["Pow"] + PRECEDENCE["Mul"])
_NOT_CONSTANT = object()
_CLASS_PRECEDENCE: dict[type, object] = {}  # class -> its precedence, where the class decides
_METHODS: dict[tuple[type, type], object] = {}  # (printer class, class) -> its printing method


def _class_precedence(cls: type):
    """The precedence every instance of ``cls`` has, or _NOT_CONSTANT where it depends on the
    instance (a number's sign, a product's factors, a ``precedence`` property)."""
    got = _CLASS_PRECEDENCE.get(cls)
    if got is not None:
        return got
    own = getattr(cls, "precedence", None)
    if own is not None:
        got = own if isinstance(own, (int, float)) else _NOT_CONSTANT
    else:
        got = PRECEDENCE["Atom"]
        for c in cls.__mro__:
            if c.__name__ in PRECEDENCE_FUNCTIONS:
                got = _NOT_CONSTANT
                break
            if c.__name__ in PRECEDENCE_VALUES:
                got = PRECEDENCE_VALUES[c.__name__]
                break
    _CLASS_PRECEDENCE[cls] = got
    return got


class FastPrinting:
    """A mixin in front of a sympy code printer: the same text, less work per expression."""

    #: exponents -k of a lone denominator factor b**-k that the printer writes as a product
    #: (b*b): that denominator is parenthesised (x/(b*b), not x/b*b)
    product_powers: tuple[int, ...] = ()

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._mul_precedence: dict = {}
        self._symbol_names: dict = {}

    def doprint(self, expr, assign_to=None):
        if assign_to is not None or not hasattr(expr, "func"):  # not a sympy expression
            return super().doprint(expr, assign_to)
        self._not_supported = set()
        self._number_symbols = set()
        text = self._print(expr)
        if self._not_supported or self._number_symbols or not self._settings["human"]:
            return super().doprint(expr, assign_to)  # the long way writes what these need
        return "\n".join(self._format_code(text.splitlines()))

    def _print(self, expr, **kwargs):
        key = (type(self), type(expr))
        method = _METHODS.get(key)
        if method is None:
            method = _METHODS[key] = self._method_for(key[1])
        if method is False or kwargs:
            return super()._print(expr, **kwargs)
        self._print_level += 1
        try:
            return method(self, expr)
        finally:
            self._print_level -= 1

    def _method_for(self, cls: type):
        """The printing method sympy's dispatch picks for every instance of ``cls``, or False
        where the pick may depend on the instance (objects that print themselves, functions,
        whose dispatch sympy treats apart) or there is none."""
        mro = cls.__mro__
        if (self.printmethod and hasattr(cls, self.printmethod)) or Function in mro \
                or AppliedUndef in mro or UndefinedFunction in mro or not issubclass(cls, Basic):
            return False
        for c in mro:
            method = getattr(type(self), "_print_" + c.__name__, None)
            if method is not None:
                return method
        return False

    def _prec(self, item):
        """sympy's ``precedence(item)``, from the cache where it can be."""
        got = _class_precedence(type(item))
        if got is not _NOT_CONSTANT:
            return got
        if type(item) is Mul:
            # sympy's precedence_Mul: Add's where a minus sign can be pulled out, which needs
            # a negative number in front; else Mul's whatever the factors (its check of
            # functions among them gives Mul's too)
            c = item.args[0]
            if not (c.is_Number and c.is_extended_negative):
                return _MUL
            got = self._mul_precedence.get(item)
            if got is None:
                got = self._mul_precedence[item] = precedence(item)
            return got
        return precedence(item)

    def parenthesize(self, item, level, strict=False):
        p = self._prec(item)
        if p < level or (not strict and p <= level):
            return f"({self._print(item)})"
        return self._print(item)

    def _print_Symbol(self, expr):
        got = self._symbol_names.get(expr)
        if got is None:
            got = self._symbol_names[expr] = super()._print_Symbol(expr)
        return got

    def _print_re(self, expr):
        arg = expr.args[0]
        if isinstance(arg, UnevaluatedExpr) and arg.args[0].is_real:
            return self._print(arg)  # what sympy's doprint rewrites re(UnevaluatedExpr) to
        return super()._print_re(expr)

    def _print_Add(self, expr, order=None):
        if order is not None or self.order != "none":
            return super()._print_Add(expr, order=order)
        prec = self._prec(expr)
        out = []
        for term in expr.args:
            t = self._print(term)
            sign = "+"
            if t.startswith("-") and not term.is_Add:
                sign, t = "-", t[1:]
            out.append(sign)
            out.append(f"({t})" if term.is_Add or self._prec(term) < prec else t)
        first = out.pop(0)
        return ("" if first == "+" else first) + " ".join(out)

    def _print_Mul(self, expr):
        macros = getattr(self, "math_macros", None)  # C: pi/2 is M_PI_2, 1/sqrt(2) M_SQRT1_2
        if self.order not in ("old", "none") or (macros and expr in macros):
            return super()._print_Mul(expr)
        prec = self._prec(expr)
        c, e = expr.as_coeff_Mul()
        sign = ""
        if c.is_extended_negative:  # c < 0 (c is a number), without sympifying the 0
            expr, sign = _keep_coeff(-c, e), "-"
        num, den, grouped = [], [], []
        lone_power = None
        for f in Mul.make_args(expr):
            if f.is_commutative and f.is_Pow and f.exp.is_Rational and f.exp.is_negative:
                if f.exp != -1:
                    den.append(Pow(f.base, -f.exp, evaluate=False))
                    lone_power = -f.exp
                else:
                    if len(f.args[0].args) != 1 and isinstance(f.base, Mul):
                        grouped.append(f)  # 1/(a*b) keeps its parentheses
                    den.append(f.base)  # = Pow(f.base, 1)
            else:
                num.append(f)
        num = num or [S.One]
        if len(num) == 1 and sign == "-":
            num_text = [self.parenthesize(num[0], _UNARY_MINUS)]
        else:
            num_text = [self.parenthesize(x, prec) for x in num]
        den_text = [self.parenthesize(x, prec) for x in den]
        for f in grouped:
            if f.base in den:
                k = den.index(f.base)
                den_text[k] = f"({den_text[k]})"
        if not den:
            return sign + "*".join(num_text)
        if len(den) > 1:
            return sign + "*".join(num_text) + "/(" + "*".join(den_text) + ")"
        d = den_text[0]
        if lone_power is not None and lone_power in self.product_powers:
            d = f"({d})"
        return sign + "*".join(num_text) + "/" + d
