"""The expression whitelist (bgc.format.expr): untrusted text is parsed, checked, never evaluated."""
from __future__ import annotations

import builtins
import string

import pytest
import sympy as sp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bgc.base.errors import Coord, ModelError
from bgc.format import expr as E

AT = Coord("m.yaml", 7, 10)


def ex(text: str) -> E.Expr:
    return E.Expr(text, AT)


class Symbols:
    """A resolver that makes every name a symbol (3-vectors for v*, 3x3 for M*)."""

    what = "test"

    def value(self, path, coord):
        name = "_".join(path)
        if name.startswith("v"):
            return sp.ImmutableMatrix(sp.symbols(f"{name}0:3"))
        if name.startswith("M"):
            return sp.ImmutableMatrix(3, 3, sp.symbols(f"{name}0:9"))
        return sp.Symbol(name)

    def bond(self, func, path, coord):
        return sp.Symbol(f"{func}_{'_'.join(path)}")


@pytest.fixture
def no_evaluation(monkeypatch):
    """Anything that would run user text fails the test."""
    def boom(*a, **k):
        raise AssertionError("evaluated!")
    for name in ("eval", "exec"):
        monkeypatch.setattr(builtins, name, boom)
    monkeypatch.setattr(sp, "sympify", boom)
    monkeypatch.setattr(sp, "parse_expr", boom, raising=False)
    yield


# ---------------------------------------------------------------------------------------------
# What is accepted


@pytest.mark.parametrize("text", [
    "1", "2.5e-3", "-k", "a + b*c - d/e**2", "M @ v", "M.T", "M[0, 2]", "M[:, 0]", "v[2]",
    "[1, 2, 3]", "[[a, b], [c, d]]", "where(t < 1, 0, F0)", "sin(x) + atan2(y, z)",
    "f(mass)", "e(link1.J)", "link1.R", "max(a, b, c)", "pi", "a +\n  b",
])
def test_accepted(text):
    E.check(ex(text))


@pytest.mark.parametrize("text,col,msg", [
    ("__import__('os').system('x')", 0, "only the built-in functions may be called"),
    ("().__class__", 0, "attribute access is only allowed on names"),
    ("a.__class__", 0, "leading underscore"),
    ("m.__dict__", 0, "leading underscore"),
    ("(lambda: 1)()", 0, "only the built-in functions may be called"),
    ("lambda: 1", 0, "Lambda is not allowed"),
    ("'abc'", 0, "only numbers are allowed as constants"),
    ("k * b'x'", 4, "only numbers are allowed as constants"),
    ("True", 0, "only numbers are allowed as constants"),
    ("eval(1)", 0, "unknown function 'eval'"),
    ("open('/etc/passwd')", 0, "unknown function 'open'"),
    ("max(a, key=b)", 0, "keyword and starred arguments"),
    ("max(*a)", 0, "keyword and starred arguments"),
    ("[x for x in a]", 0, "ListComp is not allowed"),
    ("{x: 1}", 0, "Dict is not allowed"),
    ("(a, b)", 0, "Tuple is not allowed"),
    ("a if b else c", 0, "IfExp is not allowed"),
    ("a < b", 0, "comparisons are only allowed"),
    ("a and b", 0, "BoolOp is not allowed"),
    ("a // b", 0, "FloorDiv is not allowed"),
    ("~a", 0, "Invert is not allowed"),
    ("k $ 2", 2, "invalid expression"),
    ("sin(1, 2)", 0, "sin() takes 1 argument(s), got 2"),
    ("a[b]", 2, "an index must be an integer constant"),
    ("a[::2]", 0, "slices with a step"),
    ("f(1)", 0, "f() takes one name"),
    ("1e999", 0, "out of range"),
    ("1j", 0, "only numbers are allowed as constants"),
    ("", 0, "empty expression"),
    ("(x := 1)", 1, "NamedExpr is not allowed"),
    ("a.b()", 0, "only the built-in functions may be called"),
    ("sin.__globals__", 0, "leading underscore"),
])
def test_refused(text, col, msg, no_evaluation):
    with pytest.raises(ModelError) as info:
        E.check(ex(text))
    assert msg in info.value.message
    assert info.value.coord == Coord("m.yaml", 7, 10 + col)


def test_error_columns_follow_the_text():
    # leading blanks are counted
    with pytest.raises(ModelError) as info:
        E.check(ex("   k $ 2"))
    assert info.value.coord == Coord("m.yaml", 7, 15)
    # a second line: 1-based column on that line
    with pytest.raises(ModelError) as info:
        E.check(ex("a +\n  eval(1)"))
    assert info.value.coord == Coord("m.yaml", 8, 3)
    # an offending node inside the text
    with pytest.raises(ModelError) as info:
        E.check(ex("a + b.__x"))
    assert info.value.coord == Coord("m.yaml", 7, 14)



def test_a_text_checked_before_is_still_located_at_each_use():
    """The whitelist keeps checked trees by text (a large model's thousands of "R"): an error
    in the same text is raised again at each expression's own place, and a tree shared by
    two places still gives each place its own columns."""
    for line in (3, 9):  # the same refused text twice: two errors, each at its own line
        with pytest.raises(ModelError) as info:
            E.check(E.Expr("a + b.__x", Coord("m.yaml", line, 5)))
        assert info.value.coord == Coord("m.yaml", line, 9)
    for line in (4, 11):  # an accepted text, then an error found while building it
        with pytest.raises(ModelError) as info:
            E.build(E.Expr("   v + a", Coord("m.yaml", line, 2)), Symbols())
        assert "shape mismatch" in info.value.message
        assert info.value.coord.line == line
    assert E.check(ex("k * x")) is E.check(E.Expr("k * x", Coord("n.yaml", 1, 1)))


def test_no_parenthesis_injection():
    # Text that only parses once wrapped in parentheses stays an error.
    for text in ["sin)(1", "a), (b", "a\n)(b"]:
        with pytest.raises(ModelError):
            E.check(ex(text))


@pytest.mark.parametrize("text", ["a+" * 5000 + "a", "-" * 19999 + "a", "a." * 5000 + "b",
                                  "a[0]" + "[0]" * 4000, "(" * 300 + "a" + ")" * 300,
                                  "-" * 300 + "a", "a+" * 250 + "a", "1" * 5000, "x" * 20001])
def test_pathological_text_is_a_model_error(text):
    with pytest.raises(ModelError):
        E.check(ex(text))


@pytest.mark.parametrize("text,msg", [
    ("9**9**9**9", "a number larger than 10**300"),
    ("10**400", "a number larger than 10**300"),
    ("0.5**-2000", "a number larger than 10**300"),
    ("(10**200) * (10**200)", "a number larger than 10**300"),
    ("1/0", "infinite or undefined"),
    ("log(0)", "infinite or undefined"),
    ("0**-1", "infinite or undefined"),
    ("v[3]", "index 3 is out of range for size 3"),
    ("M[0, 3]", "index 3 is out of range for size 3"),
    ("a[0]", "indexing a scalar"),
    ("v + a", "shape mismatch"),
    ("inv([[1, 2], [2, 4]])", "singular"),
])
def test_build_refuses(text, msg):
    with pytest.raises(ModelError) as info:
        E.build(ex(text), Symbols())
    assert msg in info.value.message
    assert info.value.message.startswith("test: ")  # names the owner of the expression


def test_build_values():
    assert E.build(ex("2**10"), Symbols()) == 1024
    assert E.build(ex("v[1]"), Symbols()) == sp.Symbol("v1")
    assert E.shape_of(E.build(ex("M @ v"), Symbols())) == (3, 1)


# ---------------------------------------------------------------------------------------------
# Properties


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.text(alphabet=string.printable, max_size=80))
def test_random_printable_text(text):
    """check() either accepts or raises ModelError, never anything else, never evaluates."""
    real_eval, real_exec = builtins.eval, builtins.exec
    calls = []
    builtins.eval = lambda *a, **k: calls.append(a)  # noqa: E731
    builtins.exec = lambda *a, **k: calls.append(a)  # noqa: E731
    try:
        E.check(ex(text))
    except ModelError as err:
        assert err.coord is not None and err.coord.file == "m.yaml"
        assert err.coord.line >= 7 and err.coord.column >= 1
    finally:
        builtins.eval, builtins.exec = real_eval, real_exec
    assert not calls


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.text(max_size=40))
def test_random_unicode_text(text):
    try:
        E.check(ex(text))
    except ModelError:
        pass


_atoms = st.sampled_from(["a", "b", "k", "t", "pi", "v", "M", "0", "1", "2", "0.5", "1e300",
                          "10", "99", "f(x)", "e(link.J)", "link.R", "M.T", "v[0]", "M[1, 2]",
                          "M[:, 0]", "[1, 2, 3]", "[[1, 0], [0, 1]]", "eye(3)", "zeros(3, 1)"])


def _combine(children):
    binop = st.tuples(children, st.sampled_from(["+", "-", "*", "/", "**", "@"]), children).map(
        lambda x: f"({x[0]} {x[1]} {x[2]})")
    unary = children.map(lambda c: f"-{c}")
    call1 = st.tuples(st.sampled_from(["sin", "exp", "log", "sqrt", "abs", "skew", "norm",
                                       "transpose", "inv", "det", "diag", "heaviside"]),
                      children).map(lambda x: f"{x[0]}({x[1]})")
    call2 = st.tuples(st.sampled_from(["atan2", "max", "cross", "dot"]), children,
                      children).map(lambda x: f"{x[0]}({x[1]}, {x[2]})")
    where = st.tuples(children, children, children).map(
        lambda x: f"where({x[0]} < 1, {x[1]}, {x[2]})")
    lst = st.lists(children, min_size=1, max_size=3).map(lambda xs: "[" + ", ".join(xs) + "]")
    index = children.map(lambda c: f"({c})[1]")
    return st.one_of(binop, unary, call1, call2, where, lst, index)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.recursive(_atoms, _combine, max_leaves=12))
def test_well_formed_expressions_build_or_refuse(text):
    """Whitelisted expressions either build into sympy values or raise ModelError."""
    e = ex(text)
    E.check(e)
    try:
        v = E.build(e, Symbols())
    except ModelError as err:
        assert err.message.startswith("test: ")
        return
    assert isinstance(v, (sp.Basic, sp.MatrixBase))


# ---------------------------------------------------------------------------------------------
# Bounded work: every refusal names its limit and comes fast (issue 10)


@pytest.mark.parametrize("text,msg", [
    # constants are evaluated in double precision: no sympy evaluation to unbounded precision
    ("where(exp(exp(exp(100))) > 1, k, m)", "not a finite number"),
    ("exp(exp(100))", "not a finite number"),
    ("exp(1000) - exp(1000)", "not a finite number"),
    ("sqrt(-1)", "complex"),
    ("k * sqrt(-2)", "complex"),
    ("log(-1)", "complex"),
    ("asin(2)", "complex"),
    ("(-8) ** 0.5", "complex"),
    # matrices and exponents
    ("eye(1000) @ eye(1000)", "size must be 1..64 (the limit of matrix size)"),
    ("zeros(65)", "size must be 1..64"),
    ("diag(" + ", ".join(["a"] * 70) + ")", "larger than the limit of matrix size"),
    ("x ** 100000", "the limit of exponents"),
])
def test_build_bounds(text, msg):
    with pytest.raises(ModelError) as info:
        E.build(ex(text), Symbols())
    assert msg in info.value.message, info.value.message


def test_symbolic_matrix_products_are_bounded():
    """A chain of symbolic products grows its entries geometrically: the work is counted."""
    names = ", ".join(f"[{', '.join(f'a{i}{j}' for j in range(8))}]" for i in range(8))
    m = f"[{names}]"
    text = " @ ".join([m] * 12)
    with pytest.raises(ModelError) as info:
        E.build(ex(text), Symbols())
    assert "the limit of symbolic work" in info.value.message


def test_expression_node_limit():
    text = "max(" + ", ".join(["a"] * 5500) + ")"  # 5500 names: shallow, under 20000 chars
    with pytest.raises(ModelError) as info:
        E.check(ex(text))
    assert "the limit of expression size" in info.value.message


def test_constant_conditions_are_decided_numerically():
    k, m = sp.Symbol("k"), sp.Symbol("m")
    assert E.build(ex("where(exp(100) > 1, k, m)"), Symbols()) == k
    assert E.build(ex("where(sin(10**300) > 2, k, m)"), Symbols()) == m
    assert E.build(ex("where(1 - 1e-300 < 1, k, m)"), Symbols()) == m  # as a double: equal
    # symbolic conditions stay symbolic
    assert isinstance(E.build(ex("where(x > 1, k, m)"), Symbols()), sp.Piecewise)


def test_numeric_agrees_with_sympy_on_ordinary_constants():
    """The double-precision evaluator against sympy's own evaluation (where that is cheap)."""
    for text in ["sqrt(2) * pi", "exp(3) / (1 + tan(0.3))", "atan2(-1, 2) + asinh_free",
                 "min(1, 2, -3) + max(4, 5) + abs(-7) + sign(-2)", "cosh(2) ** 1.5"]:
        if "free" in text:
            continue
        v = E.build(ex(text), Symbols())
        assert E.numeric(v) == pytest.approx(float(v.evalf(30)), rel=1e-13)


@pytest.mark.parametrize("text,hint", [("a ^ 2", "write ** for a power"),
                                       ("signum(x)", "did you mean sign?"),
                                       ("ln(x)", "did you mean log?")])
def test_hints(text, hint):
    with pytest.raises(ModelError) as info:
        E.check(ex(text))
    assert hint in info.value.message


def test_parsing_user_text_shows_no_warning():
    """Python warns about some text it still parses (1if x else y): bgc shows none of it."""
    import warnings

    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        for text in ["1if a else b", "0x1for", "a is 1"]:
            with pytest.raises(ModelError):
                E.check(ex(text))
    assert [str(w.message) for w in seen] == []
