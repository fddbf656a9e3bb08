"""What an FMU's modelDescription.xml and its C model share (bgc.backends.fmu.export): the FMI
variables with their value references in one order (states, derivatives, parameters, inputs,
outputs), their start values, and the model structure's dependencies, read from the lowered
functions."""
from __future__ import annotations

import hashlib
import re
import uuid
from dataclasses import dataclass

import sympy as sp

from bgc.base import __version__
from bgc.base.errors import ModelError
from bgc.core.equations import T
from bgc.format.scene import free_values
from bgc.format.units import div, dim, show

#: uuid5 namespace of bgc's FMU GUIDs
_GUID_NS = uuid.UUID("6f1d2c9e-5b0a-4c1e-9d0f-b9c0f3a1e2d4")


@dataclass(frozen=True)
class Var:
    name: str
    vr: int
    causality: str
    variability: str
    initial: str | None = None
    start: float | None = None
    unit: str = ""
    description: str = ""
    derivative: int | None = None  # 1-based index of the state variable


@dataclass(frozen=True)
class FmuSpec:
    """What the XML and the C model share: variables and value references, in one order."""
    model_identifier: str
    guid: str
    variables: tuple[Var, ...]
    n: int
    np: int
    nu: int
    nout: int
    param_start: tuple[float, ...]
    param_tunable: tuple[int, ...]
    input_start: tuple[float, ...]
    state_deps: tuple[tuple[int, ...], ...]  # derivative i -> variable indices (1-based)
    output_deps: tuple[tuple[int, ...], ...]
    initial_deps: tuple[tuple[int, tuple[int, ...]], ...]  # (index, dependencies), by index


def flat_names(name: str, shape: tuple[int, ...]) -> list[str]:
    """FMI scalar names of a value: ``name``, ``name[i]`` or ``name[i,j]`` (1-based)."""
    if not shape:
        return [name]
    if len(shape) == 1:
        return [f"{name}[{i + 1}]" for i in range(shape[0])]
    return [f"{name}[{i + 1},{j + 1}]" for i in range(shape[0]) for j in range(shape[1])]


def _flat_values(v) -> list[float]:
    if isinstance(v, (tuple, list)):
        out = []
        for r in v:
            out += _flat_values(r)
        return out
    return [float(v)]


def _deps(fn, state_syms, input_syms, extra=None) -> list[set]:
    """For each result of a lowered function, the states and inputs (as ('x', i) / ('u', k))
    it depends on, through the function's definitions; ``extra`` adds symbols of other
    kinds (symbol -> set), e.g. parameters as ('p', k)."""
    base = {s: {("x", i)} for i, s in enumerate(state_syms)}
    base.update({s: {("u", k)} for k, s in enumerate(input_syms)})
    base.update(extra or {})
    known: dict = {}

    def of(expr):
        out = set()
        for s in expr.free_symbols:
            if s in known:
                out |= known[s]
            elif s in base:
                out |= base[s]
        return out

    for ln in fn.lines:
        known[ln.target] = of(ln.expr)
    return [of(r) for _, r in fn.results]


def _param_base(eq, psyms) -> dict:
    """symbol -> {('p', k)}: the parameters, and the derived parameters through their
    definitions."""
    base = {s: {("p", k)} for k, s in enumerate(psyms)}
    for a in eq.derived:
        d = set()
        for s in a.expr.free_symbols:
            d |= base.get(s, set())
        base[a.symbol] = d
    return base


def _numeric(expr, values: dict) -> float:
    v = sp.sympify(expr).xreplace(values)
    try:
        return float(sp.N(v))
    except TypeError:
        raise ModelError(None, f"cannot evaluate the start value {expr} numerically") from None


def build_spec(compiled, scene=None, kind: str = "both") -> FmuSpec:
    """The FMU's variables (states, derivatives, parameters, inputs, outputs, in that order
    of value references), their start values and the model structure's dependencies."""
    low = compiled.lowered
    eq = compiled.equations
    ident = _identifier(compiled.model.name, scene)
    n = len(eq.states)
    pnames, psyms, pstart, punits, pdesc = _param_table(eq, scene)
    ptun = _tunable(eq, psyms)
    values = {s: sp.Float(v) for s, v in zip(psyms, pstart)}
    for a in eq.derived:
        values[a.symbol] = sp.Float(_numeric(a.expr, values))
    values[T] = sp.Float(scene.t_span[0] if scene is not None else 0.0)
    inames, isyms, istart, iunits = _input_table(compiled, values)
    onames, ounits = _output_table(compiled)
    xunits, dunits = _state_units(compiled)
    nu, npar, nout = len(inames), len(pnames), len(onames)
    vr_p, vr_u, vr_y = 2 * n, 2 * n + npar, 2 * n + npar + nu
    sdeps, odeps, initial = _structure(low, eq, isyms, psyms, vr_p, vr_u, vr_y)
    variables = [Var(sv.name, i, "local", "continuous", "calculated", unit=xunits[i])
                 for i, sv in enumerate(eq.states)]
    variables += [Var(f"der({sv.name})", n + i, "local", "continuous", "calculated",
                      unit=dunits[i], derivative=i + 1) for i, sv in enumerate(eq.states)]
    variables += [Var(nm, vr_p + k, "parameter", "tunable" if ptun[k] else "fixed", "exact",
                      pstart[k], punits[k], pdesc[k]) for k, nm in enumerate(pnames)]
    variables += [Var(nm, vr_u + k, "input", "continuous", None, istart[k], iunits[k])
                  for k, nm in enumerate(inames)]
    variables += [Var(nm, vr_y + k, "output", "continuous", "calculated", unit=ounits[k])
                  for k, nm in enumerate(onames)]
    _check_variables(variables, pstart + istart)
    return FmuSpec(ident, _guid(compiled, scene, kind, ident), tuple(variables), n, npar, nu,
                   nout, tuple(pstart), tuple(ptun), tuple(istart), tuple(sdeps), tuple(odeps),
                   tuple(sorted(initial.items())))


def _identifier(name: str, scene) -> str:
    """The model identifier: the model's name (and the scene's), as a C identifier."""
    ident = name + (f"_{scene.name}" if scene is not None else "")
    ident = re.sub(r"[^A-Za-z0-9_]", "_", ident)
    if not ident or ident[0].isdigit():
        ident = "m_" + ident
    return ident


def _param_table(eq, scene):
    """The parameters' FMI names, symbols, start values, units and descriptions, flat: the
    model's values (the scene's top-level values are already in), then the scene's free
    parameters' values."""
    overrides = {}
    if scene is not None:
        overrides = free_values(scene)
    pnames, psyms, pstart, punits, pdesc = [], [], [], [], []
    for pv in eq.params:
        vals = _flat_values(overrides.get(pv.id, pv.value))
        if len(vals) != len(pv.symbols):
            raise ModelError(None, f"parameter {pv.id!r}: {len(vals)} values for "
                                   f"{len(pv.symbols)} entries")
        pstart += vals
        names = flat_names(pv.id, tuple(pv.shape))
        pnames += names
        punits += [pv.unit] * len(names)
        pdesc += [pv.description] * len(names)
        psyms += list(pv.symbols)
    return pnames, psyms, pstart, punits, pdesc


def _tunable(eq, psyms) -> list[int]:
    """1 for a tunable parameter, 0 for a fixed one: one the initial state depends on
    (directly or through derived parameters)."""
    init_syms = set()
    for sv in eq.states:
        init_syms |= sp.sympify(sv.initial).free_symbols
    for a in reversed(eq.derived):
        if a.symbol in init_syms:
            init_syms |= a.expr.free_symbols
    return [0 if s in init_syms else 1 for s in psyms]


def _input_table(compiled, values: dict):
    """The inputs' FMI names, symbols, start values (their defaults at the start, with the
    parameters' start values) and units."""
    model_inputs = {i.name: i for i in compiled.model.inputs}
    inames, isyms, istart, iunits = [], [], [], []
    for iv in compiled.equations.inputs:
        names = flat_names(iv.name, tuple(iv.shape))
        inames += names
        unit = model_inputs[iv.name].unit if iv.name in model_inputs else ""
        iunits += [unit] * len(names)
        istart += [_numeric(d, values) for d in iv.default]
        isyms += list(iv.symbols)
    return inames, isyms, istart, iunits


def _output_table(compiled):
    """The outputs' FMI names and units: as declared, else the checked dimension's name."""
    onames, ounits = [], []
    report = getattr(compiled.graph, "units", None)
    out_unit = {o.name: o.unit for o in compiled.model.body.outputs}  # {expr, unit} outputs
    for name, shape, vals in compiled.equations.outputs:
        unit = out_unit.get(name, "")
        if report is not None:
            unit = report.output_unit(name, unit)
        onames += flat_names(name, tuple(shape))
        ounits += [unit] * len(flat_names(name, tuple(shape)))
    return onames, ounits


def _state_units(compiled):
    """Each state's unit and its derivative's (the state's per second), from the checked
    dimensions: a declared unit of an auxiliary state as written; "" where unknown."""
    report = getattr(compiled.graph, "units", None)
    declared = {st.id: st.unit for st in compiled.graph.states}  # components' states too
    xunits, dunits = [], []
    for sv in compiled.equations.states:
        d = report.states.get(sv.name.split("[")[0]) if report is not None else None
        unit = declared.get(sv.name.split("[")[0], "") or (show(d) if d is not None else "")
        xunits.append(unit)
        if not unit:
            dunits.append("")
        elif d is None:
            dunits.append(f"({unit})/s")
        else:
            dunits.append(show(div(d, dim(s=1))))
    return xunits, dunits


def _structure(low, eq, isyms, psyms, vr_p, vr_u, vr_y):
    """ModelStructure's dependencies as FMI indices (1-based, in ModelVariables order:
    states, derivatives, parameters, inputs, outputs): of each derivative, of each output,
    and of each initial unknown (index -> dependencies)."""
    n = len(eq.states)
    idx_x = [i + 1 for i in range(n)]
    idx_u = [vr_u + k + 1 for k in range(len(isyms))]
    state_syms = [sv.symbol for sv in eq.states]
    rhs_deps = _deps(low.rhs, state_syms, isyms)
    jac_cols: list[set] = [set() for _ in range(n)]
    for r, col in low.jac_keys:
        jac_cols[r].add(col)
    sdeps = []
    for i in range(n):
        d = sorted({idx_x[j] for j in jac_cols[i]}
                   | {idx_u[k] for (kind_, k) in rhs_deps[i] if kind_ == "u"})
        sdeps.append(tuple(d))
    out_deps = _deps(low.outs, state_syms, isyms)
    odeps = [tuple(sorted(idx_x[k] if kind_ == "x" else idx_u[k] for kind_, k in d))
             for d in out_deps]
    # InitialUnknowns: in terms of what is known at initialisation, the parameters and the
    # inputs (the states are calculated from parameters)
    pbase = _param_base(eq, psyms)
    idx_p = [vr_p + k + 1 for k in range(len(psyms))]

    def known(kind_, k):
        return idx_p[k] if kind_ == "p" else idx_u[k]

    init_x = [{known(*d) for d in ds} for ds in _deps(low.init, state_syms, isyms, pbase)]

    def at_init(ds):
        out = set()
        for kind_, k in ds:
            out |= init_x[k] if kind_ == "x" else {known(kind_, k)}
        return tuple(sorted(out))

    initial = {idx_x[i]: tuple(sorted(init_x[i])) for i in range(n)}
    for i, ds in enumerate(_deps(low.rhs, state_syms, isyms, pbase)):
        initial[n + i + 1] = at_init(ds)
    for k, ds in enumerate(_deps(low.outs, state_syms, isyms, pbase)):
        initial[vr_y + k + 1] = at_init(ds)
    return sdeps, odeps, initial


def _check_variables(variables, starts) -> None:
    """Every FMI name once; every start value finite."""
    seen: dict = {}
    for v in variables:
        if v.name in seen:
            raise ModelError(None, f"two FMI variables would be named {v.name!r}: rename the "
                                   "parameter, input or output")
        seen[v.name] = v
    for v in starts:
        if v != v or v in (float("inf"), float("-inf")):
            raise ModelError(None, "a parameter or input start value is not finite")


def _guid(compiled, scene, kind, ident) -> str:
    """The FMU's GUID: a uuid5 of everything the FMU is made from."""
    h = hashlib.sha256()
    for part in (compiled.model.source_hash, getattr(scene, "source_hash", "") or "",
                 __version__, kind, ident, compiled.source):
        h.update(str(part).encode("utf-8") + b"\0")
    return "{" + str(uuid.uuid5(_GUID_NS, h.hexdigest())) + "}"
