"""FMU export from the command line and the API: compile a model (or a scene's specialised
model) through the driver, then package it (bgc.backends.fmu.export)."""
from __future__ import annotations

from pathlib import Path

from bgc.backends.fmu.export import KINDS, package_fmu
from bgc.base.errors import ModelError
from bgc.base.outfiles import check_output
from bgc.base.reach import run_inputs
from bgc.base.store import Cache
from bgc.format.scene import parse_scene
from bgc.run.driver import build, check_scene_for


def export_fmu(model_path, out, scene_path=None, kind: str = "both", progress=None) -> Path:
    """Compile MODEL (or SCENE's specialised model) and write the FMU to out (atomically)."""
    say = progress or (lambda msg: None)
    if kind not in KINDS:
        raise ModelError(None, f"unknown FMU kind {kind!r}: one of {', '.join(KINDS)}")
    ins = run_inputs(model_path, scene_path)
    check_output(out, ins, "--fmu")  # refused before anything is compiled
    scene = None
    if scene_path is not None:
        scene = parse_scene(scene_path)

    if scene is not None:
        check_scene_for(scene, model_path)
        if scene.initial is not None:  # computed at a run's start, not compiled in
            say("warning: the FMU starts from the model's initial state: the scene's initial: "
                f"(line {scene.initial_coord.line}) is not carried into it; set the states in "
                "the importing tool")
        say("compiling the scene's model")
    else:
        say("parsing")
    # the one compile (bgc.run.driver): the scene's module is the one `bgc simulate` runs
    compiled = build(model_path, scene, "numpy", use_cache=False, progress=progress).compiled

    # the C runtime's objects from the compile cache, as `bgc compile --target c` builds them
    return package_fmu(compiled, out, scene, kind, progress, Cache(),
                       inputs=run_inputs(model_path, scene_path))
