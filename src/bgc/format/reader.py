"""Reading YAML safely, with a place for every value: the guarded loader (no aliases, bounded
depth), the node reader that types each value and reports ``file:line:col``, and the name
check every identifier passes before it can reach generated code. Shared by the model reader
(bgc.format.parse), the scene reader, tables and sweeps."""
from __future__ import annotations

import builtins
import keyword
import re

import yaml

from bgc.base.errors import Coord, ModelError
from bgc.base.limits import LIMITS
from bgc.format.whitelist import BOND_FUNCTIONS, FUNCTIONS, Expr, check

IDENT = re.compile(r"[A-Za-z][A-Za-z0-9_]*")  # always used with fullmatch
#: Names a model may not give a parameter, input, state or effect: the expression language's
#: functions, bgc's own words, and every name the generated module uses in the functions where
#: model names become locals (``tests/test_names.py`` renders modules and checks that each such
#: name is here, so a parameter can never shadow the module's own variables or imports).
RESERVED = frozenset({
    # the expression language's own words
    "t", "pi",
    # what the generated functions that bind model names as locals read themselves: their
    # arguments (rhs(t, x, p, u), the array namespace xp) and the modules their bodies call
    # (numpy as np, scipy, math), and the error a Newton loop raises. Every other local of
    # the module starts with "_", which no model name can (see check_name).
    "x", "p", "u", "xp", "np", "numpy", "scipy", "math", "SimulationError"}
    | set(FUNCTIONS) | set(BOND_FUNCTIONS))
MAX_CARDINALITY = LIMITS.cardinality
_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")  # always with fullmatch


_BUILTINS = frozenset(dir(builtins))  # (once: dir() per name was a tenth of parsing a big model)


def check_name(name, coord: Coord, what: str, allow_reserved: bool = False) -> str:
    """Validate an identifier before it can reach generated code."""
    if not isinstance(name, str) or not IDENT.fullmatch(name):
        raise ModelError(coord, f"invalid {what} name {name!r}: use letters, digits and _ , "
                                "starting with a letter")
    if "__" in name:
        raise ModelError(coord, f"invalid {what} name {name!r}: double underscores are reserved")
    if len(name) > 64:
        raise ModelError(coord, f"invalid {what} name {name[:20]!r}...: longer than 64 characters")
    if keyword.iskeyword(name) or name in _BUILTINS:
        raise ModelError(coord, f"invalid {what} name {name!r}: a Python keyword or builtin")
    if not allow_reserved and name in RESERVED:
        raise ModelError(coord, f"invalid {what} name {name!r}: reserved by bgc")
    return name


MAX_YAML_DEPTH = LIMITS.yaml_depth


class _Refused(Exception):
    def __init__(self, mark, message: str):
        self.mark, self.message = mark, message


class _Guard:
    """The safe composer, refusing aliases (shared nodes could expand exponentially, or form
    cycles) and absurd nesting."""

    _depth = 0

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            ev = self.peek_event()
            raise _Refused(ev.start_mark, f"YAML alias *{ev.anchor} is not allowed in a model")
        self._depth += 1
        try:
            if self._depth > MAX_YAML_DEPTH:
                raise _Refused(self.peek_event().start_mark,
                               f"YAML nested more than {MAX_YAML_DEPTH} levels deep")
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


class _Loader(_Guard, yaml.SafeLoader):
    """PyYAML's pure-Python loader (its messages and places are the ones bgc reports)."""


try:  # libyaml's event parser, when PyYAML was built with it: ~6x faster on large files
    from yaml._yaml import CParser as _CParser
except ImportError:  # pragma: no cover - PyYAML without libyaml
    _CParser = None

if _CParser is not None:
    class _FastLoader(_Guard, yaml.composer.Composer, _CParser, yaml.constructor.SafeConstructor,
                      yaml.resolver.Resolver):
        """libyaml's events, composed into nodes by PyYAML's (guarded) composer."""

        def __init__(self, stream):
            _CParser.__init__(self, stream)
            yaml.composer.Composer.__init__(self)
            yaml.constructor.SafeConstructor.__init__(self)
            yaml.resolver.Resolver.__init__(self)

        def compose_scalar_node(self, anchor):
            node = super().compose_scalar_node(anchor)
            node.style = node.style or None  # libyaml says '' for plain, PyYAML None
            return node
else:  # pragma: no cover
    _FastLoader = None


class Reader:
    def __init__(self, path: str, text: str):
        self.path = path
        self.text = text

    def coord(self, node) -> Coord:
        m = node.start_mark
        return Coord(self.path, m.line + 1, m.column + 1)

    def expr_coord(self, node) -> Coord:
        c = self.coord(node)
        if isinstance(node, yaml.ScalarNode) and node.style in ("'", '"'):
            return Coord(c.file, c.line, c.column + 1)
        if isinstance(node, yaml.ScalarNode) and node.style in ("|", ">"):
            return Coord(c.file, c.line + 1, c.column + 2)
        return c

    def _mark(self, m) -> Coord:
        return Coord(self.path, m.line + 1, m.column + 1) if m else Coord(self.path, 1, 1)

    def compose(self):
        if _FastLoader is not None:
            loader = _FastLoader(self.text)
            try:
                return loader.get_single_node()
            except _Refused as exc:
                raise ModelError(self._mark(exc.mark), exc.message) from None
            except Exception:  # noqa: BLE001 - a YAML error: the pure-Python loader below
                pass  # reports it with PyYAML's message and place
            finally:
                loader.dispose()
        try:
            return yaml.compose(self.text, Loader=_Loader)
        except _Refused as exc:
            raise ModelError(self._mark(exc.mark), exc.message) from None
        except yaml.MarkedYAMLError as exc:
            m = exc.problem_mark or exc.context_mark
            msg = f"YAML syntax error: {exc.problem or exc.context}"
            cm = exc.context_mark
            if exc.problem and exc.context and cm and cm is not m:
                msg += f" ({exc.context} at line {cm.line + 1}, column {cm.column + 1})"
            raise ModelError(self._mark(m), msg) from None
        except yaml.reader.ReaderError as exc:  # a character YAML does not allow
            before = self.text[:exc.position]
            line = before.count("\n") + 1
            col = exc.position - (before.rfind("\n") + 1) + 1
            ch = exc.character
            ch = f"U+{ch:04X}" if isinstance(ch, int) else repr(ch)
            raise ModelError(Coord(self.path, line, col),
                             f"YAML error: character {ch} is not allowed") from None
        except yaml.YAMLError as exc:
            raise ModelError(Coord(self.path, 1, 1),
                             "YAML error: " + " ".join(str(exc).split())) from None
        except RecursionError:
            raise ModelError(Coord(self.path, 1, 1), "YAML nested too deeply") from None

    def mapping(self, node, what: str) -> dict:
        """key -> (key node, value node), refusing duplicates and non-string keys."""
        if not isinstance(node, yaml.MappingNode):
            raise ModelError(self.coord(node), f"{what} must be a mapping")
        out: dict = {}
        for k, v in node.value:
            if not isinstance(k, yaml.ScalarNode) or k.tag == "tag:yaml.org,2002:merge":
                raise ModelError(self.coord(k), f"{what}: keys must be plain names")
            key = k.value
            if key in out:
                raise ModelError(self.coord(k), f"{what}: duplicate key {key!r}")
            out[key] = (k, v)
        return out

    def seq(self, node, what: str) -> list:
        if not isinstance(node, yaml.SequenceNode):
            raise ModelError(self.coord(node), f"{what} must be a list")
        return node.value

    def scalar(self, node, what: str):
        """A plain scalar value: int, float, str, bool or None."""
        if not isinstance(node, yaml.ScalarNode):
            raise ModelError(self.coord(node), f"{what} must be a single value")
        tag = node.tag
        v = node.value
        if tag.endswith(":int") or tag.endswith(":float"):
            return self._yaml_number(node, what)
        if tag.endswith(":bool"):
            return v.lower() in ("true", "yes", "on")
        if tag.endswith(":null"):
            return None
        if tag.endswith(":str"):
            return v
        raise ModelError(self.coord(node), f"{what}: YAML tag {tag!r} is not allowed")

    def _yaml_number(self, node, what: str):
        """A YAML int or float scalar: finite, within range, in a decimal spelling."""
        v = node.value
        text = v.replace("_", "").strip()
        bad = lambda why: ModelError(self.coord(node), f"{what}: {why}")  # noqa: E731
        if ":" in text:
            raise bad(f"{short(v)} is a sexagesimal (base 60) number: write it in decimal")
        low = text.lower().lstrip("+-")
        if low in (".inf", ".nan", "inf", "nan"):
            raise bad(f"{short(v)} is not a finite number")
        if len(text) > 400:
            raise bad(f"number {short(v)} is out of range (more than 400 characters)")
        if node.tag.endswith(":int"):
            try:
                n = int(text, 0)
            except ValueError:
                n = None
            if n is None:  # YAML 1.1 octal such as 017, or a spelling int() does not read
                if _NUMBER.fullmatch(text):
                    n = int(float(text))
                else:
                    raise bad(f"number {short(v)}: use a decimal spelling")
            if abs(n) > 10 ** LIMITS.number_exponent:
                raise bad(f"number {short(v)} is out of range (larger than "
                          f"10**{LIMITS.number_exponent})")
            return n
        try:
            x = float(text)
        except ValueError:
            raise bad(f"number {short(v)}: use a decimal spelling") from None
        return finite_number(x, lambda why: bad(f"number {short(v)} {why}"))

    def string(self, node, what: str) -> str:
        v = self.scalar(node, what)
        if not isinstance(v, str):
            raise ModelError(self.coord(node), f"{what} must be text")
        return v

    def number(self, node, what: str) -> float:
        v = self.scalar(node, what)
        if isinstance(v, bool) or v is None:
            raise ModelError(self.coord(node), f"{what} must be a number")
        if isinstance(v, str):
            if _NUMBER.fullmatch(v.strip()):
                return finite_number(float(v), lambda why: ModelError(
                    self.coord(node), f"{what}: number {short(v)} {why}"))
            raise ModelError(self.coord(node), f"{what} must be a number, not {short(v)}")
        return finite_number(float(v), lambda why: ModelError(self.coord(node), f"{what}: {why}"))

    def integer(self, node, what: str) -> int:
        v = self.scalar(node, what)
        if isinstance(v, bool) or not isinstance(v, int):
            raise ModelError(self.coord(node), f"{what} must be a whole number")
        return v

    def expr(self, node, what: str) -> Expr:
        """An expression: a number, a string, or a (nested) list of those."""
        if isinstance(node, yaml.SequenceNode):
            text = self._list_text(node, what)
            e = Expr(text, self.expr_coord(node))
        else:
            v = self.scalar(node, what)
            if v is None or isinstance(v, bool):
                raise ModelError(self.coord(node), f"{what} must be an expression")
            e = Expr(str(v) if not isinstance(v, float) else repr(v), self.expr_coord(node))
        try:
            check(e)
        except ModelError as exc:
            raise ModelError(exc.coord, f"{what}: {exc.message}") from None
        return e

    def _list_text(self, node, what) -> str:
        parts = []
        for item in node.value:
            if isinstance(item, yaml.SequenceNode):
                parts.append(self._list_text(item, what))
            else:
                e = self.expr(item, what)
                parts.append("(" + e.text + ")")
        return "[" + ", ".join(parts) + "]"

    def shape(self, node, what: str) -> tuple[int, ...]:
        if isinstance(node, yaml.ScalarNode):
            n = self.integer(node, what)
            dims = (n,)
        else:
            dims = tuple(self.integer(d, what) for d in self.seq(node, what))
        if len(dims) > 2 or any(d < 1 or d > MAX_CARDINALITY for d in dims):
            raise ModelError(self.coord(node), f"{what}: a shape is [], [n] or [n, m] "
                                               f"with 1 <= n, m <= {MAX_CARDINALITY}")
        if len(dims) == 1 and dims[0] == 1:
            dims = ()
        return dims

    def keys(self, m: dict, allowed, what: str, required=()):
        for key, (kn, _) in m.items():
            if key not in allowed:
                raise ModelError(self.coord(kn), f"{what}: unknown key {key!r} "
                                                 f"(expected one of: {', '.join(allowed)})")
        for key in required:
            if key not in m:
                return key
        return None


def short(v) -> str:
    """A user's text in a message: its repr, cut to 60 characters."""
    s = repr(v)
    return s if len(s) <= 60 else s[:56] + "...'"


def finite_number(x: float, err) -> float:
    """``x`` if it is a finite double within 10**number_exponent; else ``err(why)`` raised."""
    import math

    if not math.isfinite(x):
        raise err("is not finite (it overflows a double)" if x == x else "is not a number")
    if abs(x) > 10.0 ** LIMITS.number_exponent:
        raise err(f"is out of range (larger than 10**{LIMITS.number_exponent})")
    return x


def require(r: Reader, m: dict, node, allowed, what: str, required=()):
    missing = r.keys(m, allowed, what, required)
    if missing:
        raise ModelError(r.coord(node), f"{what}: missing key {missing!r}")


def outside(v: float, lo, hi) -> tuple[str, str, float] | None:
    """Where v lies outside a parameter's [min, max]: ("below", "min", lo) or ("above", "max",
    hi); None within (an absent bound does not bound). The one check for a model's own value,
    a scene's or sweep's value and a component instance's number."""
    if lo is not None and v < lo:
        return "below", "min", lo
    if hi is not None and v > hi:
        return "above", "max", hi
    return None


def param_value(r: Reader, pname: str, node):
    if isinstance(node, yaml.SequenceNode):
        rows = []
        for row in node.value:
            if isinstance(row, yaml.SequenceNode):
                rows.append(tuple(r.number(c, f"parameter {pname!r}") for c in row.value))
            else:
                rows.append((r.number(row, f"parameter {pname!r}"),))
        if not rows or not all(rows):
            raise ModelError(r.coord(node), f"parameter {pname!r}: an empty matrix or row")
        if len({len(x) for x in rows}) != 1:
            raise ModelError(r.coord(node), f"parameter {pname!r}: rows of different lengths")
        dim = LIMITS.matrix_dim
        if len(rows) > dim or len(rows[0]) > dim:
            raise ModelError(r.coord(node), f"parameter {pname!r}: a {len(rows)}x{len(rows[0])} "
                                            f"matrix is larger than the limit of matrix size "
                                            f"({dim} rows or columns)")
        return tuple(rows)
    v = r.scalar(node, f"parameter {pname!r}")
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        return r.number(node, f"parameter {pname!r}")
    if isinstance(v, str) and _NUMBER.fullmatch(v.strip()):
        return r.number(node, f"parameter {pname!r}")
    if isinstance(v, str):
        return r.expr(node, f"parameter {pname!r}")
    raise ModelError(r.coord(node), f"parameter {pname!r} must be a number, a matrix or an "
                                    "expression")


def read_stabilisation(r: Reader, node) -> tuple[float | None, bool]:
    """A model's ``constraints: {stabilisation: alpha, initial: check | project}``: alpha a
    positive rate in 1/s, at most 1e6 (None: the default); True where the initial state is to be
    projected onto the constraints."""
    m = r.mapping(node, "constraints")
    require(r, m, node, ("stabilisation", "initial"), "constraints")
    project = False
    if "initial" in m:
        vn = m["initial"][1]
        word = r.scalar(vn, "constraints: initial")
        if word not in ("check", "project"):
            raise ModelError(r.coord(vn), f"constraints: initial must be 'check' or 'project', "
                                          f"got {short(str(word))!r}")
        project = word == "project"
    if "stabilisation" not in m:
        return None, project
    vn = m["stabilisation"][1]
    alpha = r.number(vn, "constraints: stabilisation")
    if not (0 < alpha <= 1e6):
        raise ModelError(r.coord(vn), f"constraints: stabilisation {alpha!r} is not a rate in "
                                      "(0, 1e6] 1/s (the constraint violation's decay rate)")
    return float(alpha), project
