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


@dataclass(frozen=True)
class Compiled:
    model: Model
    graph: BondGraph
    causality: Causality
    equations: Equations
    source: str  # the generated module's text


def analyse(model: Model, progress=None) -> tuple[BondGraph, Causality]:
    say = progress or (lambda msg: None)
    say("building the bond graph")
    graph = build_graph(model)
    say("assigning causality (SCAP)")
    return graph, assign_causality(graph)


def compile_model(model: Model, progress=None, notes: tuple[str, ...] = ()) -> Compiled:
    graph, caus = analyse(model, progress)
    if progress:
        progress("deriving equations")
    eqs = derive(graph, caus, progress)
    text = render(eqs, source=Path(model.file).name, source_hash=model.source_hash,
                  description=model.description, header_notes=notes, progress=progress)
    return Compiled(model, graph, caus, eqs, text)


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
