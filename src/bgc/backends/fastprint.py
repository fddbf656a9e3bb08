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

from contextlib import contextmanager

from sympy import Basic, Dummy, Mul, Pow, S, Symbol
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
_ADD = PRECEDENCE["Add"]
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
        self._dummy_names: dict = {}  # Dummy -> its text, while :meth:`renamed` names it
        self._methods: dict = {}  # class -> its printing method (_METHODS, for this printer)
        # the settings the sums' and products' rules depend on (fixed once made)
        self._own_add = self.order == "none"
        self._own_mul = self.order in ("old", "none")
        self._macros = getattr(self, "math_macros", None)  # C: pi/2 is M_PI_2, ...

    @contextmanager
    def renamed(self, names: dict):
        """Print each Symbol of ``names`` (Symbol -> text) as its text while the block runs:
        what printing ``expr.xreplace`` with symbols of those names gives, without building
        the replaced tree (a re-rolled function of 10,000 states printed 100,000 lines so:
        half its print time went on xreplace and the assumptions of the new products)."""
        plain = {s: t for s, t in names.items() if type(s) is Symbol}
        dummies = {s: t for s, t in names.items() if type(s) is Dummy}
        if len(plain) + len(dummies) != len(names):
            raise TypeError("renamed() takes Symbols and Dummies only")
        saved = []
        for cache, new in ((self._symbol_names, plain), (self._dummy_names, dummies)):
            saved.append({s: cache[s] for s in new if s in cache})
            cache.update(new)
        try:
            yield
        finally:
            for cache, new, before in zip((self._symbol_names, self._dummy_names),
                                          (plain, dummies), saved):
                for s in new:
                    del cache[s]
                cache.update(before)

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
        if type(expr) is Symbol and not kwargs:  # the commonest node: its text, once made
            got = self._symbol_names.get(expr)
            if got is None:
                got = self._symbol_names[expr] = self._symbol_text(expr)
            return got
        if self._dummy_names and type(expr) is Dummy and not kwargs:
            got = self._dummy_names.get(expr)
            if got is not None:
                return got
        method = self._methods.get(type(expr))
        if method is None:
            key = (type(self), type(expr))
            method = _METHODS.get(key)
            if method is None:
                method = _METHODS[key] = self._method_for(key[1])
            self._methods[key[1]] = method
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
        got = _CLASS_PRECEDENCE.get(type(item))
        if got is None:
            got = _class_precedence(type(item))
        if got is not _NOT_CONSTANT:
            return got
        if type(item) is Mul:
            # sympy's precedence_Mul: Add's where a minus sign can be pulled out, which needs
            # a negative number in front; else Mul's whatever the factors (its check of
            # functions among them gives Mul's too)
            args = item.args
            c = args[0]
            if not (c.is_Number and c.is_extended_negative):
                return _MUL
            if c.is_Rational or c.is_Float:
                # a finite negative coefficient: -item is not item, so the sign can be pulled
                # out (Add's), unless a factor is a function of lower precedence than Mul's
                for a in args:
                    if isinstance(a, Function) and getattr(a, "precedence", _MUL) < _MUL:
                        return _MUL
                return _ADD
            got = self._mul_precedence.get(item)
            if got is None:
                got = self._mul_precedence[item] = precedence(item)
            return got
        return precedence(item)

    def parenthesize(self, item, level, strict=False):
        p = _CLASS_PRECEDENCE.get(type(item))
        if p is None or p is _NOT_CONSTANT:
            p = self._prec(item)
        if p < level or (not strict and p <= level):
            return f"({self._print(item)})"
        return self._print(item)

    def _symbol_text(self, expr) -> str:
        """A Symbol's text as the printer's own dispatch makes it (a printer's names do not
        change once it is made: :meth:`_print` keeps each symbol's text)."""
        method = self._methods.get(Symbol)
        if method is None:
            method = self._methods[Symbol] = _METHODS.setdefault(
                (type(self), Symbol), self._method_for(Symbol))
        if method is False:
            return super()._print(expr)
        self._print_level += 1
        try:
            return method(self, expr)
        finally:
            self._print_level -= 1

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
        if order is not None or not self._own_add:
            return super()._print_Add(expr, order=order)
        prec = self._prec(expr)
        out = []
        for term in expr.args:
            t = self._print(term)
            if term.is_Add:
                out.append(f"+ ({t})")
                continue
            p = _CLASS_PRECEDENCE.get(type(term))
            if p is None or p is _NOT_CONSTANT:
                p = self._prec(term)
            sign = "+ "
            if t.startswith("-"):
                sign, t = "- ", t[1:]
            out.append(sign + (f"({t})" if p < prec else t))
        first = out[0]  # the first term's sign: none for +, a bare - for -
        out[0] = first[2:] if first[0] == "+" else "-" + first[2:]
        return " ".join(out)

    def _print_Mul(self, expr):
        macros = self._macros  # C: pi/2 is M_PI_2, 1/sqrt(2) M_SQRT1_2
        if not self._own_mul or (macros and expr in macros):
            return super()._print_Mul(expr)
        prec = self._prec(expr)
        sign, factors = _signed_factors(expr)
        num, den, grouped = [], [], []
        lone_power = None
        for f in factors:
            if f.is_Pow and f.exp.is_Rational and f.exp.is_negative and f.is_commutative:
                if f.exp is not S.NegativeOne:  # (a Rational equal to -1 is that one)
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


def _signed_factors(expr) -> tuple[str, tuple]:
    """The sign sympy's product printing writes in front of ``expr`` and the factors it
    prints after it: ("-", the factors of -expr) where the coefficient is a negative number,
    else ("", the factors). sympy takes them as ``Mul.make_args(_keep_coeff(-c, rest))`` from
    ``expr.as_coeff_Mul()``, which builds the product -expr; here the factors are read off
    ``expr.args`` where that is what those steps give (a coefficient of -1; one plain factor;
    several factors after the number), and only other products take sympy's steps."""
    args = expr.args
    c = args[0]
    if not (c.is_Number and c.is_extended_negative):
        return "", args
    rest = args[1:]
    neg = -c
    first = rest[0]
    if neg is S.One:  # _keep_coeff(1, rest) is rest itself
        return "-", (first.args if len(rest) == 1 and isinstance(first, Mul) else rest)
    if len(rest) > 1:  # rest is a product: its factors with the coefficient in front
        if not first.is_Number:
            return "-", (neg,) + rest
    elif first.is_Symbol or (first.is_Pow and first.base.is_Symbol):
        return "-", (neg, first)  # neg*first: a number times a symbol or its power
    c, e = expr.as_coeff_Mul()
    return "-", Mul.make_args(_keep_coeff(-c, e))


def integer_text(n: int) -> str:
    """An integer constant's text: as it is up to 2**53 (exact in a double), else the double
    the arithmetic would round it to anyway (a Python int past int64 makes numpy fall back to
    object arrays, and a C literal past it does not compile: sqrt(545886860014552054364993611)
    printed so failed to evaluate)."""
    if abs(n) <= 2**53:
        return str(n)
    try:
        return repr(float(n))
    except OverflowError:
        raise ValueError(f"integer constant {n} is beyond a double's range") from None
