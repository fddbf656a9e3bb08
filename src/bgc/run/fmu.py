"""FMU export from the command line and the API: compile a model (or a scene's specialised
model) through the driver, then package it (bgc.backends.fmu.export)."""
from __future__ import annotations

from pathlib import Path

from bgc.backends.fmu.export import KINDS, package_fmu
from bgc.base.errors import ModelError


def export_fmu(model_path, out, scene_path=None, kind: str = "both", progress=None) -> Path:
    """Compile MODEL (or SCENE's specialised model) and write the FMU to out (atomically)."""
    from bgc.base.outfiles import check_output
    from bgc.base.reach import run_inputs

    say = progress or (lambda msg: None)
    if kind not in KINDS:
        raise ModelError(None, f"unknown FMU kind {kind!r}: one of {', '.join(KINDS)}")
    ins = run_inputs(model_path, scene_path)
    check_output(out, ins, "--fmu")  # refused before anything is compiled
    scene = None
    if scene_path is not None:
        from bgc.format.scene import parse_scene
        from bgc.run.runner import compile_scene

        scene = parse_scene(scene_path)
        if Path(scene.model_path).resolve() != Path(model_path).resolve():
            raise ModelError(scene.model_coord, f"the scene is for {scene.model_path}, not "
                                                f"{model_path}")
        say("compiling the scene's model")
        compiled, _ = compile_scene(scene, progress)
    else:
        from bgc.format.parse import parse_file
        from bgc.run.driver import compile_model

        say("parsing")
        compiled = compile_model(parse_file(model_path), progress)
    return package_fmu(compiled, out, scene, kind, progress, inputs=run_inputs(model_path,
                                                                               scene_path))
