"""Run a scene: compile its model with the scene's signals, simulate, collect outputs."""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from bgc.backends.load import load_module
from bgc.base.errors import ModelError, SimulationFailed
from bgc.format.scene import (
    Scene,
    free_values,
    initial_state,
    param_values,
    parse_scene,
)
from bgc.run import method_choice
from bgc.run.consistency import check_loop_start, project_start
from bgc.run.driver import build, default_backend, module_name, scene_compiled
from bgc.run.event_log import zeno_text
from bgc.run.progress import simulating_line
from bgc.run.steps import (
    STEPS_PER_PERIOD,
    fastest_input,
    rerun_tightened,
    scene_max_step,
    stepped_over,
)
from bgc.run.watch import dropped_drift


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
    #: (backend, key, [(path, bytes) the key digested], scene bytes) of the module's
    #: compile-cache entry; None when it did not go through the cache
    cache_entry: tuple | None = None
    module_name: str = ""
    #: the module's simulate arguments as the scene resolved them (a run record replays them)
    run_args: dict | None = None
    #: a hybrid model's event log: (t, event, instance index, x before, x after) per event
    events: tuple = ()
    #: why the run used its backend when the command and the scene named none, or C failed
    #: ("" when the backend was named and used); also the method auto chose, and a default
    #: atol the run tightened (the summary line's parenthesis)
    backend_why: str = ""
    #: the compile's stages and seconds (bgc.run.driver.STAGES; only "load" on a cache hit)
    stage_times: tuple = ()


def compile_scene(scene: Scene, progress=None, specialise: bool = True,
                  strict_causality: bool = False, linear: bool = False):
    """(Compiled, module) of the scene, compiled now and loaded from memory: its signals
    compiled in, and (by default) specialised to it (bgc.run.driver.scene_compiled).

    ``specialise=False`` gives the scene's full model: the model with the scene's input
    signals, every effect on, every parameter and output kept. ``linear``: keep the
    linearisation's B, C, D (runs and studies never call them)."""
    b = build(scene=scene, use_cache=False, strict_causality=strict_causality,
              progress=progress, specialise=specialise, linear=linear)
    return b.compiled, b.module


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


def scene_module(scene: Scene, progress=None, backend: str = "numpy", use_cache: bool = True,
                 strict_causality: bool = False):
    """The scene's specialised module for a backend, through the compile cache
    (bgc.run.driver.build): a warm run imports neither sympy nor the compiler. Without a C
    compiler, backend "c" says so and falls back to numpy. Returns (backend used, module)."""
    b = build(scene=scene, backend=backend, use_cache=use_cache,
              strict_causality=strict_causality, progress=progress, fallback=True)
    return b.backend, b.module


def scene_module_name(scene: Scene) -> str:
    return module_name(None, scene)


def _compiled(scene: Scene, progress=None, strict_causality: bool = False):
    c = scene_compiled(scene, progress, strict_causality=strict_causality)
    return c, c.model


def run_scene(path, progress=None, method=None, rtol=None, max_wall=None, atol=None,
              backend=None, use_cache: bool = True,
              strict_causality: bool = False, max_steps: int | None = None,
              choose_backend: bool = False) -> SceneResult:
    """Compile (or take from the cache) and run a scene. backend: "numpy" or "c", else the
    scene's; where neither names one, numpy, or with ``choose_backend`` (`bgc simulate`)
    C where a C compiler works (:func:`bgc.run.driver.default_backend`), the reason kept in
    the result's backend_why."""
    say = progress or (lambda msg: None)
    scene = path if isinstance(path, Scene) else parse_scene(path)

    t0 = time.perf_counter()
    method = method or scene.method
    asked, why = backend or scene.backend, ""
    if asked is None:  # neither the command nor the scene names one
        asked, why = default_backend(method) if choose_backend else ("numpy", "")
    built = build(scene=scene, backend=asked, use_cache=use_cache,
                  strict_causality=strict_causality, progress=progress, fallback=True)
    backend, mod, entry = built.backend, built.module, built.entry
    if backend != asked:  # the build said why (no compiler, a model C does not print, ...)
        why = "fell back from c, see above"
    t1 = time.perf_counter()
    rtol = rtol or scene.rtol
    atol_given = atol is not None or scene.atol_given  # else a run may tighten the default
    atol = scene.atol if atol is None else atol

    say(simulating_line(scene.name, method, backend, rtol, atol, why))
    if backend == "c" and method not in (*getattr(mod, "C_METHODS", (method,)), "auto"):
        say(f"note: {method} runs in scipy's Python step loop, calling the C functions (little "
            "faster than numpy); the C step loop runs Radau, Rodas4 and DOP853")
    dt = scene.dt or (scene.t_span[1] - scene.t_span[0]) / 1000
    p = runtime_params(scene, mod)
    x0 = initial_state(scene, mod, p)  # the scene's initial: values, or equilibrium
    if scene.project and getattr(mod, "CONSTRAINT_STATES", ()):
        # onto the closed loops' constraints (the model's own start too: the scene's
        # parameters may move the geometry), saying what changed
        x0, notes = project_start(mod, scene.t_span[0], x0 if x0 is not None else
                                  mod.initial_state(p), p, scene.project_coord)
        for note in notes:
            say(f"warning: {note}")
    if x0 is not None:  # against closed loops' constraints, as the compile checks the model's
        check_loop_start(mod, scene.t_span[0], x0, p, scene.initial_coord,
                         "scene initial state")
    max_step = scene_max_step(scene, mod)
    max_steps = scene.max_steps if max_steps is None else max_steps
    if max_step < scene.max_step:
        say(f"max_step {max_step:.3g} s: {STEPS_PER_PERIOD} steps per period of the input "
            f"{fastest_input(mod)!r} (solver max_step in the scene overrides it)")
    auto = method == "auto"
    if auto:  # DOP853 or Radau, by the model's Jacobian along a short probe
        method, mwhy = method_choice.choose(mod, scene.t_span, p, x0, scene.breakpoints,
                                            max_step)
        why = f"{why}; {mwhy}" if why else mwhy
        say(f"method {method} ({mwhy})")
    run = dict(dt=dt, rtol=rtol, atol=atol, p=p, breakpoints=scene.breakpoints, x0=x0,
               max_step=max_step, max_steps=max_steps, max_wall=max_wall)
    try:
        try:
            res = mod.simulate(scene.t_span, method=method, **run)
        except mod.SimulationError as exc:
            if not (auto and method == method_choice.EXPLICIT):
                raise
            # the probe missed it (a contact later in the span): Radau it is
            method = method_choice.IMPLICIT
            why += f"; {method_choice.EXPLICIT} failed at t = {exc.t:.6g}, rerun with Radau"
            say(f"{method_choice.EXPLICIT} failed ({exc}): rerunning with Radau")
            res = mod.simulate(scene.t_span, method=method, **run)
        if not atol_given:
            res, tight = rerun_tightened(mod, scene.t_span, method, run, res, say)
            atol, why = run["atol"], f"{why}; {tight}" if why and tight else why or tight
    except mod.SimulationError as exc:
        # the diagnosis reads the model's equations: compiled now if the module came from
        # the cache (a failed run can afford it)
        c, _ = _compiled(scene, None, strict_causality)
        if backend == "c" and getattr(exc, "where", None) is None and (
                "non-finite" in str(exc) or "step size fell below" in str(exc)):
            # a diverging run: C names the state or the step size, numpy's run the law
            mod, exc = _numpy_diagnosis(c, scene, method, run, mod, exc)
        raise simulation_failed(c, mod, scene, exc, p) from None
    t2 = time.perf_counter()
    t, x, y = res
    warning = stepped_over(mod, t, x, p, scene.breakpoints, res.stats.get("nsteps"))
    if warning:
        say(f"warning: {warning}")
    drift = dropped_drift(mod, t, x, p, rtol, atol)  # components dropped as redundant
    if drift:
        say(f"warning: {drift}")
    return SceneResult(scene, mod, t, x, y, res.stats, method, rtol, t1 - t0, t2 - t1,
                       backend, atol, entry, built.name,
                       dict(t_span=scene.t_span, dt=dt, method=method, rtol=rtol, atol=atol,
                            p=p, breakpoints=scene.breakpoints, x0=x0,
                            max_step=max_step, max_steps=max_steps, max_wall=max_wall),
                       tuple(getattr(res, "events", ())), why, tuple(built.times))


def _numpy_diagnosis(c, scene, method, run, mod, exc):
    """(module, error) to diagnose a C run that a value not finite (or a step size collapsing
    on a diverging run) stopped: the C runtime
    names only the state, the numpy module's run of the same scene the entry, which bgc's
    diagnosis traces to a law and a remedy. Rerun there (a failed run's path only); should
    the numpy run not fail, the C error stands."""
    with np.errstate(all="ignore"):  # X0 is computed on import: no numpy warnings
        npmod = load_module(c.source, scene_module_name(scene) + "_diagnosis")
        try:
            npmod.simulate(scene.t_span, method=method, **run)
        except npmod.SimulationError as np_exc:
            return npmod, np_exc
    return mod, exc


# ---------------------------------------------------------------------------------------------
# Which law made a value that is not finite (the module names the state; bgc, holding the
# equations, finds the element and, where known, a remedy)

#: Most assignments a diagnosis evaluates (it runs on failure only; sympy is slow).
_DIAGNOSE_MAX = 5000


def _num(expr, vals):
    """expr's value at vals (symbol -> float): a complex, or None if it cannot be evaluated."""
    import sympy as sp

    try:
        v = expr.xreplace({s: sp.Float(vals[s]) for s in expr.free_symbols if s in vals})
        if v.free_symbols:
            return None
        if v.has(sp.nan):
            return complex(np.nan)
        if v.has(sp.zoo, sp.oo, -sp.oo):
            return complex(-np.inf if v == -sp.oo else np.inf)
        return _bounded_value(v)
    except (TypeError, ValueError, ArithmeticError, AttributeError):
        return complex(np.nan)


def _bounded_value(v) -> complex:
    """A constant sympy expression's value in double precision with bounded work (sympy's
    own evalf of ``exp(exp(...))`` 100 deep runs for minutes); sympy only where the value is
    complex (to show it) or the expression holds a function the double evaluator lacks."""
    # lazy: the compile path, which a warm run never loads
    from bgc.format.expr import NumError, numeric

    try:
        x = numeric(v)
    except NumError as exc:
        if str(exc) == "overflow":
            return complex(np.inf)
        if str(exc) == "undefined":
            return complex(np.nan)
        x = None  # complex: sympy shows the value (roots and logs evaluate quickly)
    return complex(x) if x is not None else complex(v.evalf())


def _show(expr, limit: int = 160) -> str:
    """An expression for a one-line message, cut to ``limit`` characters."""
    text = " ".join(str(expr).split())
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _finite(v) -> bool:
    return v is None or (np.isfinite(v.real) and np.isfinite(v.imag) and v.imag == 0)


def _element_of(why: str) -> str | None:
    """The element id an assignment's description starts with (see equations.derive)."""
    for prefix in ("0-junction ", "1-junction "):
        if why.startswith(prefix):
            return why[len(prefix):].split(":", 1)[0]
    if why.startswith("derived parameter "):
        return None
    head = why.split(" (", 1)[0]
    return head or None


def _remedy(expr, vals, wrt=None) -> str:
    """A known cure for the law expr, at the point vals, that gave a non-finite value (or,
    with wrt, an infinite slope): a fractional power of zero, a log of zero, a division by
    zero, the root of a negative number."""
    import sympy as sp

    for node in sp.preorder_traversal(expr):
        if isinstance(node, sp.Pow) and node.exp.is_number:
            base = _num(node.base, vals)
            if base is None:
                continue
            e = float(node.exp)
            if abs(base) == 0 and 0 < e < 1:
                return (f" ({_show(node, 50)} at {_show(node.base, 40)} = 0): regularise it, "
                        "e.g. sqrt(abs(e) + eps**2) - eps for sqrt(abs(e)), or give it a "
                        "laminar (linear) region near 0")
            if abs(base) == 0 and e < 0:
                return f" (it divides by {_show(node.base, 60)}, which is 0 here)"
            if base.real < 0 and not float(e).is_integer():
                return (f" (it takes a fractional power of {_show(node.base, 60)}, which is "
                        "negative here: keep the argument positive)")
        if isinstance(node, sp.log):
            arg = _num(node.args[0], vals)
            if arg is not None and arg.real <= 0:
                return (f" (it takes the log of {_show(node.args[0], 60)}, which is "
                        f"{arg.real:g} here)")
    return ""


def simulation_failed(c, mod, scene, exc, p=None) -> SimulationFailed:
    """The user's error for the module's SimulationError ``exc``: at the scene, or for a value
    that is not finite at the law that made it, with a remedy where one is known."""
    coord, why = scene.coord, ""
    if getattr(exc, "where", None) is not None:  # a NonFiniteError: which law, and why
        with np.errstate(all="ignore"):
            found = nonfinite_culprit(c, mod, exc, p)
        if found is not None:
            coord, why = found[0] or scene.coord, found[1]
    text, zeno = zeno_text(exc)
    return SimulationFailed(coord, f"simulation failed: {text}{why or zeno}")


def check_start(c, mod, scene, p=None) -> None:
    """The model's rhs and Jacobian are finite where the scene starts: a short Radau run
    (it evaluates both at t0 first); a value that is not finite there is the located
    SimulationFailed of :func:`simulation_failed`. Other failures are left to the caller."""
    t0, t1 = scene.t_span
    span = (t0, t0 + 1e-9 * (t1 - t0))
    try:
        with np.errstate(all="ignore"):
            mod.simulate(span, t_eval=span[:1], method="Radau", p=p, rtol=1e-3, atol=1e-6,
                         max_steps=100)
    except mod.NonFiniteError as exc:
        raise simulation_failed(c, mod, scene, exc, p) from None
    except Exception:  # noqa: BLE001 - only the non-finite start is checked here
        pass


#: the generated module's functions the start check never calls, left out of the module it
#: loads (:func:`bgc.backends.skeleton.checked_code`): most of a large model's text, whose
#: compile would cost more than everything else the check does
START_UNUSED = ("jacobian", "outputs", "input_jacobian", "output_jacobian")


def check_module_start(c) -> None:
    """The compiled module's initial state and right-hand side at t = 0 with its default
    parameters are finite, or one located error naming the law that is not (a zero inertia or
    capacitance, a root of a negative parameter, ...): `bgc compile` writes no module that
    fails on its first call. (Loads the module from memory, as `bgc simulate` does, checked
    as it does, less the functions this check never calls: START_UNUSED.)"""
    # lazy: the compile path's check of the text (a warm run never loads it)
    from bgc.backends.skeleton import checked_code

    name = f"{c.model.name}_start_check"
    code = checked_code(c.source, f"<bgc {name}>", without=START_UNUSED)
    with np.errstate(all="ignore"):
        mod = load_module(c.source, name, code=code)
        x0 = np.asarray(mod.X0, dtype=float)
        dx = mod.rhs(0.0, x0)
        what, values = ("initial state", x0) if not np.isfinite(x0).all() else ("rhs", dx)
        if np.isfinite(values).all() and np.isreal(values).all():
            return
        err = mod._nonfinite("compile", what, 0.0, x0, values, (mod.N_STATES,), {})
        found = nonfinite_culprit(c, mod, err, None)
    owner = None  # the element that owns the first state that is not finite
    if isinstance(err.index, int) and err.index < len(mod.STATE_OWNERS):
        owner = next((el.coord for el in c.graph.elements
                      if el.id == mod.STATE_OWNERS[err.index]), None)
    fallback = owner or c.model.coord
    coord, why = (found[0] or fallback, found[1]) if found else (fallback, "")
    raise ModelError(coord, f"not finite with the default parameters: {err}{why}")


def nonfinite_culprit(c, mod, exc, p=None):
    """(coord, text) naming the element whose law made the NonFiniteError ``exc``, and a
    remedy where one is known; None if it cannot be told (the module's message stands)."""
    import sympy as sp

    eq = c.equations
    try:
        b = int(exc.instance or 0)
        t = float(exc.t)
        pv, _ = mod._params(p)

        def pick(v):
            a = np.asarray(v, dtype=float).ravel()
            return float(a[b] if a.size > b else a[0])

        names = [s for pvar in eq.params for s in pvar.symbols] + [d.symbol for d in eq.derived]
        vals = {s: pick(v) for s, v in zip(names, pv)}
        if eq.inputs:
            uv = mod._inputs(t, pv, None)
            for s, v in zip((s for iv in eq.inputs for s in iv.symbols), uv):
                vals[s] = pick(v)
        for sv, v in zip(eq.states, np.asarray(exc.x, dtype=float)):
            vals[sv.symbol] = float(v)
    except Exception:  # noqa: BLE001 - a diagnosis is best effort
        return None
    where = exc.where
    if where == "initial state":
        row = eq.states[exc.index].initial
        rows = [row]
    else:
        i = exc.index if where == "rhs" else exc.index[0]
        rows = [eq.derivatives[i]]
    j = exc.index[1] if where == "jacobian" else None

    def located(owner, text):
        try:
            coord = c.graph.element(owner).coord
        except Exception:  # noqa: BLE001 - a state's owner, or not an element
            coord = None
        return coord, text

    def param_coord(pid):
        return next((fp.coord for fp in c.graph.params if fp.id == pid), None)

    # parameters and inputs the failing row reads: one that is itself not finite is the cause
    by_sym = {a.symbol: a for a in eq.assignments}
    need, todo = set(), set().union(*(r.free_symbols for r in rows))
    while todo and len(need) < _DIAGNOSE_MAX:
        s = todo.pop()
        if s in need:
            continue
        need.add(s)
        if s in by_sym:
            todo |= by_sym[s].expr.free_symbols
    for pvar in eq.params:
        for s in pvar.symbols:
            if s in need and not np.isfinite(vals.get(s, 0.0)):
                return param_coord(pvar.id), f"; parameter {pvar.id!r} is {vals[s]:g}"
    for d in eq.derived:
        if d.symbol in need and not np.isfinite(vals.get(d.symbol, 0.0)):
            pid = d.why[len("derived parameter "):] if d.why.startswith("derived parameter ") \
                else None
            return param_coord(pid), (f"; the {d.why} is {vals[d.symbol]:g} (= "
                                      f"{_show(d.expr)} with the parameters' values)"
                                      + _remedy(d.expr, vals))
    for iv in eq.inputs:
        for s in iv.symbols:
            if s in need and not np.isfinite(vals.get(s, 0.0)):
                return None, f"; input {iv.name!r} is {vals[s]:g} at t = {t:g}"
    if where == "initial state" or len(need) > _DIAGNOSE_MAX:
        return None
    dep = {eq.states[j].symbol} if j is not None else set()
    for a in eq.assignments:
        if a.symbol not in need:
            continue
        v = _num(a.expr, vals)
        vals[a.symbol] = complex(np.nan) if v is None else v
        owner = _element_of(a.why)
        if not _finite(v):
            shown = ("nan" if v is None or np.isnan(v.real) else
                     f"{v.real:g}" if v.imag == 0 or np.isinf(v.real) else f"complex ({v:g})")
            return located(owner, f"; it comes from {a.why}: {_show(a.expr, 120)} is {shown} here"
                           + _remedy(a.expr, vals))
        vals[a.symbol] = v.real
        if j is None or not (a.expr.free_symbols & dep):
            continue
        dep.add(a.symbol)
        # lazy: the compile path, which a warm run never loads
        from bgc.core.eqtypes import clean_derivative

        for s in sorted(a.expr.free_symbols & dep, key=str):
            try:
                d = clean_derivative(sp.diff(a.expr, s))
            except Exception:  # noqa: BLE001
                continue
            if not _finite(_num(d, vals)):
                return located(owner, f"; it comes from {a.why}: {_show(a.expr, 120)} has an infinite "
                                      f"slope at {s} = {vals[s]:g}" + _remedy(a.expr, vals, s))
    return None


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
        with np.errstate(all="ignore"):  # timing only: no numpy warnings on the terminal
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
