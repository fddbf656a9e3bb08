"""The driver: each stage takes and returns frozen dataclasses."""
from __future__ import annotations

import contextlib
import gc
from dataclasses import dataclass
from pathlib import Path

from bgc.backends.numpy.printer import render
from bgc.base.errors import ModelError
from bgc.core.causality import (
    Causality,
    assign_causality,
    derivative_message,
    fixed_r_culprit,
)
from bgc.core.effects import known_effects, remove_effects
from bgc.core.equations import Equations, derive
from bgc.core.graph import BondGraph, build_graph
from bgc.core.specialize import (
    Plan,
    recausal,
    select_outputs,
    slice_outputs,
    state_owners,
    states_note,
)
from bgc.format.parse import Model, parse_file
from bgc.lower.ir import lower


@dataclass(frozen=True)
class Compiled:
    model: Model
    graph: BondGraph
    causality: Causality
    equations: Equations
    source: str  # the generated module's text
    notes: tuple[str, ...] = ()  # what specialisation removed and why (also in the header)
    lowered: object = None  # bgc.lower.ir.Lowered: the backend-neutral functions (C printer too)


def analyse(model: Model, progress=None, allow_derivative: bool = False
            ) -> tuple[BondGraph, Causality]:
    say = progress or (lambda msg: None)
    say("building the bond graph")
    graph = build_graph(model)
    say("assigning causality (SCAP)")
    return graph, assign_causality(graph, allow_derivative=allow_derivative)


@contextlib.contextmanager
def gc_paused():
    """The cyclic garbage collector off for the block (and back to its former state after).

    A compile allocates millions of small, short-lived sympy objects that reference counting
    frees; the collector's passes over them found almost nothing and cost a fifth of the 3R2S
    compile (measured: bench/bench_compile.py). Memory stays bounded: the model limits bound
    the compile, and the collector runs again as soon as the block ends."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def compile_model(model: Model, progress=None, plan: Plan | None = None,
                  strict_causality: bool = False, symbolic_max: int | None = None) -> Compiled:
    """Compile a model, specialised to a scene's plan (effects, folded parameters, outputs).

    A plan that changes nothing gives exactly the module of the model alone. Storage elements
    in derivative causality are eliminated (their states follow from the others) unless
    ``strict_causality`` or the model's ``causality: strict`` asks for today's error."""
    with gc_paused():
        return _compile_model(model, progress, plan, strict_causality, symbolic_max)


def _compile_model(model: Model, progress, plan: Plan | None, strict_causality: bool,
                   symbolic_max: int | None) -> Compiled:
    say = progress or (lambda msg: None)
    special = plan is not None and not plan.trivial
    strict = strict_causality or model.strict_causality
    graph, caus = analyse(model, progress, allow_derivative=not strict)
    if caus.derivative:  # an R law in the wrong fixed form is the mistake, not the storage
        culprit = fixed_r_culprit(graph, caus)
        if culprit is not None:
            raise ModelError(culprit[0], culprit[1])
    if plan is not None:  # every effect the scene names (on or off) must exist
        effects = known_effects(graph)
        for eff in list(plan.effect_coords) + sorted(plan.effects_off):
            if eff not in effects:
                raise ModelError(plan.effect_coords.get(eff, plan.coord),
                                 f"the model has no effect {eff!r} (effects: "
                                 f"{', '.join(sorted(effects)) or 'none'})")
    notes: list[str] = []
    fold, zero, rem = None, None, None
    if special:
        say("specialising for the scene")
        full_states = state_owners(graph, caus)
        if caus.derivative and plan.effects_off:
            # turning effects off re-assigns causality, which assumes every storage element
            # independent; folding parameters and slicing outputs work on the equations
            raise ModelError(graph.element(caus.derivative[0]).coord,
                             derivative_message(graph, caus).replace(
                                 "derivative causality:", "derivative causality (a scene "
                                 "that turns effects off needs every storage element "
                                 "independent):", 1))
        rem = remove_effects(graph, plan.effects_off, plan.coord)
        if plan.effects_off:
            notes.append("effects off: " + ", ".join(sorted(plan.effects_off)))
            caus, cnotes = recausal(graph, caus, rem, plan)
            notes += list(rem.notes) + list(cnotes)
        spec_graph, onotes = select_outputs(graph, rem, plan)
        notes += list(onotes)
        graph, zero = spec_graph, (rem.zero or None)
        if plan.fold:
            fold = plan.fold
            notes.append("parameters folded in as constants: " + ", ".join(
                f"{k} = {_short(v)}" for k, v in sorted(plan.fold.items())))
    say("deriving equations")
    kw = {} if symbolic_max is None else {"symbolic_max": symbolic_max}
    kw["newton"] = not strict  # strict: a nonlinear algebraic loop stays an error too
    eqs = derive(graph, caus, progress, fold=fold, zero=zero, **kw)
    if special and plan.outputs:
        say("slicing to the requested outputs")
        eqs, snotes, _ = slice_outputs(eqs)
        notes += list(snotes)
    if special and len(eqs.states) < len(full_states):
        notes.append(states_note(full_states, {sv.name for sv in eqs.states}, rem))
    if notes:
        notes.insert(0, f"specialised for scene {plan.scene!r}")
    low = lower(eqs, progress)
    text = render(eqs, source=Path(model.file).name, source_hash=model.source_hash,
                  description=model.description, header_notes=tuple(notes), progress=progress,
                  output_units={o.name: o.unit for o in model.body.outputs},
                  input_units={i.name: i.unit for i in model.inputs}, lowered=low)
    return Compiled(model, graph, caus, eqs, text, tuple(notes), low)


def _short(v) -> str:
    if isinstance(v, tuple):
        return "[" + ", ".join(_short(r) if isinstance(r, tuple) else repr(r) for r in v) + "]"
    return repr(v)


def compile_file(path: str | Path, progress=None, strict_causality: bool = False,
                 symbolic_max: int | None = None) -> Compiled:
    if progress:
        progress("parsing")
    return compile_model(parse_file(path), progress, strict_causality=strict_causality,
                         symbolic_max=symbolic_max)
