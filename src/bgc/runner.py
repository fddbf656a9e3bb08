"""Run a scene: compile its model with the scene's signals, simulate, collect outputs."""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .compiler import compile_model
from .errors import ModelError
from .scene import (Scene, check_against, free_values, load_module, param_values, parse_scene,
                    plan_for, scene_model)
from .specialize import known_effects as _effects


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


def compile_scene(scene: Scene, progress=None, specialise: bool = True):
    """The scene's module: its signals compiled in, and (by default) specialised to it."""
    model = scene_model(scene)
    plan = None
    if specialise:
        from .graph import build_graph

        graph = build_graph(model)
        plan = plan_for(scene, graph.params)
        if effects_unknown := set(k for k, (on, _) in scene.effects.items()) - _effects(graph):
            name = sorted(effects_unknown)[0]
            raise ModelError(scene.effects[name][1], f"the model has no effect {name!r} "
                                                     f"(effects: {', '.join(sorted(_effects(graph))) or 'none'})")
    c = compile_model(model, progress, plan)
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
                           p=free_values(scene) or None, breakpoints=scene.breakpoints,
                           max_step=scene.max_step)
    except mod.SimulationError as exc:
        raise ModelError(scene.coord, f"simulation failed: {exc}") from None
    t2 = time.perf_counter()
    t, x, y = res
    return SceneResult(scene, mod, t, x, y, res.stats, method, rtol, t1 - t0, t2 - t1)
