"""bgc from Python: compile a model to a loaded module, check it, read its equations,
linearise it. Documented, with examples, in docs/api.md.

Every function takes a model as a path (``str`` or ``pathlib.Path``) or as YAML text: a
string is text when it contains a line break or starts with ``bgc:``. Nothing is written to
disk: the generated module is loaded from memory. Every mistake in a model or scene raises
:class:`bgc.BgcError` (``bgc.base.errors.ModelError``) with ``.coord`` (file, line, column) and
``.message``.
"""
from __future__ import annotations

import html
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bgc.backends.load import BACKENDS as targets
from bgc.base.errors import Coord, ModelError
from bgc.base.safeio import not_a_file
from bgc.builder import Builder, Component  # noqa: F401 (bgc.Builder, bgc.Component)
from bgc.core.causality import assign_causality
from bgc.core.draw import render_image, to_dot
from bgc.core.equations import T, derive
from bgc.core.graph import build_graph
from bgc.format.parse import parse_file, parse_text
from bgc.format.scene import initial_state, parse_scene
from bgc.linear import (
    load_target,
    modes,
    on_manifold,
    operating_point,
    point_warnings,
    scene_start,
    to_statespace,
)
from bgc.run.consistency import check_loop_start
from bgc.run.watch import dropped_drift
from bgc.run.driver import build, check_model, check_scene_for

BgcError = ModelError


def _is_text(src) -> bool:
    return isinstance(src, str) and ("\n" in src or src.lstrip().startswith("bgc:"))


def _model(src):
    """Parse a model given as a path, as YAML text or as a builder (bgc.builder)."""
    if isinstance(src, Builder):
        return src.build()
    if _is_text(src):
        return parse_text(src, "<string>")
    if not isinstance(src, (str, Path)):
        raise TypeError(f"a model is a path or YAML text (or a bgc.Builder), not "
                        f"{type(src).__name__}")
    why = not_a_file(src)
    if why is not None:
        raise ModelError(Coord(str(src), 1, 1), f"model file {why}")
    return parse_file(src)


def _check_types(src, scene=None) -> None:
    """The documented TypeError for a model that is neither a path nor YAML text (bytes, a
    dict, ...) nor a builder, and for a scene that is not a path."""
    if not isinstance(src, (str, Path, Builder)):
        raise TypeError(f"a model is a path or YAML text (or a bgc.Builder), not "
                        f"{type(src).__name__}")
    if scene is not None and not isinstance(scene, (str, Path)):
        raise TypeError(f"a scene is a path, not {type(scene).__name__}")


def compile(path_or_text, scene=None, target: str = "numpy") -> "CompiledModel":  # noqa: A001
    """Compile a model (path or YAML text), optionally specialised to a scene file, and return
    the loaded module wrapped in a :class:`CompiledModel` (attributes go to the module).
    A model file goes through the compile cache (bgc.run.driver.build, as `bgc simulate`)."""
    _check_types(path_or_text, scene)
    if target not in targets:
        raise ModelError(None, f"unknown target {target!r} (one of {', '.join(targets)})")
    built = _is_text(path_or_text) or isinstance(path_or_text, Builder)
    path = None if built else path_or_text
    why = None if path is None else not_a_file(path)
    if why is not None:
        raise ModelError(Coord(str(path), 1, 1), f"model file {why}")
    sc = None
    if scene is not None:
        sc = parse_scene(scene)
        check_scene_for(sc, path, "the text given" if path is None else path_or_text)
    b = build(path if path is not None else _model(path_or_text), sc, target)
    return CompiledModel(b.module, b.compiled, path_or_text, sc)


class CompiledModel:
    """A compiled, loaded model: every attribute of the generated module (``rhs``,
    ``simulate``, ``linearize``, ``STATE_NAMES``, ...) is reachable on it; ``.module`` is the
    module itself, ``.source`` its text, ``.compiled`` bgc's record of the compilation. In
    Jupyter it shows a summary and the bond graph (SVG, when Graphviz is installed)."""

    def __init__(self, module, compiled=None, origin=None, scene=None):
        self.module = module
        self.compiled = compiled  # None when the module came from the compile cache
        self.origin = origin  # the path or text it was compiled from
        self.scene = scene  # the scene (bgc.format.scene.Scene) it was specialised to, or None

    @property
    def source(self) -> str:
        """The generated module's text."""
        return self.compiled.source if self.compiled is not None else \
            self.module.__loader__.get_source(self.module.__name__)

    @property
    def name(self) -> str:
        return self.compiled.model.name if self.compiled is not None else \
            self.module.__name__.removeprefix("bgc_generated_")

    def _graph(self):
        """(bond graph, causality) for the drawing (rebuilt after a cache hit: cheap)."""
        if self.compiled is not None:
            return self.compiled.graph, self.compiled.causality
        bg = build_graph(_model(self.origin))
        return bg, assign_causality(bg, allow_derivative=True)

    def simulate(self, t_span, *args, x0=None, p=None, **kw):
        """The module's ``simulate``; a given x0 is first checked against the model's
        closed-loop constraints (positions and velocities: a ModelError naming the constraint
        and the residual), as the compile checks the model's own initial state. Afterwards
        the constraint components dropped as redundant at the start are checked at the output
        times (a RuntimeWarning where one's velocity residual grew: bgc.run.watch)."""
        if x0 is not None and np.ndim(x0) == 1:
            check_loop_start(self.module, float(t_span[0]), x0, p, None, "x0")
        res = self.module.simulate(t_span, *args, x0=x0, p=p, **kw)
        if not args and getattr(self.module, "CONSTRAINT_DROPPED", ()):
            drift = dropped_drift(self.module, res[0], res[1], p, kw.get("rtol", 1e-6),
                                  kw.get("atol", 1e-9))
            if drift:
                warnings.warn(drift, RuntimeWarning, stacklevel=2)
        return res

    def __getattr__(self, name):
        if name.startswith("__"):
            raise AttributeError(name)
        return getattr(self.__dict__["module"], name)

    def __dir__(self):
        return sorted(set(dir(self.module)) | {"module", "compiled", "source"})

    def __repr__(self):
        m = self.module
        return (f"<bgc model {self.name!r}: {m.N_STATES} states, "
                f"{len(m.PARAM_DEFAULTS)} parameters, inputs {list(m.INPUT_NAMES)}, outputs "
                f"{list(m.OUTPUT_NAMES)}>")

    def _repr_svg_(self):
        return _svg(*self._graph())

    def _repr_html_(self):
        m = self.module
        rows = [("states", ", ".join(m.STATE_NAMES)),
                ("parameters", ", ".join(f"{k} = {v}" + (f" [{m.PARAM_UNITS[k]}]"
                                                         if m.PARAM_UNITS.get(k) else "")
                                         for k, v in m.PARAM_DEFAULTS.items())),
                ("inputs", ", ".join(m.INPUT_NAMES) or "none"),
                ("outputs", ", ".join(m.OUTPUT_NAMES))]
        return _html(f"bgc model {self.name}", rows, _svg(*self._graph()))


def _svg(graph, caus):
    """The bond graph as SVG text, or None without Graphviz."""
    try:
        return render_image(to_dot(graph, caus), "svg").decode("utf-8")
    except ModelError:
        return None


def _html(title, rows, svg):
    body = "".join(f"<tr><th style='text-align:left'>{html.escape(k)}</th>"
                   f"<td style='text-align:left'>{html.escape(str(v))}</td></tr>" for k, v in rows)
    return (f"<div><b>{html.escape(title)}</b><table>{body}</table>"
            + (svg or "") + "</div>")


@dataclass(frozen=True)
class BondCausality:
    bond: str
    src: str
    dst: str
    n: int
    effort_by: str  # the element that computes the bond's effort
    stroke_at: str  # the end that receives the effort (where the causal stroke is drawn)


@dataclass(frozen=True)
class CheckResult:
    """What ``bgc check`` reports, as data."""

    model: str
    bonds: tuple[BondCausality, ...]
    forms: dict  # element id -> causal form in words ("integral", "resistance", ...)
    states: tuple[str, ...]
    all_integral: bool
    derivative: tuple[str, ...]  # storage elements in derivative causality
    loops: tuple[str, ...]  # algebraic loops solved
    warnings: tuple[str, ...]
    diagnostics: tuple[str, ...]  # errors that stop compilation (e.g. derivative causality)
    dot: str  # the bond graph with causal strokes (Graphviz DOT)

    def _repr_html_(self):
        rows = [("states", ", ".join(self.states)),
                ("causality", "all integral" if self.all_integral else
                 "derivative: " + ", ".join(self.derivative))]
        rows += [("warning", w) for w in self.warnings] + [("error", d) for d in self.diagnostics]

        try:
            svg = render_image(self.dot, "svg").decode("utf-8")
        except ModelError:
            svg = None
        return _html(f"bgc check {self.model}", rows, svg)


def check(path_or_text, strict_causality: bool = False) -> CheckResult:
    """Causality per bond, causal forms, states, loops and warnings of a model, as data: what
    `bgc check` reports (bgc.run.driver.check_model). Derivative causality the model refuses
    (``causality: strict``, or ``strict_causality``) is reported in ``diagnostics`` (not
    raised); other errors raise."""
    chk = check_model(_model(path_or_text), strict_causality)
    m, bg, caus, eqs = chk.model, chk.graph, chk.causality, chk.equations
    bonds = []
    for b in bg.bonds:
        setter = caus.effort_by[b.id]
        bonds.append(BondCausality(b.id, b.src, b.dst, b.n, setter,
                                   b.dst if setter == b.src else b.src))
    forms = {el.id: caus.form(bg, el) for el in bg.elements
             if el.type in ("I", "C", "R", "TF", "MTF", "GY", "MGY")}
    diagnostics, loops, states = (), (), ()
    warnings = tuple(caus.warnings)
    if chk.error is not None:
        diagnostics = (chk.error.message,)
    else:
        loops = tuple(eqs.loops)
        states = tuple(sv.name for sv in eqs.states)
        warnings = tuple(eqs.warnings)
    return CheckResult(m.name, tuple(bonds), forms, states, not caus.derivative,
                       tuple(caus.derivative), loops, warnings, diagnostics,
                       to_dot(bg, caus))


@dataclass(frozen=True)
class StateEquations:
    """The state equations as sympy objects: ``assignments`` (efforts and flows in causal
    order, each ``Eq(symbol, expression)``) and ``derivatives`` (``Eq(Derivative(x, t),
    expression)`` in terms of the states, parameters, inputs and the assigned symbols)."""

    states: tuple
    assignments: tuple
    derivatives: tuple
    outputs: tuple  # Eq(Symbol(name), expression) per output component

    def explicit(self):
        """dx/dt with every assignment substituted: a sympy Matrix of the states, parameters,
        inputs and t (no simplification; fine for small models, large for big ones)."""
        import sympy as sp

        subs = {}
        for a in self.assignments:
            subs[a.lhs] = a.rhs.xreplace(subs)
        return sp.Matrix([d.rhs.xreplace(subs) for d in self.derivatives])

    def latex(self, explicit: bool = False) -> str:
        """LaTeX (an ``aligned`` block): the causal assignments, then dx/dt."""
        import sympy as sp

        lines = []
        if explicit:
            rhs = self.explicit()
            for s, e in zip(self.states, rhs):
                lines.append(rf"\dot{{{sp.latex(s)}}} &= {sp.latex(e)}")
        else:
            for a in self.assignments:
                lines.append(rf"{sp.latex(a.lhs)} &= {sp.latex(a.rhs)}")
            for s, d in zip(self.states, self.derivatives):
                lines.append(rf"\dot{{{sp.latex(s)}}} &= {sp.latex(d.rhs)}")
        return "\\begin{aligned}\n" + " \\\\\n".join(lines) + "\n\\end{aligned}"


def equations(path_or_text) -> StateEquations:
    """The state equations of a model as sympy objects (and LaTeX: ``.latex()``)."""
    import sympy as sp

    model = _model(path_or_text)
    bg = build_graph(model)
    strict = bool(getattr(model, "strict_causality", False))
    # as compile does: rigid connections (derivative causality) eliminated, nonlinear
    # algebraic loops solved by Newton, unless the model asks for strict causality
    eqs = derive(bg, assign_causality(bg, allow_derivative=not strict), newton=not strict)
    states = tuple(sv.symbol for sv in eqs.states)
    assigns = tuple(sp.Eq(a.symbol, a.expr, evaluate=False) for a in eqs.assignments)
    derivs = tuple(sp.Eq(sp.Derivative(s, T), d, evaluate=False)
                   for s, d in zip(states, eqs.derivatives))
    outs = []
    for name, shp, vals in eqs.outputs:
        for k, v in enumerate(vals):
            outs.append(sp.Eq(sp.Symbol(name if len(vals) == 1 else f"{name}_{k}"), v,
                              evaluate=False))
    return StateEquations(states, assigns, derivs, tuple(outs))


@dataclass(frozen=True)
class Linearization:
    """A, B, C, D at (t, x) with the names of their rows and columns; ``modes`` (eigenvalues,
    natural frequencies, damping ratios, dominant states); ``statespace``: a python-control
    StateSpace when that package is installed, else None."""

    A: object
    B: object
    C: object
    D: object
    t: float
    x: object
    states: tuple
    inputs: tuple
    outputs: tuple
    modes: tuple
    statespace: object = None
    #: a model with closed loops: the reduction to its constraint manifold (bgc.linear.Reduced:
    #: N, A, B, C, note), whose A ``modes`` are; None without constraints
    reduced: object = None


def linearize(model, at="equilibrium", p=None, u=None, x0=None) -> Linearization:
    """Linearise a model (path, text or a :class:`CompiledModel`) or a scene file at its
    equilibrium (inputs held at their values at the start) or at a time ``at`` reached by a
    run from x0. The start is t = 0 for a model, the scene's start (and its parameter
    values) for a scene or a model compiled for one: where `bgc linearize` linearises.
    ``x0``: the equilibrium's Newton starts there (default: the initial state), or the run to
    time ``at`` starts there."""
    pv, t0, sc = None, 0.0, None
    if isinstance(model, CompiledModel):
        mod = model
        if model.scene is not None:
            pv, t0, sc = scene_start(model.scene, model.module)
            if hasattr(model.module, "_NO_LINEAR"):  # a scene's module: B, C, D left out
                mod = CompiledModel(build(model.origin, model.scene, linear=True).module,
                                    None, model.origin, model.scene)
    elif not _is_text(model) and isinstance(model, (str, Path)) and Path(model).is_file():
        mod, pv, t0, sc = load_target(model)
    else:
        mod = compile(model)
    if p is not None:
        pv = {**(pv or {}), **p}
    if x0 is None and sc is not None and isinstance(sc.initial, dict):
        x0 = initial_state(sc, mod, pv)  # the scene's `initial:` values: the guess
    found = []
    t, x, _ = operating_point(mod, at, pv, u, t0, hint=")", x0=x0, on_equilibrium=found.append)
    guess = mod.initial_state(pv) if x0 is None else x0
    settled = getattr(found[0], "settled", None) if found else None
    for msg in point_warnings(mod, t, x, pv, u, guess, at == "equilibrium", settled):
        warnings.warn(msg, RuntimeWarning, stacklevel=2)
    A, B, C, D = mod.linearize(t, x, u, pv)
    try:
        ss = to_statespace(mod, A, B, C, D)
    except ImportError:
        ss = None
    red = on_manifold(mod, A, B, C)
    ms = modes(A, mod.STATE_NAMES) if red is None else modes(red.A, mod.STATE_NAMES,
                                                              basis=red.N)
    return Linearization(A, B, C, D, t, x, tuple(mod.STATE_NAMES), tuple(mod.INPUT_LABELS),
                         tuple(mod.OUTPUT_LABELS), tuple(ms), ss, red)
