"""The driver: each stage takes and returns frozen dataclasses."""
from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

from .causality import Causality, assign_causality
from .emit import render
from .equations import Equations, derive
from .graph import BondGraph, build_graph
from .parse import Model, parse_file
from .specialize import Plan, recausal, remove_effects, slice_outputs


@dataclass(frozen=True)
class Compiled:
    model: Model
    graph: BondGraph
    causality: Causality
    equations: Equations
    source: str  # the generated module's text


def analyse(model: Model, progress=None, allow_derivative: bool = False
            ) -> tuple[BondGraph, Causality]:
    say = progress or (lambda msg: None)
    say("building the bond graph")
    graph = build_graph(model)
    say("assigning causality (SCAP)")
    return graph, assign_causality(graph, allow_derivative=allow_derivative)


def compile_model(model: Model, progress=None, plan: Plan | None = None) -> Compiled:
    """Compile a model, specialised to a scene's plan (effects, folded parameters, outputs)."""
    say = progress or (lambda msg: None)
    special = plan is not None and not plan.trivial
    graph, caus = analyse(model, progress, allow_derivative=special)
    notes: list[str] = []
    fold, zero = None, None
    if special:
        say("specialising for the scene")
        notes.append(f"specialised for scene {plan.scene!r}")
        if plan.effects_off:
            notes.append("effects off: " + ", ".join(sorted(plan.effects_off)))
            rem = remove_effects(graph, plan.effects_off)
            caus, moved = recausal(graph, caus, rem, plan.effects_off)
            graph, zero = rem.graph, rem.zero
            notes += list(rem.notes) + list(moved)
        elif caus.derivative:
            from .causality import derivative_message
            from .errors import ModelError

            raise ModelError(graph.element(caus.derivative[0]).coord,
                             derivative_message(graph, caus))
        if plan.fold:
            fold = plan.fold
            notes.append("parameters folded in as constants: " + ", ".join(
                f"{k} = {_short(v)}" for k, v in sorted(plan.fold.items())))
    say("deriving equations")
    eqs = derive(graph, caus, progress, fold=fold, zero=zero)
    if special and plan.outputs:
        eqs, snotes = slice_outputs(eqs, plan.outputs)
        notes += list(snotes)
    text = render(eqs, source=Path(model.file).name, source_hash=model.source_hash,
                  description=model.description, header_notes=tuple(notes), progress=progress)
    return Compiled(model, graph, caus, eqs, text)


def _short(v) -> str:
    return repr(v) if not isinstance(v, tuple) else "matrix"


def compile_file(path: str | Path, progress=None) -> Compiled:
    if progress:
        progress("parsing")
    return compile_model(parse_file(path), progress)


def write_atomic(path: str | Path, text: str) -> None:
    """Write to a temporary file beside the target, then rename: never a half-written file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
