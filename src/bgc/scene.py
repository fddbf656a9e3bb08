"""Scenes: which model, how long, parameter overrides, input signals, outputs, solver, plots.

A scene's input expressions replace the model's input defaults before compilation, so the
generated module carries the scene's signals; its parameter overrides are passed at run time.
"""
from __future__ import annotations

import dataclasses
import hashlib
import importlib.abc
import importlib.util
import linecache
import sys
from dataclasses import dataclass
from pathlib import Path

import yaml

from .errors import Coord, ModelError
from .expr import Expr
from .parse import Model, _Reader, _param_value, _require, check_name, parse_file

METHODS = ("Radau", "BDF", "LSODA", "RK45", "RK23", "DOP853", "Rodas4")
PLOT_KINDS = ("time", "path3d", "loci")
BACKENDS = ("numpy", "c")


@dataclass(frozen=True)
class Plot:
    kind: str
    outputs: tuple[str, ...]
    title: str
    coord: Coord
    labels: tuple[str, ...] = ()


@dataclass(frozen=True)
class Scene:
    file: str
    name: str
    model_path: str
    t_span: tuple[float, float]
    params: dict  # id -> float or nested tuple
    inputs: dict  # name -> Expr
    outputs: tuple[str, ...]
    method: str
    rtol: float
    atol: float
    dt: float | None
    max_step: float
    breakpoints: tuple[float, ...]
    plots: tuple[Plot, ...]
    effects: dict  # effect name -> bool
    description: str = ""
    coord: Coord | None = None
    source_hash: str = ""
    free: tuple[str, ...] = ()  # scene parameters that stay parameters (not folded)
    output_coords: dict = dataclasses.field(default_factory=dict)  # output -> Coord
    model_coord: Coord | None = None  # where the scene names its model
    backend: str = "numpy"  # solver.backend: numpy, or c (the C step loop)


def parse_scene(path: str | Path) -> Scene:
    path = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ModelError(Coord(path, 1, 1), f"cannot read scene file: {exc}") from None
    r = _Reader(path, text)
    root = r.compose()
    if root is None:
        raise ModelError(Coord(path, 1, 1), "the scene file is empty")
    top = r.mapping(root, "the scene")
    allowed = ("bgc_scene", "name", "description", "model", "duration", "t_span", "parameters",
               "inputs", "outputs", "solver", "breakpoints", "plots", "effects", "free")
    _require(r, top, root, allowed, "the scene", required=("bgc_scene", "model"))
    if r.scalar(top["bgc_scene"][1], "bgc_scene") != 1:
        raise ModelError(r.coord(top["bgc_scene"][1]), "unsupported scene format version")
    name = Path(path).stem
    if "name" in top:
        name = check_name(r.string(top["name"][1], "name"), r.coord(top["name"][1]), "scene")
    model_rel = r.string(top["model"][1], "model")
    model_path = str(Path(path).parent / model_rel)
    if not Path(model_path).is_file():
        raise ModelError(r.coord(top["model"][1]), f"model file {model_rel!r} does not exist")
    if "t_span" in top:
        span = r.seq(top["t_span"][1], "t_span")
        if len(span) != 2:
            raise ModelError(r.coord(top["t_span"][1]), "t_span is [start, end]")
        t0, t1 = (r.number(s, "t_span") for s in span)
    elif "duration" in top:
        t0, t1 = 0.0, r.number(top["duration"][1], "duration")
    else:
        raise ModelError(r.coord(root), "the scene: give duration or t_span")
    if not t1 > t0:
        raise ModelError(r.coord(root), f"the scene: the end time {t1} is not after {t0}")
    params = {}
    if "parameters" in top:
        for pname, (kn, vn) in r.mapping(top["parameters"][1], "parameters").items():
            parts = pname.split(".")
            for part in parts:
                check_name(part, r.coord(kn), "parameter")
            v = _param_value(r, pname, vn)
            if isinstance(v, Expr):
                raise ModelError(r.coord(vn), f"scene parameter {pname!r} must be a number or "
                                              "a matrix")
            params[pname] = (v, r.coord(kn))
    inputs = {}
    if "inputs" in top:
        for iname, (kn, vn) in r.mapping(top["inputs"][1], "inputs").items():
            check_name(iname, r.coord(kn), "input")
            inputs[iname] = (r.expr(vn, f"input {iname!r}"), r.coord(kn))
    outputs, output_coords = (), {}
    if "outputs" in top:
        for o in r.seq(top["outputs"][1], "outputs"):
            oname = check_name(r.string(o, "output"), r.coord(o), "output", allow_reserved=True)
            if oname in output_coords:
                raise ModelError(r.coord(o), f"output {oname!r} is listed twice")
            output_coords[oname] = r.coord(o)
        if not output_coords:
            raise ModelError(r.coord(top["outputs"][1]), "outputs: list at least one output "
                                                         "(leave the key out for all of them)")
        outputs = tuple(output_coords)
    method, rtol, atol, dt, max_step = "Radau", 1e-6, 1e-9, None, float("inf")
    backend = "numpy"
    if "solver" in top:
        sm = r.mapping(top["solver"][1], "solver")
        _require(r, sm, top["solver"][1], ("method", "rtol", "atol", "dt", "max_step", "backend"),
                 "solver")
        if "backend" in sm:
            backend = r.string(sm["backend"][1], "backend")
            if backend not in BACKENDS:
                raise ModelError(r.coord(sm["backend"][1]), f"unknown backend {backend!r} "
                                                            f"(one of {', '.join(BACKENDS)})")
        if "method" in sm:
            method = r.string(sm["method"][1], "method")
            if method not in METHODS:
                raise ModelError(r.coord(sm["method"][1]), f"unknown solver method {method!r} "
                                                           f"(one of {', '.join(METHODS)})")
        for key in ("rtol", "atol", "dt", "max_step"):
            if key in sm:
                v = r.number(sm[key][1], key)
                if not v > 0:
                    raise ModelError(r.coord(sm[key][1]), f"solver {key} must be positive")
                if key == "rtol":
                    rtol = v
                elif key == "atol":
                    atol = v
                elif key == "dt":
                    dt = v
                else:
                    max_step = v
    bps = ()
    if "breakpoints" in top:
        bps = tuple(r.number(b, "breakpoint") for b in r.seq(top["breakpoints"][1], "breakpoints"))
    plots = []
    if "plots" in top:
        for pn in r.seq(top["plots"][1], "plots"):
            pm = r.mapping(pn, "a plot")
            _require(r, pm, pn, ("kind", "outputs", "title", "labels"), "a plot",
                     required=("kind", "outputs"))
            kind = r.string(pm["kind"][1], "kind")
            if kind not in PLOT_KINDS:
                raise ModelError(r.coord(pm["kind"][1]), f"unknown plot kind {kind!r} "
                                                         f"(one of {', '.join(PLOT_KINDS)})")
            outs = tuple(r.string(o, "output") for o in r.seq(pm["outputs"][1], "outputs"))
            labels = tuple(r.string(o, "label") for o in r.seq(pm["labels"][1], "labels")) \
                if "labels" in pm else ()
            title = r.string(pm["title"][1], "title") if "title" in pm else ""
            for o, on in zip(outs, pm["outputs"][1].value):
                if outputs and o not in output_coords:
                    raise ModelError(r.coord(on), f"plot: output {o!r} is not among the "
                                                  f"scene's outputs ({', '.join(outputs)})")
            plots.append(Plot(kind, outs, title, r.coord(pn), labels))
    effects = {}
    if "effects" in top:
        for ename, (kn, vn) in r.mapping(top["effects"][1], "effects").items():
            check_name(ename, r.coord(kn), "effect")
            v = r.scalar(vn, f"effect {ename!r}")
            if not isinstance(v, bool):
                raise ModelError(r.coord(vn), f"effect {ename!r}: write on or off (true/false)")
            effects[ename] = (v, r.coord(kn))
    desc = r.string(top["description"][1], "description") if "description" in top else ""
    free = ()
    if "free" in top:
        free = tuple(r.string(f, "free parameter") for f in r.seq(top["free"][1], "free"))
        for k, (f, fn) in enumerate(zip(free, top["free"][1].value)):
            if f not in params:
                raise ModelError(r.coord(fn), f"free parameter {f!r} is not set by the scene's "
                                              "parameters (free keeps a scene value tunable)")
            if f in free[:k]:
                raise ModelError(r.coord(fn), f"free parameter {f!r} is listed twice")
    return Scene(path, name, model_path, (t0, t1), params, inputs, outputs, method, rtol, atol,
                 dt, max_step, bps, tuple(plots), effects, desc, r.coord(root),
                 hashlib.sha256(text.encode()).hexdigest()[:16], free, output_coords,
                 r.coord(top["model"][1]), backend)


def apply_scene(model: Model, scene: Scene) -> Model:
    """The model with the scene's input signals in place of the input defaults."""
    names = {i.name for i in model.inputs}
    for iname, (_, coord) in scene.inputs.items():
        if iname not in names:
            raise ModelError(coord, f"the model has no input {iname!r} "
                                    f"(inputs: {', '.join(sorted(names)) or 'none'})")
    new_inputs = tuple(dataclasses.replace(i, default=scene.inputs[i.name][0])
                       if i.name in scene.inputs else i for i in model.inputs)
    return dataclasses.replace(model, inputs=new_inputs)


def check_against(scene: Scene, module) -> None:
    """Scene plots must name outputs of the compiled module."""
    check_outputs(scene, module.OUTPUT_NAMES)


def plan_for(scene: Scene, graph_params) -> "Plan":
    """The specialisation a scene asks for: effects off, parameters to fold, outputs."""
    from .specialize import Plan

    known = {p.id: p for p in graph_params}
    fold = {}
    for pid, (v, coord) in scene.params.items():
        if pid not in known or isinstance(known[pid].value, Expr):
            raise ModelError(coord, f"the model has no parameter {pid!r}"
                             + (" (it is derived from others)" if pid in known else ""))
        if pid not in scene.free:
            fold[pid] = v
    off = frozenset(k for k, (on, _) in scene.effects.items() if not on)
    return Plan(off, fold, scene.outputs, scene.name,
                {k: c for k, (_, c) in scene.effects.items()}, dict(scene.output_coords),
                scene.coord, tuple(f for f in scene.free))


def param_values(scene: Scene) -> dict:
    """The scene's parameter values as plain numbers and nested lists."""
    out = {}
    for pid, (v, _) in scene.params.items():
        if isinstance(v, tuple):
            v = [list(r) for r in v] if len(v[0]) > 1 else [r[0] for r in v]
        out[pid] = v
    return out


def free_values(scene: Scene) -> dict:
    """Run-time values of the scene's free parameters."""
    return {k: v for k, v in param_values(scene).items() if k in scene.free}


def load_module(source: str, name: str, check=None, code=None):
    """Import generated source as a module, from memory: nothing is written to disk. The code
    is compiled under a recognisable file name (``<bgc NAME>``) registered with ``linecache``,
    so tracebacks and ``inspect`` still show the generated lines."""
    if code is None:  # code: compiled from checked text (a trusted cache entry)
        if check is None:
            from .skeleton import check_skeleton as check
        check(source)  # never execute a module whose top level is not the template's
    modname = f"bgc_generated_{name}"
    filename = f"<bgc {name}>"
    loader = _SourceLoader(modname, filename, source, code)
    spec = importlib.util.spec_from_loader(modname, loader, origin=filename)
    mod = importlib.util.module_from_spec(spec)
    mod.__file__ = filename
    linecache.cache[filename] = (len(source), None, source.splitlines(True), filename)
    sys.modules[modname] = mod
    try:
        loader.exec_module(mod)
    except BaseException:
        sys.modules.pop(modname, None)
        raise
    return mod


class _SourceLoader(importlib.abc.Loader):
    """A loader for generated source held in memory (``get_source`` serves tracebacks,
    ``get_data`` the module's own text)."""

    def __init__(self, modname: str, filename: str, source: str, code=None):
        self.modname, self.filename, self.source, self.code = modname, filename, source, code

    def create_module(self, spec):
        return None

    def exec_module(self, module):
        code = self.code if self.code is not None else compile(self.source, self.filename,
                                                                 "exec")
        exec(code, module.__dict__)

    def get_source(self, fullname):
        return self.source

    def get_data(self, path):
        return self.source.encode("utf-8")


def scene_model(scene: Scene) -> Model:
    """The scene's model: its input signals, and its values for the model's top-level
    parameters in place of the defaults (the module keeps them as parameters unless the
    scene's plan folds them in)."""
    model = apply_scene(parse_file(scene.model_path), scene)
    values = {k: v for k, (v, _) in scene.params.items()}
    top = {p.name: p for p in model.body.params}
    if not any(k in top and not isinstance(top[k].value, Expr) for k in values):
        return model
    params = tuple(dataclasses.replace(p, value=values[p.name])
                   if p.name in values and not isinstance(p.value, Expr) else p
                   for p in model.body.params)
    return dataclasses.replace(model, body=dataclasses.replace(model.body, params=params))


def check_outputs(scene: Scene, names) -> None:
    """Scene plots must name outputs the compiled module has."""
    for pl in scene.plots:
        for o in pl.outputs:
            if o not in names:
                raise ModelError(pl.coord, f"plot: the module has no output {o!r} "
                                           f"(outputs: {', '.join(names)})")
