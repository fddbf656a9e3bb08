"""The compile driver: one way from a model (or a scene) to a loaded module, for every caller.

The stages, each a function below that takes and returns frozen data and is timed:

1. **parse** (``bgc.format``): the YAML file -> :class:`~bgc.format.parse.Model`; a scene's
   model is the model with the scene's signals and parameter values
   (:func:`bgc.format.scene.scene_model`), and its :class:`~bgc.core.specialize.Plan`.
2. **graph** (``bgc.core.graph``): Model -> the flat :class:`~bgc.core.graph.BondGraph`.
3. **causality** (``bgc.core.causality``): BondGraph -> :class:`~bgc.core.causality.Causality`
   (SCAP), with the resistor-law diagnosis of derivative causality.
4. **specialise** (``bgc.core.specialize``, scenes only): effects removed, causality
   re-assigned, outputs selected.
5. **equations** (``bgc.core.equations``): -> :class:`~bgc.core.equations.Equations`
   (sympy), sliced to the scene's outputs.
6. **lower** (``bgc.lower.ir``): Equations -> :class:`~bgc.lower.ir.Lowered`, the one IR
   every printer reads.
7. **print** (``bgc.backends.<backend>``): Lowered -> the module's text (numpy). The C target
   prints no numpy module: its C sources and wrapper (the numpy module's names, parameters
   and runtime without the equations, then the binding) are printed from the same IR when the
   C entry is built, and :attr:`Compiled.source` prints the numpy module only when asked.
8. **build/load** (``bgc.backends.load``, ``bgc.backends.c.build``): the text -> a loaded
   module, through the compile cache (:mod:`bgc.run.cache` makes the key).

:func:`build` is the one function that compiles a scene (or a bare model) for a backend
through the cache: ``bgc compile``/``simulate``/``export``/``linearize``, ``bgc.compile``, run
records, sweeps, accuracy studies and FMU export all come here. :func:`compile_source` is the
one compile of a model or scene (stages 1 to 7), for callers that write the text themselves.
The stage times are on :attr:`Compiled.times` and :attr:`Built.times`.

A cache hit runs only stage 8 and imports neither sympy nor the parser: the stages import
their modules when they run (deferred imports below keep a warm run light).
"""
from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

from bgc.backends import load as backends
from bgc.backends.c import build as cbuild
from bgc.backends.c.build import CompilerFailed, CUnsupported
from bgc.base.collector import gc_paused
from bgc.base.errors import ModelError
from bgc.format.parse import parse_file
from bgc.format.scene import check_against, check_outputs, scene_model
from bgc.run import cache as cache_mod

if TYPE_CHECKING:  # annotations only
    from bgc.core.causality import Causality
    from bgc.core.equations import Equations
    from bgc.core.graph import BondGraph
    from bgc.core.specialize import Plan
    from bgc.format.parse import Model

#: The stages in order, as named in :attr:`Compiled.times` and :attr:`Built.times`: "imports"
#: is the compile path's own (sympy's parts, the lowering); the C target's stages (its C
#: printed, its wrapper printed and checked, the compiler, the wrapper's code) stand in place
#: of "print", which only the numpy target runs; "load" is the rest of the build.
STAGES = ("parse", "imports", "graph", "causality", "specialise", "equations", "lower",
          "print", "print C", "wrapper", "build C", "wrapper code", "load")


@dataclass(frozen=True)
class Compiled:
    """A compiled model. ``source``, the numpy module's text, is printed when first asked for
    unless the compile printed it (the numpy target does; the C target prints its wrapper from
    ``module_text(equations=False)`` and needs the numpy module only for a caller that asks)."""
    model: Model
    graph: BondGraph
    causality: Causality
    equations: Equations
    text: str | None  # the numpy module's text, once printed
    notes: tuple[str, ...] = ()  # what specialisation removed and why (also in the header)
    lowered: object = None  # bgc.lower.ir.Lowered: the backend-neutral functions (C printer too)
    times: tuple[tuple[str, float], ...] = ()  # (stage, seconds), in order
    printer: object = None  # (equations, check) -> text: the numpy module, printed from the IR

    @property
    def compile_time(self) -> float:
        return sum(s for _, s in self.times)

    @property
    def source(self) -> str:
        """The numpy module's text (printed now if the compile did not print it)."""
        if self.text is None:
            object.__setattr__(self, "text", self.module_text())
        return self.text

    def module_text(self, equations: bool = True, check: bool = True) -> str:
        """The numpy module's text; ``equations=False``: without its equation functions (the
        C wrapper's numpy part); ``check=False``: the caller checks it."""
        if equations and check and self.text is not None:
            return self.text
        return self.printer(equations, check)


@dataclass(frozen=True)
class Built:
    """What :func:`build` gives: the backend used, the loaded module, the compile (None on a
    cache hit), the cache entry ((backend, key, [(path, bytes) the key digested], scene
    bytes), or None when uncached), the module's name and the stage times."""
    backend: str
    module: object
    compiled: Compiled | None
    entry: tuple | None
    name: str
    times: tuple[tuple[str, float], ...]

    @property
    def compile_time(self) -> float:
        return sum(s for _, s in self.times)


class _Clock:
    """Times the stages of one compile: ``with clock("graph"): ...``."""

    def __init__(self):
        self.times: list[tuple[str, float]] = []

    @contextlib.contextmanager
    def __call__(self, stage: str):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.times.append((stage, time.perf_counter() - t0))


# ---------------------------------------------------------------------------------------------
# Stages 2-3: the bond graph and its causality

def graph_of(model: Model, progress=None) -> BondGraph:
    """Stage 2: the flat bond graph."""
    from bgc.core.graph import build_graph  # (networkx, sympy: compile path only)

    (progress or (lambda msg: None))("building the bond graph")
    return build_graph(model)


def causality_of(graph: BondGraph, allow_derivative: bool, progress=None) -> Causality:
    """Stage 3: causality (SCAP); with derivative causality allowed, one caused by a resistor
    law in the wrong fixed form is that law's located error, not the storage element's."""
    # lazy: the compile path, which a warm run never loads
    from bgc.core.causality import assign_causality, fixed_r_culprit

    (progress or (lambda msg: None))("assigning causality (SCAP)")
    caus = assign_causality(graph, allow_derivative=allow_derivative)
    if caus.derivative:
        culprit = fixed_r_culprit(graph, caus)
        if culprit is not None:
            raise ModelError(culprit[0], culprit[1])
    return caus


def analyse(model: Model, progress=None, allow_derivative: bool = False
            ) -> tuple[BondGraph, Causality]:
    """Stages 2 and 3 as `bgc compile` and `bgc check` run them."""
    graph = graph_of(model, progress)
    return graph, causality_of(graph, allow_derivative, progress)


# ---------------------------------------------------------------------------------------------
# Stages 2-7 for one model

def compile_model(model: Model, progress=None, plan: Plan | None = None,
                  strict_causality: bool = False, symbolic_max: int | None = None,
                  target: str = "numpy", graph: BondGraph | None = None,
                  linear: bool = True) -> Compiled:
    """Compile a model, specialised to a scene's plan (effects, folded parameters, outputs).

    A plan that changes nothing gives exactly the module of the model alone (with the same
    ``linear``). Storage elements in derivative causality are eliminated (their states follow
    from the others) unless ``strict_causality`` or the model's ``causality: strict`` asks for
    today's error.
    ``target``: "numpy" prints the numpy module (stage 7); any other target leaves it to be
    printed on demand (:attr:`Compiled.source`), and the linearisation's B, C, D unlowered.
    ``graph``: the model's bond graph, when the caller built it already (stage 2).
    ``linear=False``: the numpy module without the linearisation's B, C, D (a scene's runs
    never call them; its input_jacobian and output_jacobian then say how to get them)."""
    with gc_paused():
        return _compile_model(model, progress, plan, strict_causality, symbolic_max, target,
                              graph, linear)


@dataclass(frozen=True)
class _Special:
    """What stage 4 hands on: the graph and causality to derive, and what it did."""
    graph: BondGraph
    causality: Causality
    notes: tuple[str, ...] = ()
    fold: dict | None = None
    zero: frozenset | None = None
    removed: object = None  # bgc.core.specialize's removal (for the states note)
    full_states: tuple = ()


def _check_plan_effects(graph, plan) -> None:
    """Every effect the scene names (on or off) must exist."""
    # lazy: the compile path, which a warm run never loads
    from bgc.core.effects import known_effects

    effects = known_effects(graph)
    for eff in list(plan.effect_coords) + sorted(plan.effects_off):
        if eff not in effects:
            raise ModelError(plan.effect_coords.get(eff, plan.coord),
                             f"the model has no effect {eff!r} (effects: "
                             f"{', '.join(sorted(effects)) or 'none'})")


def specialise(graph: BondGraph, caus: Causality, plan: Plan, progress=None) -> _Special:
    """Stage 4: effects off (causality re-assigned), outputs selected, parameters to fold."""
    # lazy: the compile path, which a warm run never loads
    from bgc.core.causality import derivative_message
    from bgc.core.specialize import (
        recausal,
        remove_effects,
        select_outputs,
        state_owners,
    )

    (progress or (lambda msg: None))("specialising for the scene")
    full_states = tuple(state_owners(graph, caus))
    if caus.derivative and plan.effects_off:
        # turning effects off re-assigns causality, which assumes every storage element
        # independent; folding parameters and slicing outputs work on the equations
        raise ModelError(graph.element(caus.derivative[0]).coord,
                         derivative_message(graph, caus).replace(
                             "derivative causality:", "derivative causality (a scene "
                             "that turns effects off needs every storage element "
                             "independent):", 1))
    notes: list[str] = []
    rem = remove_effects(graph, plan.effects_off, plan.coord)
    if plan.effects_off:
        notes.append("effects off: " + ", ".join(sorted(plan.effects_off)))
        caus, cnotes = recausal(graph, caus, rem, plan)
        notes += list(rem.notes) + list(cnotes)
    spec_graph, onotes = select_outputs(graph, rem, plan)
    notes += list(onotes)
    fold = None
    if plan.fold:
        fold = plan.fold
        notes.append("parameters folded in as constants: " + ", ".join(
            f"{k} = {_short(v)}" for k, v in sorted(plan.fold.items())))
    return _Special(spec_graph, caus, tuple(notes), fold, rem.zero or None, rem, full_states)


def _compile_model(model: Model, progress, plan: Plan | None, strict_causality: bool,
                   symbolic_max: int | None, target: str = "numpy", graph=None,
                   linear: bool = True) -> Compiled:
    clock = _Clock()
    with clock("imports"):
        # lazy: the compile path, which a warm run never loads
        from bgc.core.equations import derive  # (sympy: compile path only)
        from bgc.lower.ir import lower
    say = progress or (lambda msg: None)
    special = plan is not None and not plan.trivial
    strict = strict_causality or model.strict_causality
    with clock("graph"):  # (a scene's graph is built once, for its plan: given)
        graph = graph_of(model, progress) if graph is None else graph
    with clock("causality"):
        caus = causality_of(graph, not strict, progress)
        if plan is not None:
            _check_plan_effects(graph, plan)
    sp_ = _Special(graph, caus)
    if special:
        with clock("specialise"):
            sp_ = specialise(graph, caus, plan, progress)
    if getattr(sp_.graph, "units", None) is None:  # the full graph's dimensions (FMI units)
        object.__setattr__(sp_.graph, "units", graph.units)
    notes = list(sp_.notes)
    with clock("equations"):
        say("deriving equations")
        kw = {} if symbolic_max is None else {"symbolic_max": symbolic_max}
        kw["newton"] = not strict  # strict: a nonlinear algebraic loop stays an error too
        eqs = derive(sp_.graph, sp_.causality, progress, fold=sp_.fold, zero=sp_.zero, **kw)
        if special:
            eqs, more = _sliced(eqs, plan, sp_, progress)
            notes += more
    if notes:
        notes.insert(0, f"specialised for scene {plan.scene!r}")
    with clock("lower"):
        try:
            low = lower(eqs, progress, linear=target == "numpy" and linear)
        except ModelError as exc:  # an output the linearisation cannot differentiate: placed
            places = {o.name: o.coord for o in model.body.outputs}
            out = places.get(getattr(exc, "output", None))
            if exc.coord is not None or out is None:
                raise
            raise ModelError(out, exc.message) from None
    units = graph.units

    def printer(equations: bool = True, check: bool = True) -> str:
        # (the C target's numpy twin lowers B, C, D on demand, when it is first linearised)
        return print_numpy(model, low, tuple(notes), progress, units, equations, check,
                           linear or target != "numpy")
    text = None
    if target == "numpy":
        with clock("print"):
            text = printer()
    return Compiled(model, sp_.graph, sp_.causality, eqs, text, tuple(notes), low,
                    tuple(clock.times), printer)


def _sliced(eqs, plan, sp_: _Special, progress) -> tuple[Equations, list[str]]:
    """The equations sliced to the scene's outputs, and the notes on states removed."""
    # lazy: the compile path, which a warm run never loads
    from bgc.core.specialize import slice_outputs, states_note

    notes: list[str] = []
    if plan.outputs:
        (progress or (lambda msg: None))("slicing to the requested outputs")
        eqs, snotes, _ = slice_outputs(eqs)
        notes += list(snotes)
    if len(eqs.states) < len(sp_.full_states):
        notes.append(states_note(list(sp_.full_states), {sv.name for sv in eqs.states},
                                 sp_.removed))
    return eqs, notes


def print_numpy(model: Model, low, notes: tuple[str, ...], progress=None,
                units=None, equations: bool = True, check: bool = True,
                linear: bool = True) -> str:
    """Stage 7 for the numpy backend: the module's text from the IR. ``units``: the unit
    check's report (bgc.core.units.UnitReport): an output without a declared unit gets its
    inferred one in OUTPUT_UNITS (the axes of plots)."""
    # lazy: the compile path, which a warm run never loads
    from bgc.backends.numpy.printer import render

    return render(low.eq, source=Path(model.file).name, source_hash=model.source_hash,
                  description=model.description, header_notes=notes, progress=progress,
                  output_units={o.name: units.output_unit(o.name, o.unit) if units else o.unit
                                for o in model.body.outputs},
                  input_units={i.name: i.unit for i in model.inputs}, lowered=low,
                  equations=equations, check=check, linear=linear)


def _short(v) -> str:
    if isinstance(v, tuple):
        return "[" + ", ".join(_short(r) if isinstance(r, tuple) else repr(r) for r in v) + "]"
    return repr(v)


# ---------------------------------------------------------------------------------------------
# Stage 1 and the whole compile of a model or a scene

def parse(path) -> Model:
    return parse_file(path)


def compile_file(path: str | Path, progress=None, strict_causality: bool = False,
                 symbolic_max: int | None = None, target: str = "numpy") -> Compiled:
    if progress:
        progress("parsing")
    t0 = time.perf_counter()
    with gc_paused():
        model = parse(path)
    t1 = time.perf_counter()
    c = compile_model(model, progress, strict_causality=strict_causality,
                      symbolic_max=symbolic_max, target=target)
    return replace(c, times=(("parse", t1 - t0),) + c.times)


def check_scene_for(scene, model_path, label=None) -> None:
    """A scene must be for the model it is given with (``label``: how to name the model)."""
    if model_path is None or Path(scene.model_path).resolve() != Path(model_path).resolve():
        raise ModelError(scene.model_coord, f"the scene is for {scene.model_path}, not "
                                            f"{label if label is not None else model_path}")


def scene_compiled(scene, progress=None, specialise: bool = True,
                   strict_causality: bool = False, target: str = "numpy",
                   linear: bool = True) -> Compiled:
    """Stages 1-7 of a scene: the scene's model (its signals and parameter values:
    :func:`bgc.format.scene.scene_model`) specialised to its plan (``specialise=False``: the
    scene's full model). Plots must name outputs the module keeps."""
    t0 = time.perf_counter()
    # lazy: the compile path, which a warm run never loads
    from bgc.core.graph import build_graph  # (the compile path: sympy, networkx)
    from bgc.core.specialize import plan_for

    t1 = time.perf_counter()
    with gc_paused():  # (parse and graph allocate as much as the later stages: see gc_paused)
        model = scene_model(scene)
        t2 = time.perf_counter()
        graph = build_graph(model)  # stage 2 once: for the plan's parameters and the compile
        plan = plan_for(scene, graph.params) if specialise else None
    t3 = time.perf_counter()
    c = compile_model(model, progress, plan, strict_causality=strict_causality, target=target,
                      graph=graph, linear=linear)
    if specialise:
        check_outputs(scene, [o[0] for o in c.equations.outputs])
    more = {"imports": t1 - t0, "graph": t3 - t2}
    return replace(c, times=(("parse", t2 - t1),) + tuple((s, v + more.get(s, 0.0))
                                                          for s, v in c.times))


def compile_source(model=None, scene=None, progress=None, strict_causality: bool = False,
                   label=None, specialise: bool = True, target: str = "numpy",
                   linear: bool = True) -> Compiled:
    """Stages 1-7 of a model (a path, or a parsed Model) or of a scene (for that model, when
    both are given; ``specialise=False``: the scene's full model): the one compile every
    caller shares. ``linear=False``: a scene's numpy module without B, C, D (a bare model
    keeps them always)."""
    if scene is not None:
        if model is not None:
            check_scene_for(scene, model if isinstance(model, (str, Path)) else None, label)
        return scene_compiled(scene, progress, specialise, strict_causality, target, linear)
    if isinstance(model, (str, Path)):
        return compile_file(model, progress, strict_causality=strict_causality, target=target)
    return compile_model(model, progress, strict_causality=strict_causality, target=target)


# ---------------------------------------------------------------------------------------------
# Stage 8: the one compile of a scene or a model for a backend, through the cache

def usable_backend(backend: str, progress=None) -> str:
    """The backend a run can use: "c" without a compiler (or without the C runtime) says so
    and falls back to numpy."""
    if backend != "c":
        return backend

    say = progress or (lambda msg: None)
    if not cbuild.available():
        say(f"no C compiler ({cbuild.cc_text()!r} cannot run; set CC): "
            "using the numpy backend")
        return "numpy"
    if not cbuild.runtime_sources():
        say("the C runtime (templates/c/runtime/*.c) is not installed: using the numpy "
            "backend")
        return "numpy"
    return backend


#: The methods whose step loop runs in C (templates/c/binding.py's C_METHODS); the others run
#: scipy's step loop over the C functions, no faster than numpy's.
C_STEP_METHODS = ("Radau", "Rodas4", "DOP853")


def default_backend(method: str) -> tuple[str, str]:
    """(backend, why) for a run that names no backend: "c" where the system C compiler works
    (the probe kept in the compile cache) and the method's step loop runs in C, else "numpy";
    why says which in a few words (the summary line shows it). A C build that then fails
    still falls back to numpy (:func:`build` with ``fallback``)."""
    if method not in C_STEP_METHODS + ("auto",):  # (auto: DOP853 or Radau, both in C)
        return "numpy", f"default: {method} has no C step loop"
    if not cbuild.available():
        return "numpy", f"default: no C compiler ({cbuild.cc_text()!r} cannot run)"
    if not cbuild.runtime_sources():
        return "numpy", "default: the C runtime is not installed"
    return "c", "default: a C compiler works"


def module_name(model, scene=None, specialise: bool = True) -> str:
    """The loaded module's name: the model file's stem (and the scene's name)."""
    if scene is not None:
        return f"{Path(scene.model_path).stem}_{scene.name}{'' if specialise else '_full'}"
    return Path(model).stem if isinstance(model, (str, Path)) else "string"


def build(model=None, scene=None, backend: str = "numpy", *, use_cache: bool = True,
          strict_causality: bool = False, progress=None, fallback: bool = False,
          label=None, specialise: bool = True, linear: bool | None = None) -> Built:
    """The one compile of a scene (or a bare model: a path, or a parsed Model, never cached)
    for a backend, through the compile cache: a hit loads the entry without compiling (and
    without importing sympy); a miss compiles (:func:`compile_source`), keeps the entry and
    loads it. ``fallback``: without a C compiler or for a model the C backend refuses, say so
    and use numpy (else the error stands). A scene's plots must name the module's outputs.
    ``specialise=False``: the scene's full model (every effect, parameter and output).
    ``linear``: a scene's numpy module with the linearisation's B, C, D; by default a
    scene's module has none (its runs never call them: `bgc linearize SCENE` asks for them,
    a cache entry of its own), a bare model's always has them."""
    import numpy as np

    linear = scene is None if linear is None else linear
    if fallback:
        backend = usable_backend(backend, progress)
    path = scene.model_path if scene is not None else model
    cached = use_cache and specialise and isinstance(path, (str, Path))
    store = cache_mod.Cache() if cached else None
    key, files, scene_bytes = (cache_mod.key_inputs(
        backend, path, None if scene is None else scene.file,
        extra=("strict" if strict_causality else "") + _nolinear(scene, backend, linear))
        if cached else (None, [], None))
    name = module_name(model, scene, specialise)
    made: list[Compiled] = []
    ctimes: list[tuple[str, float]] = []  # the C stages (print C, wrapper, build C, ...)

    def compile_fn():
        made.append(compile_source(model, scene, progress, strict_causality, label,
                                   specialise, backend, linear))
        return made[-1]
    t0 = time.perf_counter()
    with np.errstate(all="ignore"):  # X0 is computed on import: no numpy warnings
        try:
            compiled, mod = backends.load(name, backend, key, compile_fn,
                                          store if key is not None else None, progress, ctimes)
        except (CUnsupported, CompilerFailed) as exc:  # a CC that runs but cannot build
            if not fallback or backend != "c":
                raise
            (progress or (lambda msg: None))(f"{exc.message}: using the numpy backend")
            return build(model, scene, "numpy", use_cache=use_cache,
                         strict_causality=strict_causality, progress=progress, label=label,
                         specialise=specialise, linear=linear)
    if backend == "c":  # what only the numpy module's equations compute (u=, B, C, D)
        mod._NUMPY_MODULE = _numpy_twin(made, model, scene, name, use_cache, strict_causality,
                                        label, specialise)
    times = (made[-1].times if made else ()) + tuple(ctimes)  # the rest is the load
    times += (("load", time.perf_counter() - t0 - sum(s for _, s in times)),)
    if scene is not None:
        _check_scene_module(scene, mod)
    return Built(backend, mod, compiled, None if key is None else
                 (backend, key, files, scene_bytes), name, times)


def _nolinear(scene, backend: str, linear: bool) -> str:
    """The cache key's mark of a scene's numpy module printed without B, C, D."""
    return "" if linear or scene is None or backend != "numpy" else "\0nolinear"


def _numpy_twin(made, model, scene, name, use_cache, strict_causality, label, specialise):
    """() -> the numpy module of what a C wrapper was built from, made on first call: printed
    from this process's compile when there was one, else through the cache (numpy entry)."""
    def twin():
        if made:
            return backends.load_module(made[-1].source, f"{name}_numpy")
        return build(model, scene, "numpy", use_cache=use_cache,
                     strict_causality=strict_causality, label=label,
                     specialise=specialise, linear=True).module
    return twin


def _check_scene_module(scene, mod) -> None:
    check_against(scene, mod)
    # lazy: numpy's import, which only a loaded module's checks need (not `bgc check`, --help)
    from bgc.run.plots import check_plots

    check_plots(scene, mod.OUTPUT_SHAPES)  # a plot that cannot be drawn: before any run


# ---------------------------------------------------------------------------------------------
# `bgc check` and bgc.check: stages 2-5, one implementation

@dataclass(frozen=True)
class Checked:
    """A model checked as far as its equations: ``error`` is what stops its compilation
    (derivative causality under ``causality: strict``: then ``equations`` is None)."""
    model: Model
    graph: BondGraph
    causality: Causality
    equations: Equations | None
    error: ModelError | None = None


def check_model(model: Model, strict_causality: bool = False, progress=None) -> Checked:
    """Stages 2-5 as a compile runs them (the model's ``causality: strict`` or
    ``strict_causality`` refuses derivative causality; a resistor law in the wrong fixed form
    is that law's error), the strict refusal kept as data rather than raised."""
    # lazy: the compile path, which a warm run never loads
    from bgc.core.causality import derivative_message
    from bgc.core.equations import derive

    strict = strict_causality or model.strict_causality
    graph = graph_of(model, progress)
    caus = causality_of(graph, True, progress)
    if caus.derivative and strict:
        err = ModelError(graph.element(caus.derivative[0]).coord,
                         derivative_message(graph, caus))
        return Checked(model, graph, caus, None, err)
    with gc_paused():
        eqs = derive(graph, caus, progress, newton=not strict)
    return Checked(model, graph, caus, eqs)
