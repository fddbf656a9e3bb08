"""Run a scene: compile its model with the scene's signals, simulate, collect outputs."""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import ModelError
from .scene import (Scene, check_against, free_values, load_module, param_values, parse_scene,
                    plan_for, scene_model)


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
    backend: str = "numpy"
    atol: float = 1e-9


def compile_scene(scene: Scene, progress=None, specialise: bool = True):
    """The scene's module: its signals compiled in, and (by default) specialised to it.

    ``specialise=False`` gives the scene's full model: the model with the scene's input
    signals, every effect on, every parameter and output kept."""
    model = scene_model(scene)
    plan = None
    if specialise:
        from .graph import build_graph

        plan = plan_for(scene, build_graph(model).params)
    from .compiler import compile_model

    c = compile_model(model, progress, plan)
    mod = load_module(c.source, f"{c.model.name}_{scene.name}{'' if specialise else '_full'}")
    check_against(scene, mod)
    return c, mod


def runtime_params(scene: Scene, mod) -> dict | None:
    """The scene's free parameter values the module does not already have as defaults (the
    scene's values of top-level parameters are compiled in as defaults, so most scenes pass
    none and use the module's precomputed defaults)."""
    out = {}
    for k, v in free_values(scene).items():
        if k in mod.PARAM_DEFAULTS and not np.array_equal(np.asarray(v, dtype=float),
                                                          np.asarray(mod.PARAM_DEFAULTS[k])):
            out[k] = v
    return out or None


def scene_module(scene: Scene, progress=None, backend: str = "numpy", use_cache: bool = True):
    """The scene's specialised module for a backend, through the compile cache: a warm run
    imports neither sympy nor the compiler. Without a C compiler, backend "c" says so and
    falls back to numpy. Returns (backend used, module)."""
    from . import backends, cache as cache_mod

    say = progress or (lambda msg: None)
    if backend == "c":
        from . import cbuild

        if not cbuild.available():
            say(f"no C compiler ({' '.join(cbuild.compiler())!r} cannot run; set CC): "
                "using the numpy backend")
            backend = "numpy"
        elif not cbuild.runtime_sources():
            say("the C runtime (templates/c/runtime/*.c) is not installed: using the numpy "
                "backend")
            backend = "numpy"
    store = cache_mod.Cache() if use_cache else None
    key = cache_mod.key(backend, scene.model_path, scene.file) if store is not None else None

    def compile_fn():
        c, _ = _compiled(scene, progress)
        return c
    name = f"{Path(scene.model_path).stem}_{scene.name}"
    _, mod = backends.load(name, backend, key, compile_fn, store, progress)
    check_against(scene, mod)
    return backend, mod


def _compiled(scene: Scene, progress=None):
    from .compiler import compile_model
    from .graph import build_graph

    model = scene_model(scene)
    return compile_model(model, progress, plan_for(scene, build_graph(model).params)), model


def run_scene(path, progress=None, method=None, rtol=None, max_wall=None, atol=None,
              backend=None, use_cache: bool = True) -> SceneResult:
    say = progress or (lambda msg: None)
    scene = parse_scene(path)
    t0 = time.perf_counter()
    backend, mod = scene_module(scene, progress, backend or scene.backend, use_cache)
    t1 = time.perf_counter()
    method = method or scene.method
    rtol = rtol or scene.rtol
    atol = scene.atol if atol is None else atol
    say(f"simulating {scene.name} with {method} ({backend}), rtol {rtol:g}, atol {atol:g}")
    dt = scene.dt or (scene.t_span[1] - scene.t_span[0]) / 1000
    try:
        res = mod.simulate(scene.t_span, dt=dt, method=method, rtol=rtol, atol=atol,
                           p=runtime_params(scene, mod), breakpoints=scene.breakpoints,
                           max_step=scene.max_step, max_wall=max_wall)
    except mod.SimulationError as exc:
        raise ModelError(scene.coord, f"simulation failed: {exc}") from None
    t2 = time.perf_counter()
    t, x, y = res
    return SceneResult(scene, mod, t, x, y, res.stats, method, rtol, t1 - t0, t2 - t1,
                       backend, atol)


# ---------------------------------------------------------------------------------------------
# Full model against scene: what specialisation saves (bgc explain, bench/bench_scenes.py)

_NOT_WORK = {"empty", "zeros", "asarray", "broadcast_shapes", "broadcast_to", "shape", "stack",
             "array", "reshape"}
_SETUP = {"_pv", "_bshape", "_uv", "x", "dx", "J", "_shape", "_b"}


def operation_counts(source: str) -> dict:
    """Arithmetic operations and function calls in the generated rhs and jacobian (after CSE),
    counted on the module's own code: binary and unary operators and calls of numpy functions,
    leaving out the unpacking of x, p and u and the allocation of the result."""
    import ast

    tree = ast.parse(source)
    out = {}
    for fn in tree.body:
        if not isinstance(fn, ast.FunctionDef) or fn.name not in ("rhs", "jacobian"):
            continue
        n = 0
        for stmt in fn.body:
            if isinstance(stmt, ast.Assign):
                tgt = stmt.targets[0]
                if isinstance(tgt, ast.Tuple) or (isinstance(tgt, ast.Name) and tgt.id in _SETUP):
                    continue
            elif not isinstance(stmt, ast.Return):
                continue
            for node in ast.walk(stmt):
                if isinstance(node, (ast.BinOp, ast.UnaryOp)):
                    n += 1
                elif isinstance(node, ast.Call):
                    f = node.func
                    if isinstance(f, ast.Attribute) and f.attr not in _NOT_WORK:
                        n += 1
        out[fn.name] = n
    return out


def rhs_cost(mods, ps, t: float, rounds: int = 7, budget: float = 0.04) -> list[float]:
    """Seconds per rhs call of each module at its initial state, measured side by side:
    ``rounds`` interleaved rounds of about ``budget`` seconds each, the median per module
    (a shared machine is noisy; compare the ratios)."""
    import statistics

    xs = [np.asarray(m.X0, dtype=float) for m in mods]
    ns = []
    for m, x, p in zip(mods, xs, ps):  # calibrate: calls per round
        n, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < budget / 4 or n < 3:
            m.rhs(t, x, p)
            n += 1
        ns.append(max(3, int(n * 4)))
    per: list[list[float]] = [[] for _ in mods]
    for _ in range(rounds):
        for k, (m, x, p, n) in enumerate(zip(mods, xs, ps, ns)):
            t0 = time.perf_counter()
            for _ in range(n):
                m.rhs(t, x, p)
            per[k].append((time.perf_counter() - t0) / n)
    return [statistics.median(v) for v in per]


@dataclass(frozen=True)
class Explanation:
    scene: Scene
    full: object  # Compiled: the scene's model with every effect, parameter and output
    special: object  # Compiled: specialised to the scene
    full_module: object
    module: object
    compile_time: tuple[float, float]  # full, scene [s]
    same: bool  # the scene changes nothing: both modules are the same text

    @property
    def states(self) -> tuple[list[str], list[str]]:
        """(kept, removed) state names."""
        kept = list(self.module.STATE_NAMES)
        return kept, [s for s in self.full_module.STATE_NAMES if s not in set(kept)]

    @property
    def full_params(self) -> dict | None:
        """Run-time parameters of the full module: the scene's values it lacks as defaults."""
        out = {k: v for k, v in param_values(self.scene).items()
               if k in self.full_module.PARAM_DEFAULTS and not np.array_equal(
                   np.asarray(v, dtype=float), np.asarray(self.full_module.PARAM_DEFAULTS[k]))}
        return out or None

    @property
    def params(self) -> dict | None:
        """Run-time parameters of the scene's module (as `bgc simulate` passes them)."""
        return runtime_params(self.scene, self.module)

    def ops(self) -> tuple[dict, dict]:
        return operation_counts(self.full.source), operation_counts(self.special.source)

    def rhs_cost(self, rounds: int = 7) -> tuple[float, float]:
        """Seconds per rhs call, full and scene, at the initial state with the modules' own
        parameter values (p=None: no parameter dictionary unpacked per call), so the numbers
        compare the equations' arithmetic."""
        sc = self.scene
        t = 0.5 * (sc.t_span[0] + sc.t_span[1])
        if self.same:
            c = rhs_cost([self.module], [None], t, rounds)[0]
            return c, c
        a, b = rhs_cost([self.full_module, self.module], [None, None], t, rounds)
        return a, b


def explain_scene(path, progress=None) -> Explanation:
    scene = parse_scene(path) if not isinstance(path, Scene) else path
    say = progress or (lambda msg: None)
    say("compiling the full model")
    t0 = time.perf_counter()
    full, full_mod = compile_scene(scene, None, specialise=False)
    t1 = time.perf_counter()
    say("compiling the scene's specialisation")
    spec, mod = compile_scene(scene, None, specialise=True)
    t2 = time.perf_counter()
    return Explanation(scene, full, spec, full_mod, mod, (t1 - t0, t2 - t1),
                       full.source == spec.source)
