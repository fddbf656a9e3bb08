"""Dimensional analysis of a flat bond graph: every bond's effort and flow get a dimension.

Run on the flat graph (bgc.core.graph) before the equations. The declared units (parameters,
inputs, states, outputs; bgc.format.units) and the laws fix dimensions; what nothing fixes
stays unknown and is never an error, so a model without units checks as before. The laws, in
the order they are added (the first law that contradicts those before it is the one reported):

1. parameters: a declared unit is a fact; a derived parameter equals its expression; a
   component parameter bound at an instance has its expression's dimension (and must match
   the unit the component declares for it, if any);
2. junctions: the bonds on a 0- or 1-junction carry efforts of one dimension and flows of one
   dimension (a sum needs terms of one dimension);
3. sources (e or f = the expression), storage (I: p = integral of e, f = p / inertia; C: q =
   integral of f, e = stiffness q = q / compliance), two-ports (TF/MTF: f2 = M f1 and
   e1 = M e2; GY/MGY: e2 = M f1 and e1 = M f2), then resistors (e = R f, or their laws);
4. auxiliary states (derivative = state / s), input defaults, initial values, outputs.

Declared units of inputs and states are facts like parameters'; outputs' are checked last.

:func:`check_units` raises the located error; its result, :class:`UnitReport`, gives each
bond's dimensions and physical domain (``bgc check --units``).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from fractions import Fraction

from bgc.base.errors import ModelError
from bgc.core.dimexpr import SECOND
from bgc.core.dimnames import Checker, unit_of
from bgc.core.dimsys import Form
from bgc.format.units import dim, show
from bgc.format.whitelist import Expr, short_text

_NEWTON = dim(kg=1, m=1, s=-2)
#: (effort, flow) dimensions -> the domain's name.
DOMAINS = {
    (_NEWTON, dim(m=1, s=-1)): "mechanical translation",
    (dim(kg=1, m=2, s=-2), dim(s=-1)): "mechanical rotation",
    (dim(kg=1, m=2, s=-3, A=-1), dim(A=1)): "electrical",
    (dim(kg=1, m=-1, s=-2), dim(m=3, s=-1)): "hydraulic",
    (dim(K=1), dim(kg=1, m=2, s=-3)): "thermal (temperature, heat flow)",
    (dim(K=1), dim(kg=1, m=2, s=-3, K=-1)): "thermal (temperature, entropy flow)",
}


@dataclass(frozen=True)
class BondUnits:
    id: str
    src: str
    dst: str
    effort: object  # a dimension (tuple of 7 exponents), or None when the model leaves it open
    flow: object

    @property
    def domain(self) -> str:
        if self.effort is None or self.flow is None:
            return "unknown"
        return DOMAINS.get((self.effort, self.flow), "other")

    def line(self) -> str:
        e = show(self.effort) if self.effort is not None else "?"
        f = show(self.flow) if self.flow is not None else "?"
        return f"{self.id}  {self.src} -> {self.dst}: {self.domain}; effort {e}, flow {f}"


@dataclass(frozen=True)
class UnitReport:
    bonds: tuple[BondUnits, ...]
    #: output name -> its expression's dimension (None where the model leaves it open)
    outputs: dict = field(default_factory=dict, compare=False)
    #: state (``mass.p``, ``spring.q``, an auxiliary state's id) -> the state's dimension
    states: dict = field(default_factory=dict, compare=False)

    def output_unit(self, name: str, declared: str = "") -> str:
        """An output's unit for axes and FMI: as declared, else the inferred dimension's name
        ("" when unknown)."""
        d = self.outputs.get(name)
        return declared or (show(d) if d is not None else "")

    def text(self) -> str:
        """The report of ``bgc check --units``: one line per bond."""
        lines = ["units (each bond: its domain, the dimensions of its effort and flow; ? where "
                 "the model leaves them open):"]
        lines += [f"  {b.line()}" for b in self.bonds]
        for title, dims in (("states", self.states), ("outputs", self.outputs)):
            if dims:
                lines.append(f"{title} (their dimensions):")
                width = max(len(k) for k in dims)
                lines += [f"  {k.ljust(width)}  {show(d) if d is not None else '?'}"
                          for k, d in dims.items()]
        return "\n".join(lines) + "\n"


def check_units(bg) -> UnitReport:
    """Infer and check the dimensions of ``bg`` (a bgc.core.graph.BondGraph): a located
    ModelError for the first law that disagrees with the others. A model that declares no unit
    anywhere is not checked (its dimensions are all unknown): it compiles as it did before."""
    if not _declares_units(bg):
        return UnitReport(tuple(BondUnits(b.id, b.src, b.dst, None, None) for b in bg.bonds))
    chk = Checker(bg)
    _parameters(chk)
    _junctions(chk)
    for types in (("Se", "Sf"), ("I", "C"), ("TF", "MTF", "GY", "MGY"), ("R",)):
        for el in bg.elements:
            if el.type in types and el.law is not None:
                _element(chk, el)
    _states(chk)
    _inputs(chk)
    _initials(chk)
    outs = _outputs(chk)
    _closures(chk)
    chk.sys.settle()
    val = chk.sys.value
    return UnitReport(tuple(BondUnits(b.id, b.src, b.dst, val(chk.e(b.id)), val(chk.f(b.id)))
                            for b in bg.bonds),
                      {name: val(form) for name, form in outs.items()},
                      {key: val(form) for key, form in _state_forms(chk).items()})


def _closures(chk: Checker) -> None:
    """A flow source's closure (a loop's position residual) is its bond's displacement: checked
    last, so that a wrong closure is blamed, not the laws it would contradict."""
    for el in chk.bg.elements:
        cl = el.closure if el.type == "Sf" else None
        if cl is not None:
            (b,) = chk.bg.bonds_of(el.id)
            got = chk.eval(cl, el.scope, f"Sf {el.id!r} (closure)")
            chk.equate(got, chk.f(b.id) + SECOND, cl.coord,
                       lambda x, y, el=el, cl=cl: f"Sf {el.id!r}: closure {short_text(cl.text)} "
                       f"is {x}, but the displacement of its bond (flow x time) is {y}")


def _state_forms(chk: Checker) -> dict:
    """Each state's dimension as a form, by its name without an index (STATE_NAMES' ``mass.p``
    for ``mass.p`` and ``mass.p[1]``): an I's momentum is its effort times s, a C's
    displacement its flow times s, an auxiliary state's its own."""
    out = {}
    for el in chk.bg.elements:
        if el.type in ("I", "C"):
            b = chk.bg.bonds_of(el.id)[0]
            name = f"{el.id}.{'p' if el.type == 'I' else 'q'}"
            out[name] = (chk.e(b.id) if el.type == "I" else chk.f(b.id)) + SECOND
    for st in chk.bg.states:
        out[st.id] = chk.states[st.id]
    return out


def _declares_units(bg) -> bool:
    model = bg.model
    comps = [p for c in model.components for p in c.body.params]
    return getattr(model, "strict_units", False) or any(
        x.unit for x in (*bg.params, *comps, *model.inputs, *bg.states, *model.body.outputs))


def _parameters(chk: Checker) -> None:
    bg = chk.bg
    strict = getattr(bg.model, "strict_units", False)
    for fp in bg.params:
        if strict and not fp.unit and not isinstance(fp.value, Expr):
            raise ModelError(fp.coord, f"parameter {fp.id!r} has no unit (the model says "
                                       "'units: strict': every parameter needs one)")
        if isinstance(fp.value, Expr):
            got = chk.eval(fp.value, fp.scope, f"parameter {fp.id!r}")
            unit = fp.unit
            chk.equate(chk.params[fp.id], got, fp.value.coord,
                       lambda x, y, fp=fp, unit=unit: f"parameter {fp.id!r} is declared {unit}, "
                       f"but its value {short_text(fp.value.text)} is {y}")
    for scope, sc in bg.scopes.items():
        for name, binding in sc.bindings.items():
            if binding.kind == "expr":
                chk.binding(scope, name, binding)


def _junctions(chk: Checker) -> None:
    for el in chk.bg.elements:
        if el.type not in ("0", "1"):
            continue
        bonds = chk.bg.bonds_of(el.id)
        for b in bonds[1:]:
            for word, var in (("efforts", chk.e), ("flows", chk.f)):
                chk.equate(var(bonds[0].id), var(b.id), el.coord,
                           lambda x, y, b=b, word=word, el=el: f"{el.type}-junction {el.id!r}: "
                           f"bond {bonds[0].id!r} carries {word} in {x}, but bond {b.id!r} in {y}")


#: Law key -> (the law's dimension as a function of the bond's (e, f), in words).
_ONE_PORT = {
    ("Se", "effort"): (lambda e, f: e, "the effort"),
    ("Sf", "flow"): (lambda e, f: f, "the flow"),
    ("I", "inertia"): (lambda e, f: e + SECOND - f, "momentum/flow"),
    ("I", "flow"): (lambda e, f: f, "the flow"),
    ("C", "stiffness"): (lambda e, f: e - f - SECOND, "effort/displacement"),
    ("C", "compliance"): (lambda e, f: f + SECOND - e, "displacement/effort"),
    ("C", "effort"): (lambda e, f: e, "the effort"),
    ("R", "resistance"): (lambda e, f: e - f, "effort/flow"),
    ("R", "effort"): (lambda e, f: e, "the effort"),
    ("R", "flow"): (lambda e, f: f, "the flow"),
}
_TWO_PORT = {  # (in e, in f, out e, out f) -> the modulus, twice
    "TF": ((lambda ei, fi, eo, fo: fo - fi, "flow out/flow in"),
           (lambda ei, fi, eo, fo: ei - eo, "effort in/effort out")),
    "GY": ((lambda ei, fi, eo, fo: eo - fi, "effort out/flow in"),
           (lambda ei, fi, eo, fo: ei - fo, "effort in/flow out")),
}


def _element(chk: Checker, el) -> None:
    key, expr = el.law
    bonds = chk.bg.bonds_of(el.id)
    what = f"{el.type} {el.id!r}"
    if el.type in ("Se", "Sf", "I", "C", "R"):
        e, f = chk.e(bonds[0].id), chk.f(bonds[0].id)
        local = {"I": {"p": e + SECOND}, "C": {"q": f + SECOND}, "R": {"e": e, "f": f}}
        got = chk.eval(expr, el.scope, f"{what} ({key})", local.get(el.type, {}))
        rule, words = _ONE_PORT[(el.type, key)]
        chk.equate(got, rule(e, f), expr.coord,
                   lambda x, y: f"{what}: {key} {short_text(expr.text)} is {x}, but {words} on "
                                f"its bond is {y}")
        return
    bin_ = next(b for b in bonds if b.dst == el.id)
    bout = next(b for b in bonds if b.src == el.id)
    got = chk.eval(expr, el.scope, f"{what} ({key})")
    args = (chk.e(bin_.id), chk.f(bin_.id), chk.e(bout.id), chk.f(bout.id))
    (rule1, _), (rule2, _) = _TWO_PORT[el.type.lstrip("M")]
    both = (rule1(*args) + rule2(*args)).scaled(Fraction(1, 2))  # fixed by the bonds' units
    chk.equate(got, both, expr.coord,  # even where their split into e and f is still open
               lambda x, y: f"{what}: {key} {short_text(expr.text)} is {x}, but its bonds need "
                            f"{y}")
    for rule, words in _TWO_PORT[el.type.lstrip("M")]:
        chk.equate(got, rule(*args), expr.coord,
                   lambda x, y, words=words: f"{what}: {key} {short_text(expr.text)} is {x}, but "
                                             f"{words} on its bonds is {y}")


def _states(chk: Checker) -> None:
    for st in chk.bg.states:
        got = chk.eval(st.derivative, st.scope, f"state {st.id!r} (derivative)")
        rate = chk.states[st.id] - SECOND
        if not st.unit:  # x' = exp(x): a state without a unit may carry its own time scale
            rate = rate + Form.var(chk.sys.new_var(f"{st.id} time scale", soft=True))
        chk.equate(got, rate, st.derivative.coord,
                   lambda x, y, st=st: f"state {st.id!r}: derivative "
                                       f"{short_text(st.derivative.text)} is {x}, but the "
                                       f"state's rate of change is {y}")


def _inputs(chk: Checker) -> None:
    for inp in chk.bg.model.inputs:
        got = chk.eval(inp.default, (), f"input {inp.name!r} (default)")
        chk.equate(chk.inputs[inp.name], got, inp.default.coord,
                   lambda x, y, inp=inp: f"input {inp.name!r} is {inp.unit or x}, but its "
                   f"default {short_text(inp.default.text)} is {y}")


def _initials(chk: Checker) -> None:
    for el in chk.bg.elements:
        if el.initial is None or el.type not in ("I", "C"):
            continue
        b = chk.bg.bonds_of(el.id)[0]
        want = (chk.e(b.id) if el.type == "I" else chk.f(b.id)) + SECOND
        name = "momentum" if el.type == "I" else "displacement"
        got = chk.eval(el.initial, el.scope, f"{el.type} {el.id!r} (initial)")
        chk.equate(got, want, el.initial.coord,
                   lambda x, y, el=el, name=name: f"{el.type} {el.id!r}: initial value "
                   f"{short_text(el.initial.text)} is {x}, but its {name} is {y}")
    for st in chk.bg.states:
        got = chk.eval(st.initial, st.scope, f"state {st.id!r} (initial)")
        chk.equate(got, chk.states[st.id], st.initial.coord,
                   lambda x, y, st=st: f"state {st.id!r}: initial value "
                   f"{short_text(st.initial.text)} is {x}, but the state is {y}")


def _outputs(chk: Checker) -> dict:
    forms = {}
    for out in chk.bg.model.body.outputs:
        got = chk.eval(out.expr, (), f"output {out.name!r}")
        declared = unit_of(out.unit, out.coord, f"output {out.name!r}")
        chk.equate(declared, got, out.coord,
                   lambda x, y, out=out: f"output {out.name!r} is declared {out.unit}, but "
                   f"its expression {short_text(out.expr.text)} is {y}")
        forms[out.name] = got
    return forms
