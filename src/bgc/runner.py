"""Run a scene: compile its model with the scene's signals, simulate, collect outputs."""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .compiler import compile_model
from .errors import ModelError
from .scene import Scene, check_against, load_module, param_values, parse_scene, scene_model


@dataclass(frozen=True)
class SceneResult:
    scene: Scene
    module: object
    t: np.ndarray
    x: np.ndarray
    y: dict
    stats: dict
    method: str
    rtol: float
    compile_time: float
    run_time: float


def compile_scene(scene: Scene, progress=None):
    model = scene_model(scene)
    c = compile_model(model, progress)
    mod = load_module(c.source, f"{c.model.name}_{scene.name}")
    check_against(scene, mod)
    return c, mod


def run_scene(path, progress=None, method=None, rtol=None) -> SceneResult:
    say = progress or (lambda msg: None)
    scene = parse_scene(path)
    t0 = time.perf_counter()
    c, mod = compile_scene(scene, progress)
    t1 = time.perf_counter()
    method = method or scene.method
    rtol = rtol or scene.rtol
    say(f"simulating {scene.name} with {method}, rtol {rtol:g}")
    dt = scene.dt or (scene.t_span[1] - scene.t_span[0]) / 1000
    try:
        res = mod.simulate(scene.t_span, dt=dt, method=method, rtol=rtol, atol=scene.atol,
                           p=param_values(scene) or None, breakpoints=scene.breakpoints,
                           max_step=scene.max_step)
    except mod.SimulationError as exc:
        raise ModelError(scene.coord, f"simulation failed: {exc}") from None
    t2 = time.perf_counter()
    t, x, y = res
    if scene.outputs:
        y = {k: y[k] for k in scene.outputs}
    return SceneResult(scene, mod, t, x, y, res.stats, method, rtol, t1 - t0, t2 - t1)
