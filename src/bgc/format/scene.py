"""Scenes: which model, how long, parameter overrides, input signals, outputs, solver, plots.

A scene's input expressions replace the model's input defaults before compilation, so the
generated module carries the scene's signals; its parameter overrides are passed at run time.
"""
from __future__ import annotations

import dataclasses
import hashlib
from dataclasses import dataclass
from pathlib import Path

import yaml

from bgc.base import BACKENDS  # noqa: F401 (the one list, re-exported)
from bgc.base.errors import Coord, ModelError
from bgc.base.limits import LIMITS
from bgc.base.safeio import not_a_file, read_text_bounded
from bgc.format import tables as _tables
from bgc.format.parse import Model, parse_file
from bgc.format.reader import Reader, check_name, outside, param_value, require
from bgc.format.whitelist import Expr

#: the solver methods a scene or --method may name; "auto": DOP853 or Radau by a stiffness probe
#: (bgc.run.method_choice; a sweep, which runs a batch, takes Radau)
METHODS = ("Radau", "BDF", "LSODA", "RK45", "RK23", "DOP853", "Rodas4", "auto")
PLOT_KINDS = ("time", "path3d", "loci")


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
    # initial states: None (the model's), "equilibrium", or {state or element: (value, Coord)}
    initial: object = None
    initial_coord: Coord | None = None
    #: solver.backend: numpy, or c (the C step loop); None when the scene names none (a run
    #: then takes C where a C compiler works: bgc.run.driver.default_backend)
    backend: str | None = None
    max_steps: int = 50_000  # solver.max_steps: the most steps a run may take (explicit methods)
    #: `constraints: {initial: project}`: the start is projected onto the model's closed-loop
    #: constraints at run start (bgc.run.consistency.project_start); where it says so
    project: bool = False
    project_coord: Coord | None = None
    #: the scene's solver gives atol (else the default, which a run may tighten where a state
    #: stays small next to it: bgc.run.steps.tightened_atol)
    atol_given: bool = False


def parse_scene(path: str | Path) -> Scene:
    path = str(path)
    text = read_text_bounded(path, None, "scene file", LIMITS.scene_bytes)
    r = Reader(path, text)
    root = r.compose()
    if root is None:
        raise ModelError(Coord(path, 1, 1), "the scene file is empty")
    top = r.mapping(root, "the scene")
    allowed = ("bgc_scene", "name", "description", "model", "duration", "t_span", "parameters",
               "inputs", "outputs", "solver", "breakpoints", "plots", "effects", "free",
               "initial", "constraints",
               "sweep")  # sweep: read by bgc.studies.sweep (bgc sweep); bgc simulate ignores it
    require(r, top, root, allowed, "the scene", required=("bgc_scene", "model"))
    version = r.scalar(top["bgc_scene"][1], "bgc_scene")
    if isinstance(version, bool) or version != 1:
        raise ModelError(r.coord(top["bgc_scene"][1]), "unsupported scene format version")
    name = Path(path).stem
    if "name" in top:
        name = check_name(r.string(top["name"][1], "name"), r.coord(top["name"][1]), "scene")
    model_path = _model_path(r, top, path)
    t0, t1 = _span(r, top, root)
    params = _parameters(r, top)
    inputs = _inputs(r, top)
    outputs, output_coords = _outputs(r, top)
    method, rtol, atol, dt, max_step, backend, max_steps, atol_given = _solver(r, top,
                                                                             t1 - t0)
    bps = ()
    if "breakpoints" in top:
        items = r.seq(top["breakpoints"][1], "breakpoints")
        if len(items) > LIMITS.breakpoints:
            raise ModelError(r.coord(items[LIMITS.breakpoints]), f"more than "
                                                                 f"{LIMITS.breakpoints} "
                                                                 "breakpoints (the limit)")
        bps = tuple(_a_time(r, b, "breakpoint") for b in items)
    plots = _plots(r, top, outputs, output_coords)
    effects = _effects(r, top)
    desc = r.string(top["description"][1], "description") if "description" in top else ""
    free = _free(r, top, params)
    initial, initial_coord = None, None
    if "initial" in top:
        initial, initial_coord = _initial(r, top["initial"][1]), r.coord(top["initial"][0])
    project, project_coord = _constraints(r, top)
    return Scene(path, name, model_path, (t0, t1), params, inputs, outputs, method, rtol, atol,
                 dt, max_step, bps, tuple(plots), effects, desc, r.coord(root),
                 hashlib.sha256(text.encode()).hexdigest()[:16], free, output_coords,
                 r.coord(top["model"][1]), initial, initial_coord,
                 backend, max_steps, project, project_coord, atol_given)


def _constraints(r: Reader, top: dict) -> tuple[bool, Coord | None]:
    """``constraints: {initial: check | project}``: project the start (the scene's `initial:`
    values, or the model's at the scene's parameters) onto the closed loops' constraints at
    run start; `check` (the default) refuses an inconsistent start."""
    if "constraints" not in top:
        return False, None
    node = top["constraints"][1]
    m = r.mapping(node, "constraints")
    require(r, m, node, ("initial",), "constraints")
    if "initial" not in m:
        return False, None
    vn = m["initial"][1]
    word = r.scalar(vn, "constraints: initial")
    if word not in ("check", "project"):
        raise ModelError(r.coord(vn), "constraints: initial must be 'check' or 'project', got "
                         f"{str(word)[:40]!r}")
    return word == "project", r.coord(vn)


def _model_path(r: Reader, top: dict, path: str) -> str:
    """model: the model file, relative to the scene's folder; it must exist."""
    model_rel = r.string(top["model"][1], "model")
    if "\0" in model_rel:
        raise ModelError(r.coord(top["model"][1]), "the model's path contains a NUL byte")
    model_path = str(Path(path).parent / model_rel)
    why = not_a_file(model_path)
    if why is not None:
        raise ModelError(r.coord(top["model"][1]), f"model file {model_rel!r} {why}")
    return model_path


def _a_time(r: Reader, node, what: str) -> float:
    """A time, within the limit of times."""
    tmax = LIMITS.time_magnitude
    v = r.number(node, what)
    if abs(v) > tmax:
        raise ModelError(r.coord(node), f"{what}: {v:g} s is beyond the limit of times "
                                        f"(|t| <= {tmax:g} s)")
    return v


def _span(r: Reader, top: dict, root) -> tuple[float, float]:
    """duration or t_span: the start and the end."""
    if "t_span" in top and "duration" in top:  # which one would win is no answer
        later = max((top["t_span"][0], top["duration"][0]), key=lambda n: n.start_mark.index)
        raise ModelError(r.coord(later), "the scene: give duration or t_span, not both")
    if "t_span" in top:
        span_node = top["t_span"][1]
        span = r.seq(span_node, "t_span")
        if len(span) != 2:
            raise ModelError(r.coord(span_node), "t_span is [start, end]")
        t0, t1 = (_a_time(r, s, "t_span") for s in span)
    elif "duration" in top:
        span_node = top["duration"][1]
        t0, t1 = 0.0, _a_time(r, span_node, "duration")
    else:
        raise ModelError(r.coord(root), "the scene: give duration or t_span")
    if not t1 > t0:
        raise ModelError(r.coord(span_node), f"the scene: the end time {t1:g} is not after "
                                             f"the start {t0:g}")
    return t0, t1


def _parameters(r: Reader, top: dict) -> dict:
    """parameters: dotted id -> (number or matrix, Coord of its key)."""
    params = {}
    if "parameters" in top:
        for pname, (kn, vn) in r.mapping(top["parameters"][1], "parameters").items():
            parts = pname.split(".")
            for part in parts:
                check_name(part, r.coord(kn), "parameter")
            v = param_value(r, pname, vn)
            if isinstance(v, Expr):
                raise ModelError(r.coord(vn), f"scene parameter {pname!r} must be a number or "
                                              "a matrix")
            params[pname] = (v, r.coord(kn))
    return params


def _inputs(r: Reader, top: dict) -> dict:
    """inputs: name -> (an expression or a table, Coord of its key)."""
    inputs = {}
    if "inputs" in top:
        for iname, (kn, vn) in r.mapping(top["inputs"][1], "inputs").items():
            check_name(iname, r.coord(kn), "input")
            if _tables.is_table(r, vn):  # data from a CSV file beside the scene
                inputs[iname] = (_tables.read_table(r, vn, f"input {iname!r}"), r.coord(kn))
                continue
            inputs[iname] = (r.expr(vn, f"input {iname!r}"), r.coord(kn))
    return inputs


def _outputs(r: Reader, top: dict) -> tuple[tuple[str, ...], dict]:
    """outputs: the names asked for (empty: all), and the Coord of each."""
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
    return outputs, output_coords


def _solver(r: Reader, top: dict, length: float) -> tuple:
    """solver: (method, rtol, atol, dt, max_step, backend, max_steps, whether it gives atol),
    each checked against the span."""
    method, rtol, atol, dt, max_step = "Radau", 1e-6, 1e-9, None, float("inf")
    backend, max_steps = None, Scene.max_steps
    if "solver" in top:
        sm = r.mapping(top["solver"][1], "solver")
        require(r, sm, top["solver"][1], ("method", "rtol", "atol", "dt", "max_step", "backend",
                                           "max_steps"), "solver")
        if "max_steps" in sm:
            max_steps = check_max_steps(r.integer(sm["max_steps"][1], "max_steps"),
                                        r.coord(sm["max_steps"][1]), "solver max_steps")
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
                v = _solver_number(r, sm, key, length)
                if key == "rtol":
                    rtol = v
                elif key == "atol":
                    atol = v
                elif key == "dt":
                    dt = v
                else:
                    max_step = v
    return (method, rtol, atol, dt, max_step, backend, max_steps,
            "solver" in top and "atol" in sm)


def _solver_number(r: Reader, sm: dict, key: str, length: float) -> float:
    """solver rtol, atol, dt or max_step: positive, and within the limits for the span."""
    v = r.number(sm[key][1], key)  # finite, within 10**300
    where = r.coord(sm[key][1])
    if not v > 0:
        raise ModelError(where, f"solver {key} must be positive")
    if key == "rtol":
        check_rtol(v, where, "solver rtol")
    if key == "dt" and length / v + 1 > LIMITS.output_samples:
        raise ModelError(where, f"solver dt {v:g} over {length:g} s gives "
                                f"{length / v + 1:.0f} output samples, more than "
                                f"the limit of {LIMITS.output_samples}")
    if key == "max_step" and v < length * LIMITS.min_step_fraction:
        raise ModelError(where, f"solver max_step {v:g} is below the limit of "
                                f"{LIMITS.min_step_fraction:g} times the span "
                                f"({length * LIMITS.min_step_fraction:g} s): the "
                                "run would not end")
    return v


def _plots(r: Reader, top: dict, outputs: tuple, output_coords: dict) -> list:
    """plots: each a kind, the outputs it shows (among the scene's), a title and labels."""
    plots = []
    if "plots" in top:
        for pn in r.seq(top["plots"][1], "plots"):
            pm = r.mapping(pn, "a plot")
            require(r, pm, pn, ("kind", "outputs", "title", "labels"), "a plot",
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
    return plots


def _effects(r: Reader, top: dict) -> dict:
    """effects: name -> (on, Coord of its key)."""
    effects = {}
    if "effects" in top:
        for ename, (kn, vn) in r.mapping(top["effects"][1], "effects").items():
            check_name(ename, r.coord(kn), "effect")
            v = r.scalar(vn, f"effect {ename!r}")
            if not isinstance(v, bool):
                raise ModelError(r.coord(vn), f"effect {ename!r}: write on or off (true/false)")
            effects[ename] = (v, r.coord(kn))
    return effects


def _free(r: Reader, top: dict, params: dict) -> tuple[str, ...]:
    """free: scene parameters that stay parameters of the module (each set by the scene)."""
    free = ()
    if "free" in top:
        free = tuple(r.string(f, "free parameter") for f in r.seq(top["free"][1], "free"))
        for k, (f, fn) in enumerate(zip(free, top["free"][1].value)):
            if f not in params:
                raise ModelError(r.coord(fn), f"free parameter {f!r} is not set by the scene's "
                                              "parameters (free keeps a scene value tunable)")
            if f in free[:k]:
                raise ModelError(r.coord(fn), f"free parameter {f!r} is listed twice")
    return free


#: The most steps a run may be given (solver max_steps, --max-steps).
MAX_STEPS_LIMIT = 10 ** 9

#: The span `bgc simulate MODEL.yaml` runs a model over when no --t-end is given (s).
MODEL_T_END = 10.0


def check_max_steps(v: int, where, what: str) -> int:
    """A step budget: a whole number from 1 to MAX_STEPS_LIMIT, else a located error."""
    if not 1 <= v <= MAX_STEPS_LIMIT:
        raise ModelError(where, f"{what} {v} is outside 1..{MAX_STEPS_LIMIT}")
    return v


def is_model_file(path) -> bool:
    """Does the YAML file at path look like a model (a top-level ``bgc:`` key and no
    ``bgc_scene:``)? Reading errors say False: the scene reader then reports them."""
    try:
        text = read_text_bounded(str(path), None, "scene file", LIMITS.scene_bytes)
        root = Reader(str(path), text).compose()
    except (ModelError, OSError):
        return False
    if not isinstance(root, yaml.MappingNode):
        return False
    keys = {k.value for k, _ in root.value if isinstance(k, yaml.ScalarNode)}
    return "bgc" in keys and "bgc_scene" not in keys


def model_scene(path, t_end: float | None = None) -> Scene:
    """The scene `bgc simulate MODEL.yaml` runs: the model with its defaults (parameters,
    inputs, every output), from t = 0 to t_end (default MODEL_T_END), Radau at the default
    tolerances. The model is checked when it is compiled."""
    path = str(path)
    t1 = MODEL_T_END if t_end is None else t_end
    return Scene(path, Path(path).stem, path, (0.0, float(t1)), {}, {}, (), "Radau", 1e-6, 1e-9,
                 None, float("inf"), (), (), {}, "", Coord(path, 1, 1), "", (), {},
                 Coord(path, 1, 1))


def with_t_end(scene: Scene, t_end: float, where=None) -> Scene:
    """The scene run to t_end instead of its own end (--t-end); a located error when t_end
    is not after the start or beyond the limit of times."""
    t0 = scene.t_span[0]
    if not (t_end > t0 and abs(t_end) <= LIMITS.time_magnitude):
        raise ModelError(where, f"--t-end {t_end:g} must be after the scene's start {t0:g} s "
                                f"and within {LIMITS.time_magnitude:g} s")
    if scene.dt and (t_end - t0) / scene.dt + 1 > LIMITS.output_samples:
        raise ModelError(where, f"--t-end {t_end:g} with the scene's dt {scene.dt:g} gives more "
                                f"than {LIMITS.output_samples} output samples (the limit)")
    return dataclasses.replace(scene, t_span=(t0, float(t_end)))


def _initial(r: Reader, node):
    """``initial: equilibrium`` or ``initial: {state-or-element: value}`` (a number, or a
    list / nested list for a vector or matrix state); names are checked against the
    compiled module's states by :func:`initial_state`."""

    if isinstance(node, yaml.ScalarNode):
        v = r.scalar(node, "initial")
        if v != "equilibrium":
            raise ModelError(r.coord(node), "initial: write 'equilibrium' or a mapping "
                                            "{state or element: value}")
        return "equilibrium"
    out = {}
    for sname, (kn, vn) in r.mapping(node, "initial").items():
        for part in sname.replace("[", ".").replace("]", "").replace(",", ".").split("."):
            if not part.isdigit():
                check_name(part, r.coord(kn), "state", allow_reserved=True)
        if isinstance(vn, yaml.ScalarNode):
            vals = (r.number(vn, f"initial {sname!r}"),)
        else:
            vals = []
            for item in r.seq(vn, f"initial {sname!r}"):
                if isinstance(item, yaml.SequenceNode):
                    vals += [r.number(c, f"initial {sname!r}") for c in item.value]
                else:
                    vals.append(r.number(item, f"initial {sname!r}"))
            vals = tuple(vals)
        out[sname] = (vals, r.coord(kn))
    return out


def initial_state(scene: Scene, module, p=None):
    """The scene's initial state for ``module``: the module's own x0 with the scene's values
    set (names: a state of STATE_NAMES, or an element or state whose components follow in
    order), or its equilibrium with the inputs held at their values at t0."""
    import numpy as np

    if scene.initial is None:
        return None
    t0 = scene.t_span[0]
    if scene.initial == "equilibrium":
        with np.errstate(all="ignore"):  # a singular or not finite search: one located line
            try:
                x, info = module.equilibrium(p=p, t=t0)
            except (np.linalg.LinAlgError, ValueError, FloatingPointError) as exc:
                raise ModelError(scene.initial_coord, f"initial: no equilibrium found: the "
                                 f"search failed ({exc}); is the right-hand side finite near "
                                 "the initial state?") from None
        if not np.all(info.converged) or not np.all(np.isfinite(x)):
            raise ModelError(scene.initial_coord, f"initial: no equilibrium found (max "
                                                  f"|dx/dt| = {np.max(info.residual):.3g})")
        return x
    x = np.array(module.initial_state(p), dtype=float)
    for i, v in initial_values(scene, module).items():
        x[i] = v
    return x


def initial_values(scene: Scene, module) -> dict:
    """The states a scene's ``initial:`` mapping sets: state index -> value (located errors
    for a name the module does not have, or the wrong number of values)."""
    names, out = list(module.STATE_NAMES), {}
    for sname, (vals, coord) in scene.initial.items():
        if sname in names:
            idx = [names.index(sname)]
        else:
            idx = [i for i, n in enumerate(names)
                   if n.split("[")[0] in (sname, sname + ".p", sname + ".q")]
        if not idx:
            raise ModelError(coord, f"initial: the model has no state {sname!r}"
                             + (" (removed by the scene?)" if names else "")
                             + f" (states: {', '.join(names[:12])}"
                             + (", ..." if len(names) > 12 else "") + ")")
        if len(vals) != len(idx):
            raise ModelError(coord, f"initial {sname!r}: {len(vals)} value(s) for "
                                    f"{len(idx)} state(s) ({', '.join(names[i] for i in idx)})")
        out.update(zip(idx, (float(v) for v in vals)))
    return out


def check_rtol(v: float, where: Coord | None, what: str) -> float:
    """A relative tolerance: finite, within [LIMITS.min_rtol, 1] (a scene's, or ``--rtol``)."""
    if not LIMITS.min_rtol <= v <= 1:  # false for NaN too
        raise ModelError(where, f"{what} {v:g} is outside [{LIMITS.min_rtol:g}, 1] (the limit "
                                "of tolerances: doubles carry about 16 digits)")
    return v


def apply_scene(model: Model, scene: Scene) -> Model:
    """The model with the scene's input signals in place of the input defaults (and the
    scene's parameter values checked against the parameters' shapes)."""
    top = {p.name: p for p in model.body.params}
    for k, (v, coord) in scene.params.items():
        if k in top and not isinstance(top[k].value, Expr):
            _check_value_shape(k, v, top[k], coord)
    names = {i.name for i in model.inputs}
    for iname, (_, coord) in scene.inputs.items():
        if iname not in names:
            raise ModelError(coord, f"the model has no input {iname!r} "
                                    f"(inputs: {', '.join(sorted(names)) or 'none'})")
    new_inputs = []
    for i in model.inputs:
        if i.name not in scene.inputs:
            new_inputs.append(i)
            continue
        v, coord = scene.inputs[i.name]
        if isinstance(v, _tables.Table):
            if i.shape:
                raise ModelError(coord, f"input {i.name!r} has shape {list(i.shape)}: a table "
                                        "gives a scalar input")
            new_inputs.append(dataclasses.replace(i, default=Expr("0", v.coord), table=v))
        else:
            new_inputs.append(dataclasses.replace(i, default=v, table=None))
    new_inputs = tuple(new_inputs)
    return dataclasses.replace(model, inputs=new_inputs)


def check_against(scene: Scene, module) -> None:
    """Scene plots must name outputs of the compiled module."""
    check_outputs(scene, module.OUTPUT_NAMES)


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


def _value_shape(v):
    """A parameter value's shape: () for a number, (n, 1) for a vector (a list of numbers or
    a column), (r, c) for a matrix, None for a ragged one."""
    if not isinstance(v, (list, tuple)):
        return ()
    rows = [len(r) if isinstance(r, (list, tuple)) else None for r in v]
    if all(n is None for n in rows):
        return (len(v), 1)
    if any(n is None for n in rows) or len(set(rows)) != 1:
        return None
    return (len(v), rows[0])


def _shape_text(shape) -> str:
    if shape is None:
        return "a ragged value"
    return "a scalar" if shape == () else "a " + "x".join(map(str, shape)) + " value"


def _check_value_shape(pid: str, v, param, coord) -> None:
    """A scene's value for a parameter has the parameter's shape: a scalar for a 3x3 matrix
    would fold into something else entirely."""
    want, got = _value_shape(param.value), _value_shape(v)
    if got != want:
        raise ModelError(coord, f"parameter {pid!r}: the scene gives {_shape_text(got)}, the "
                                f"model's parameter is {_shape_text(want)} (line "
                                f"{param.coord.line} of {param.coord.file})")
    check_bounds(pid, v, param, coord, "the scene gives")


def check_bounds(pid: str, v, param, coord, who: str) -> None:
    """A value for a scalar parameter within the model's ``min`` and ``max`` (which the model's
    own value had to keep): a scene or a sweep may not run a negative mass the model refused."""
    if not isinstance(v, (int, float)) or isinstance(v, bool):
        return
    out = outside(v, param.min, param.max)
    if out is not None:
        raise ModelError(coord, f"parameter {pid!r}: {who} {v:g}, {out[0]} the model's "
                                f"{out[1]} {out[2]:g} (line {param.coord.line} of "
                                f"{param.coord.file})")


def check_outputs(scene: Scene, names) -> None:
    """Scene plots must name outputs the compiled module has."""
    for pl in scene.plots:
        for o in pl.outputs:
            if o not in names:
                raise ModelError(pl.coord, f"plot: the module has no output {o!r} "
                                           f"(outputs: {', '.join(names)})")
