"""Fast symbolic kernels: differentiation and common-subexpression elimination in symengine.

sympy stays the IR of bgc (its printers write the generated code, its assumptions and
functions define the model's meaning), but its ``diff`` and ``cse`` are pure Python and were
two thirds of the compile time of the 3R2S (2.1 s of Jacobian derivatives, 1.7 s of CSE on
this machine). symengine, a C++ library with the same algebra, does both a hundred times
faster. Expressions cross over only where symengine's meaning is the same as sympy's:

* :func:`to_se` converts an expression whose every function is in :data:`_SAFE_FUNCS` (and
  whose numbers are integers, rationals or floats) and returns ``None`` for anything else
  (``Piecewise``, ``sign``, ``Min``, ``Heaviside``, ``atan2``...): the caller then uses sympy,
  so a model's meaning never depends on which engine differentiated it.
* :func:`from_se` converts back node by node, mapping every symbol to the very sympy symbol
  it came from (with its assumptions), through a memo so shared subtrees convert once.
* :func:`cse` (only) passes the functions of :data:`_OPAQUE` (atan2) over as symengine
  functions of no meaning: CSE reads their arguments, and nothing there evaluates them.
* :func:`free_symbols` is sympy's ``free_symbols`` by one walk of the tree.

Both engines' results are deterministic: symengine orders terms by its own structural hash,
which does not depend on Python's hash seed (checked by tests/test_golden.py across seeds).
"""
from __future__ import annotations

import sympy as sp

try:  # optional at import time: bgc works without it, only slower
    import symengine as se
except ImportError:  # pragma: no cover - exercised by the fallback test
    se = None

#: sympy function classes that symengine implements with the same meaning and derivative.
_SAFE_FUNCS = {sp.sin: "sin", sp.cos: "cos", sp.tan: "tan", sp.asin: "asin",
               sp.acos: "acos", sp.atan: "atan", sp.sinh: "sinh", sp.cosh: "cosh",
               sp.tanh: "tanh", sp.exp: "exp", sp.log: "log"}


_ADD, _MUL, _POW, _SYMBOL = (se.Add, se.Mul, se.Pow, se.Symbol) if se else (None,) * 4
_SP_ADD, _SP_MUL = sp.Add._from_args, sp.Mul._from_args
_SE_OPS = {sp.Add: se.Add, sp.Mul: se.Mul, sp.Pow: se.Pow} if se else {}
_MISSING = object()

#: sympy functions that common-subexpression elimination passes through symengine as
#: undefined functions of the same name (nothing there evaluates or rewrites them; CSE reads
#: only their arguments): an output angle atan2(y, x) kept the 3R2S's outputs in sympy's cse,
#: a tenth of its lowering
_OPAQUE = {sp.atan2: "atan2"}
_OPAQUE_BACK = {v: k for k, v in _OPAQUE.items()}


def _opaque(name: str):
    return lambda *args: se.function_symbol(name, *args)


def available() -> bool:
    return se is not None


class Bridge:
    """Conversions sympy <-> symengine for one compilation (symbols keep their identity)."""

    def __init__(self, opaque: bool = False):
        """``opaque``: the functions of :data:`_OPAQUE` cross over too, as symengine functions
        of no meaning (for CSE only: never differentiate through such a bridge)."""
        self.sym_back: dict = {}  # symengine Symbol -> original sympy Symbol
        self._to: dict = {}  # sympy expr -> symengine expr (None: not convertible)
        self._back: dict = {}
        self._se_funcs = {k: getattr(se, v) for k, v in _SAFE_FUNCS.items()} if se else {}
        if opaque and se is not None:
            self._se_funcs.update({k: _opaque(v) for k, v in _OPAQUE.items()})
        self._back_funcs = {v: k for k, v in _SAFE_FUNCS.items()}

    # -- sympy -> symengine ------------------------------------------------------------------
    def to_se(self, e):
        if se is None:
            return None
        try:
            return self._to[e]
        except KeyError:
            pass
        out = self._convert(e)
        self._to[e] = out
        return out

    def _convert(self, e):
        t = type(e)
        if t is sp.Add or t is sp.Mul or t is sp.Pow:  # the most common nodes, first
            args = self._args_to(e)
            if args is None:
                return None
            return _SE_OPS[t](*args)
        if e.is_Symbol:
            if e.is_commutative is False:
                return None
            s = se.Symbol(e.name)
            prev = self.sym_back.setdefault(s, e)
            return s if prev == e else None  # two sympy symbols of one name: refuse
        if e.is_Integer:
            return se.Integer(int(e))
        if e.is_Rational:
            return se.Rational(int(e.p), int(e.q))
        if e.is_Float:
            return se.RealDouble(float(e))
        if e is sp.pi:
            return se.pi
        f = self._se_funcs.get(e.func)
        if f is None:
            return None
        args = self._args_to(e)
        return None if args is None else f(*args)

    def _args_to(self, e) -> list | None:
        """``e``'s arguments in symengine (the memo read inline), or None if one is not."""
        memo = self._to
        args = []
        for a in e.args:
            c = memo.get(a, _MISSING)
            if c is _MISSING:
                c = self.to_se(a)
            if c is None:
                return None
            args.append(c)
        return args

    # -- symengine -> sympy ------------------------------------------------------------------
    def from_se(self, e):
        try:
            return self._back[e]
        except KeyError:
            pass
        out = self._unconvert(e)
        self._back[e] = out
        return out

    def _args_back(self, e) -> list:
        """``e``'s arguments converted back (the memo read inline: most are met before)."""
        back = self._back
        out = []
        for a in e.args:
            v = back.get(a)
            out.append(self.from_se(a) if v is None else v)
        return out

    def _unconvert(self, e):
        t = type(e)
        # symengine's result is already canonical in its own algebra: build the sympy node
        # without sympy's (slow) re-canonicalisation; its meaning is the same. _from_args is
        # what Add(*args, evaluate=False) does, less the constructor cache's hashing of args
        # (a third of the 3R2S's CSE time); every node converted is commutative (real
        # symbols, numbers and the functions of _SAFE_FUNCS of them), which _from_args would
        # otherwise ask each argument again
        if t is _ADD:
            return _SP_ADD(self._args_back(e), is_commutative=True)
        if t is _MUL:
            return _SP_MUL(self._args_back(e), is_commutative=True)
        if t is _SYMBOL:
            s = self.sym_back.get(e)
            return s if s is not None else sp.Symbol(str(e), real=True)
        if t is _POW:
            if e.args[0] == se.E:  # symengine writes exp(z) as E**z
                return sp.exp(self.from_se(e.args[1]))
            return sp.Pow(*self._args_back(e), evaluate=False)
        return self._unconvert_other(e)

    def _unconvert_other(self, e):
        """Numbers, constants and functions (and the rare subclasses of the types above)."""
        if isinstance(e, se.Symbol):
            s = self.sym_back.get(e)
            return s if s is not None else sp.Symbol(str(e), real=True)
        if e.is_Number:
            if isinstance(e, se.RealDouble):
                return sp.Float(float(e))
            if e.is_integer:
                return sp.Integer(int(e))
            return sp.Rational(str(e))  # "p/q"
        if e == se.pi:
            return sp.pi
        if e == se.E:
            return sp.E
        if isinstance(e, se.Pow) and e.args[0] == se.E:
            return sp.exp(self.from_se(e.args[1]))
        args = self._args_back(e)
        if isinstance(e, se.Add):
            return sp.Add._from_args(args)
        if isinstance(e, se.Mul):
            return sp.Mul._from_args(args)
        if isinstance(e, se.Pow):
            return sp.Pow(*args, evaluate=False)
        if isinstance(e, se.FunctionSymbol):  # (only an opaque bridge makes them)
            f = _OPAQUE_BACK.get(e.get_name())
            if f is not None:
                # rebuilt as it was, unevaluated: CSE only named some of its arguments'
                # parts (sympy's evaluation of atan2 asks its arguments' signs: 10 ms each)
                return f(*args, evaluate=False)
        else:
            f = self._back_funcs.get(type(e).__name__.lower())
        if f is None:
            # symengine's own form of something it produced (e.g. a derivative it could not
            # evaluate); let sympy read it, then refuse if meaning could differ
            raise _Unsupported(str(e))
        return f(*args)


#: per node class, how its free symbols are found: _FREE_SELF (the node itself), _FREE_ARGS
#: (its arguments': sympy's generic rule) or _FREE_OWN (the class's own rule: bound variables)
_FREE_SELF, _FREE_ARGS, _FREE_OWN = 0, 1, 2
_RULE: dict = {}


def _rule(t) -> int:
    for k in t.__mro__:
        if "free_symbols" in k.__dict__:
            rule = _FREE_SELF if k is sp.Symbol else _FREE_ARGS if k is sp.Basic else _FREE_OWN
            break
    else:  # pragma: no cover - every sympy class inherits Basic's
        rule = _FREE_OWN
    _RULE[t] = rule
    return rule


def free_symbols(e) -> set:
    """``e.free_symbols``, found by one walk of the tree (sympy builds a set at every node and
    unites them on the way up); a class with its own rule (bound variables) keeps it. Pure
    sympy: what the forward sweep and the lowering ask of every expression they read."""
    out = set()
    stack = [e]
    rules = _RULE
    while stack:
        n = stack.pop()
        t = type(n)
        rule = rules.get(t)
        if rule is None:
            rule = _rule(t)
        if rule == _FREE_ARGS:
            stack.extend(n.args)
        elif rule == _FREE_SELF:
            out.add(n)
        else:
            out |= n.free_symbols
    return out


class _Unsupported(Exception):
    pass


def partials(bridge: Bridge, expr, symbols) -> dict | None:
    """{s: d expr / d s} for the given symbols (nonzero only), through symengine; ``None``
    when the expression is not convertible (the caller differentiates with sympy)."""
    x = bridge.to_se(expr)
    if x is None:
        return None
    out = {}
    try:
        for s in symbols:
            d = x.diff(bridge.to_se(s))
            if d != 0:
                out[s] = d
    except (RuntimeError, TypeError):
        return None
    return out


def cse(exprs: list, make_symbol) -> tuple[list, list] | None:
    """Common subexpressions of ``exprs`` (sympy) through symengine: (replacements as
    (sympy symbol, sympy expr), reduced sympy exprs); ``None`` if any expression is not
    convertible (the caller uses sympy's cse)."""
    if se is None:
        return None
    bridge = Bridge(opaque=True)
    conv = []
    for e in exprs:
        c = bridge.to_se(e)
        if c is None:
            return None
        conv.append(c)
    repl, reduced = se.cse(conv)
    try:
        out_repl = []
        for s, e in repl:
            ns = make_symbol()
            v = bridge.from_se(e)
            bridge.sym_back[s] = ns
            bridge._back[s] = ns
            out_repl.append((ns, v))
        return out_repl, [bridge.from_se(r) for r in reduced]
    except _Unsupported:
        return None
