"""Parameter sweeps of a scene: the scene's ``sweep:`` section, its samples, and the engine
that runs them as batched simulations on Dask and writes the results to Zarr.

The ``sweep:`` section (documented in docs/model-format.md, "Sweeps")::
    sweep:
      parameters:                      # model parameters (ids as in PARAM_DEFAULTS)
        m: {linspace: [0.5, 2.0, 4]}   # n evenly spaced values from a to b
        k: {logspace: [10, 1000, 3]}   # n values from a to b, evenly spaced in log (a, b > 0)
        c: {values: [0.1, 0.2]}        # a list
        F0: {uniform: [5, 15]}         # random: uniform, normal [mu, sigma], loguniform [a, b]
      initial:                         # initial states by name (STATE_NAMES), same forms
        spring.q: {values: [0, 0.01]}
      combine: cross                   # cross (every combination, default) or zip
      samples: 32                      # how many random samples (with random entries only)
      method: lhs                      # lhs (Latin hypercube, default) or random
      seed: 1
      plot: {outputs: [position], stat: final, units: {position: m}}

Every grid or list is one axis; the random entries together are one more axis of ``samples``
rows (sampled jointly: a Latin hypercube over all of them). ``cross`` takes every combination
of the axes (the first listed varies slowest), ``zip`` pairs them row by row (equal lengths).

The engine (:func:`run_sweep`) cuts the samples into chunks; each chunk is one Dask task that
loads the module from its text (no module is pickled), integrates the chunk's instances in one
``simulate`` call, and returns its arrays; the client writes each chunk into
a pre-created Zarr store (a region write) and then marks it done. Rerunning with the same
store computes only the chunks not marked done; the store's attributes hold a hash of
everything the results depend on, and a store made for another sweep is refused.

Backends (:func:`choose_backend`): the C backend when a C compiler is available and the C
printer accepts the model, else numpy; ``bgc sweep --backend`` or the scene's ``solver:
{backend: ...}`` choose. For C the tasks receive the C sources and the wrapper's text; each
worker process gets the library from the compile cache (on the client's machine it was built
there by :func:`prepare`; elsewhere the worker builds it once from the texts) and loads it
once. A C batch integrates every instance with its own step size (a sample equals the same run
alone); a numpy batch shares its steps (one error norm over the batch).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import sys
import time
import uuid
import warnings
from dataclasses import dataclass, field

import numpy as np

from bgc.backends import load as backends
from bgc.backends.c import build as cbuild
from bgc.backends.c.build import CUnsupported
from bgc.backends.load import c_key, load_c, load_module
from bgc.base.errors import ModelError
from bgc.base.limits import LIMITS
from bgc.base.reach import run_inputs
from bgc.base.safeio import read_text_bounded
from bgc.core.graph import build_graph
from bgc.format.expr import Expr
from bgc.format.reader import Reader
from bgc.format.scene import check_bounds, initial_values, parse_scene, scene_model
from bgc.run.runner import compile_scene, runtime_params
from bgc.studies.sweep_plot import plot_sweep  # noqa: F401 (bgc.studies.sweep.plot_sweep)
from bgc.studies.sweep_spec import (  # noqa: F401 (the section's names, as sweep.*)
    MAX_SAMPLES,
    Entry,
    SweepSpec,
    parse_sweep,
    samples,
)
from bgc.studies.sweep_store import (  # noqa: F401 (the store's names, as sweep.*)
    MESSAGE_WIDTH,
    STATS,
    SweepMismatch,
    chunk_bounds,
    consolidate,
    open_or_create,
    open_results,
    write_chunk,
)

# ---------------------------------------------------------------------------------------------
# preparing: the scene's module with every swept parameter kept as a parameter


@dataclass
class Prepared:
    """What every task needs, all plain data: the module's text (for C, the C sources and the
    wrapper's text, from which a worker builds the library) and the call."""

    scene_name: str
    backend: str  # "numpy" (source) or "c" (c_files and c_wrapper; source kept for reference)
    source: str
    modname: str
    t_span: tuple
    dt: float
    method: str
    rtol: float
    atol: float
    max_step: float
    breakpoints: tuple
    base_p: dict  # the scene's run-time parameter values
    params: dict  # label -> (param id) for swept parameters
    states: dict  # label -> state index for swept initial states
    values: dict  # label -> (S,) swept values
    outputs: tuple  # output names kept
    output_shapes: dict
    param_units: dict
    spec: SweepSpec = None
    max_wall: float | None = None
    c_files: dict = field(default_factory=dict)  # C file name -> text
    c_wrapper: str = ""  # the C wrapper module's text
    c_key: str = ""  # their compile-cache key on the client's machine (backends.c_key)
    inputs: object = None  # the run's inputs (bgc.base.outfiles.Inputs): no output replaces one
    fixed: dict = field(default_factory=dict)  # state index -> the scene's initial: value
    equilibrium: bool = False  # the scene's initial: equilibrium (each sample its own)

    @property
    def n(self) -> int:
        return len(next(iter(self.values.values())))

    def digest(self, chunk: int) -> str:
        """A hash of everything the results depend on (backend, module and C texts, call,
        samples, chunking)."""
        h = hashlib.sha256()
        h.update(self.backend.encode() + b"\0")
        h.update(self.source.encode())
        if self.backend == "c":
            for name in sorted(self.c_files):
                h.update(b"\0" + name.encode() + b"\0" + self.c_files[name].encode())
            h.update(b"\0" + self.c_wrapper.encode())
            # the client's cache key: the C runtime's sources, the compiler and its flags
            h.update(b"\0" + str(self.c_key).encode())
        h.update(json.dumps([self.t_span, self.dt, self.method, self.rtol, self.atol,
                             repr(self.max_step), self.breakpoints, _jsonable(self.base_p),
                             sorted(self.params.items()), sorted(self.states.items()),
                             list(self.outputs), chunk, self.max_wall], default=str).encode())
        if self.fixed or self.equilibrium:  # the scene's start (a store made without differs)
            h.update(json.dumps([sorted(self.fixed.items()), self.equilibrium]).encode())
        for k in sorted(self.values):
            h.update(k.encode())
            h.update(np.ascontiguousarray(self.values[k], dtype="<f8").tobytes())
        return h.hexdigest()[:24]


def _jsonable(d):
    return {k: np.asarray(v).tolist() for k, v in (d or {}).items()}


def solver_backend(path) -> str | None:
    """The backend the scene's ``solver:`` names, None when it names none (the scene parser
    has already checked the value)."""
    path = str(path)
    r = Reader(path, read_text_bounded(path, None, "scene file", LIMITS.scene_bytes))
    top = r.mapping(r.compose(), "the scene")
    if "solver" not in top:
        return None
    sm = r.mapping(top["solver"][1], "solver")
    return r.string(sm["backend"][1], "backend") if "backend" in sm else None


def choose_backend(compiled, backend=None, progress=None):
    """(backend, C files, wrapper text, cache key) for a compiled sweep module: "c" when asked
    for or by default, if a C compiler is there and the C printer accepts the model (else
    the reason is said and numpy it is); "numpy" when asked for."""
    say = progress or (lambda msg: None)
    if backend == "numpy":
        return "numpy", {}, "", ""
    if not cbuild.available():
        say(f"no C compiler ({cbuild.cc_text()!r} cannot run; set CC): using the "
            "numpy backend")
        return "numpy", {}, "", ""
    if not cbuild.runtime_sources():
        say("the C runtime (templates/c/runtime/*.c) is not installed: using the numpy backend")
        return "numpy", {}, "", ""
    try:
        files, wrapper = backends.c_files(compiled)
    except CUnsupported as exc:
        say(f"{exc.message}: using the numpy backend")
        return "numpy", {}, "", ""
    return "c", files, wrapper, backends.c_key(files, wrapper)


def prepare(scene_path, progress=None, backend: str | None = None) -> Prepared:
    """Parse the scene and its sweep, compile the module (swept parameters kept free).

    backend: "c", "numpy", or None for the scene's ``solver: {backend: ...}`` if it names
    one, else C where it can run (see :func:`choose_backend`). For C the library is built here
    into the compile cache, so that workers on this machine only load it."""
    scene = parse_scene(scene_path)
    spec = parse_sweep(scene_path)
    if spec is None:
        raise ModelError(scene.coord, "the scene has no sweep: section (see docs/model-format.md,"
                                      " Sweeps)")
    known = {p.id: p for p in build_graph(scene_model(scene)).params}
    swept = []
    for e in spec.entries:
        if e.kind != "param":
            continue
        if e.name not in known:
            raise ModelError(e.coord, f"sweep: the model has no parameter {e.name!r}")
        pv = known[e.name].value
        if isinstance(pv, Expr):
            raise ModelError(e.coord, f"sweep: parameter {e.name!r} is derived from others; "
                                      "sweep the ones it is made of")
        if isinstance(pv, tuple):
            raise ModelError(e.coord, f"sweep: parameter {e.name!r} is a matrix; only scalar "
                                      "parameters can be swept")
        swept.append(e.name)
    values = samples(spec)
    for e in spec.entries:  # within the model's min and max, as a scene's value must be
        if e.kind == "param":
            for v in (float(np.min(values[e.label])), float(np.max(values[e.label]))):
                check_bounds(e.name, v, known[e.name], e.coord, "the sweep gives")
    extra = tuple(n for n in swept if n in scene.params and n not in scene.free)
    scene2 = dataclasses.replace(scene, free=scene.free + extra)
    c, mod = compile_scene(scene2, progress)
    states = {}
    for e in spec.entries:
        if e.kind == "param" and e.name not in mod.PARAM_DEFAULTS:
            raise ModelError(e.coord, f"sweep: parameter {e.name!r} is not in the scene's "
                                      "module (an effect the scene turns off removed it)")
        if e.kind == "state":
            if e.name not in mod.STATE_NAMES:
                raise ModelError(e.coord, f"sweep: the scene's module has no state {e.name!r} "
                                          f"(states: {', '.join(mod.STATE_NAMES)})")
            states[e.label] = mod.STATE_NAMES.index(e.name)
    outs = scene.outputs or tuple(mod.OUTPUT_NAMES)
    for o in spec.plot_outputs:
        if o not in outs:
            raise ModelError(spec.plot_coord, f"sweep plot: no output {o!r} (outputs: "
                                              f"{', '.join(outs)})")
    for o in spec.plot_units:
        if o not in outs:
            raise ModelError(spec.plot_coord, f"sweep plot units: no output {o!r}")
    dt = scene.dt or (scene.t_span[1] - scene.t_span[0]) / 1000
    if backend is None:
        backend = solver_backend(scene_path)
    backend, files, wrapper, ckey = choose_backend(c, backend, progress)
    prep = Prepared(scene.name, backend, c.source, f"{c.model.name}_{scene.name}_sweep",
                    tuple(scene.t_span), dt,
                    "Radau" if scene.method == "auto" else scene.method, scene.rtol, scene.atol,
                    scene.max_step, tuple(scene.breakpoints),
                    runtime_params(scene2, mod) or {},
                    {e.label: e.name for e in spec.entries if e.kind == "param"}, states,
                    values, outs, {o: tuple(mod.OUTPUT_SHAPES[o]) for o in outs},
                    dict(mod.PARAM_UNITS), spec, c_files=files, c_wrapper=wrapper, c_key=ckey)
    if backend == "c":
        load(prep, progress)  # built once here: the workers on this machine find it cached

    prep.inputs = run_inputs(scene.model_path, scene_path)
    # each sample starts where the scene alone does: its initial: states, or the equilibrium
    prep.equilibrium = scene.initial == "equilibrium"
    prep.fixed = initial_values(scene, mod) if isinstance(scene.initial, dict) else {}
    return prep


# ---------------------------------------------------------------------------------------------
# one task: a chunk of instances


_MODULES: dict = {}


def _module_key(prep: Prepared) -> str:
    h = hashlib.sha256(prep.backend.encode() + b"\0")
    if prep.backend == "c":
        for name in sorted(prep.c_files):
            h.update(name.encode() + b"\0" + prep.c_files[name].encode() + b"\0")
        h.update(prep.c_wrapper.encode())
    else:
        h.update(prep.source.encode())
    return h.hexdigest()


def load(prep: Prepared, progress=None):
    """The module in this process, loaded once (memoised by a hash of its texts): numpy from
    its source text; C through the compile cache (backends.load_c: the entry the client built,
    or built here from the shipped sources when this machine has none)."""
    key = _module_key(prep)
    mod = _MODULES.get(key)
    if mod is None:
        name = f"{prep.modname}_{key[:8]}"
        if prep.backend == "numpy":
            mod = load_module(prep.source, name)
        elif prep.backend == "c":
            # the key of this machine's compiler (on the client's machine: prep.c_key)
            with np.errstate(all="ignore"):
                mod = load_c(prep.c_files, prep.c_wrapper, name,
                             c_key(prep.c_files, prep.c_wrapper), progress)
            mod._NUMPY_MODULE = lambda: load_module(prep.source, f"{name}_numpy")
        else:
            raise ModelError(None, f"sweep: unknown backend {prep.backend!r}")
        _MODULES[key] = mod
    return mod


def task_threads(slots: dict | None) -> int | None:
    """Threads for one C simulate call in this task: this machine's CPUs shared evenly among
    the task slots (workers x threads per worker) the cluster has on this host, at least one
    (so with as many workers as cores, or more, every task runs one thread and the workers
    never oversubscribe the cores). slots: host -> task slots, from the client when the sweep
    started; a host it does not know (a worker that joined later) gets 1 thread. None outside a
    Dask worker (the C default: every CPU)."""
    import os

    try:
        from distributed import get_worker
        from distributed.comm import get_address_host

        host = get_address_host(get_worker().address)
    except (ImportError, ValueError):
        return None
    try:
        cpus = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cpus = os.cpu_count() or 1
    n = (slots or {}).get(host)
    return max(1, cpus // n) if n else 1


def host_slots(client) -> dict:
    """host -> task slots (sum of the threads of the workers there) of the client's cluster."""
    out: dict = {}
    for w in client.scheduler_info().get("workers", {}).values():
        out[w.get("host")] = out.get(w.get("host"), 0) + int(w.get("nthreads") or 1)
    return out


def _start(mod, prep: Prepared, p: dict):
    """The batch's start before the swept states: the module's initial state, or with the
    scene's ``initial: equilibrium`` each instance's equilibrium (inputs held at t0)."""
    if not prep.equilibrium:
        return mod.initial_state(p or None)
    x, info = mod.equilibrium(p=p or None, t=prep.t_span[0])
    if not np.all(info.converged) or not np.all(np.isfinite(x)):
        raise ValueError(f"initial: no equilibrium found (max |dx/dt| = "
                         f"{np.nanmax(info.residual):.3g})")
    return np.asarray(x, dtype=float)


def _call(mod, prep: Prepared, idx: np.ndarray, nthreads: int | None = None):
    """One vectorised simulate over the instances idx; (y dict with the batch first, stats).
    nthreads: the C integrator's threads (None: every CPU); unused by numpy."""
    p = dict(prep.base_p)
    for label, pid in prep.params.items():
        p[pid] = prep.values[label][idx]
    x0 = None
    if prep.states or prep.fixed or prep.equilibrium:  # the scene's start, then the swept
        x0 = np.array(np.broadcast_to(_start(mod, prep, p).reshape(
            mod.N_STATES, -1), (mod.N_STATES, len(idx))))
        for k, v in prep.fixed.items():
            x0[k] = v
        for label, k in prep.states.items():
            x0[k] = prep.values[label][idx]
    if not prep.params:  # a batch axis from x0 only
        p = p or None
    t, _, y = res = mod.simulate(prep.t_span, dt=prep.dt, method=prep.method, rtol=prep.rtol,
                                 atol=prep.atol, p=p, x0=x0, breakpoints=prep.breakpoints,
                                 max_step=prep.max_step, max_wall=prep.max_wall,
                                 **({"nthreads": nthreads} if prep.backend == "c" else {}))
    out = {}
    for o in prep.outputs:
        a = np.asarray(y[o], dtype=float)
        k = len(prep.output_shapes[o])
        a = np.broadcast_to(a, prep.output_shapes[o] + (len(idx), len(t))) if a.ndim < k + 2 \
            else a
        out[o] = np.moveaxis(a, k, 0)
    bad = [o for o in out if not np.all(np.isfinite(out[o]))]
    if bad:
        raise FloatingPointError(f"non-finite values in output {bad[0]!r}")
    return t, out, res.stats


def run_chunk(prep: Prepared, a: int, b: int, slots: dict | None = None) -> dict:
    """Instances a..b-1 as one batch; when the batch fails, each instance alone, so that one
    diverging instance is recorded (NaNs and its message) while the others finish. slots:
    host -> task slots of the cluster (see :func:`task_threads`)."""
    t0 = time.perf_counter()
    mod = load(prep)
    nth = task_threads(slots) if prep.backend == "c" else None
    idx = np.arange(a, b)
    nt = int(round(abs(prep.t_span[1] - prep.t_span[0]) / prep.dt)) + 1
    ys = {o: np.full((b - a,) + prep.output_shapes[o] + (nt,), np.nan) for o in prep.outputs}
    stats = {k: np.zeros(b - a, dtype=np.int64) for k in STATS}
    status = np.zeros(b - a, dtype=np.int8)
    message = np.full(b - a, "", dtype=f"<U{MESSAGE_WIDTH}")
    batch = np.full(b - a, b - a, dtype=np.int32)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        try:
            _, out, st = _call(mod, prep, idx, nth)
            for o in out:
                ys[o][...] = out[o]
            for k in STATS:
                stats[k][:] = st.get(k, 0)
        except Exception:  # noqa: BLE001 - isolate: every instance alone
            batch[:] = 1
            for j, i in enumerate(idx):
                try:
                    _, out, st = _call(mod, prep, np.array([i]), nth)
                    for o in out:
                        ys[o][j] = out[o][0]
                    for k in STATS:
                        stats[k][j] = st.get(k, 0)
                except Exception as exc:  # noqa: BLE001 - recorded, not raised
                    status[j] = 1
                    msg = " ".join(f"{type(exc).__name__}: {exc}".split())
                    message[j] = msg[:MESSAGE_WIDTH]
                    st = getattr(exc, "stats", None) or {}
                    for k in STATS:
                        stats[k][j] = st.get(k, 0)
    return {"a": a, "b": b, "y": ys, "stats": stats, "status": status, "message": message,
            "batch": batch, "wall": time.perf_counter() - t0}


# ---------------------------------------------------------------------------------------------
# the engine


@dataclass
class SweepReport:
    out: str
    n: int
    chunks: int
    computed: int  # chunks computed by this run
    skipped: int  # chunks already done
    failed: int  # failed instances in the chunks computed now
    wall: float


def client_for(scheduler=None, workers=None):
    """A dask.distributed Client: on a new LocalCluster (processes, `workers` workers, one
    thread each) for None or 'local', else on the running scheduler at that address. The
    caller closes it (and its cluster: client.bgc_cluster)."""
    import dask
    from distributed import Client, LocalCluster

    if scheduler in (None, "", "local"):
        # workers may fork children (bgc accuracy isolates each run in one); no statistical
        # profiler sampling the workers 100 times a second (it competes for the cores)
        with dask.config.set({"distributed.worker.daemon": False,
                              "distributed.worker.profile.enabled": False}):
            cluster = LocalCluster(n_workers=workers or 2, threads_per_worker=1,
                                   processes=True, dashboard_address=None)
        client = Client(cluster)
        client.bgc_cluster = cluster
        from bgc.studies.quiet_close import QuietWorkerClose  # imports distributed
        client.register_plugin(QuietWorkerClose(), name="bgc-quiet-close")
        return client
    try:
        client = Client(scheduler)
    except (ValueError, TypeError) as exc:  # not an address (no port, unknown protocol)
        raise ModelError(None, f"--scheduler {str(scheduler)[:80]!r} is not a Dask "
                               f"scheduler's address ({str(exc)[:120]}): give "
                               "tcp://HOST:PORT, or 'local'") from None
    client.bgc_cluster = None
    return client


def close_client(client):
    cluster = getattr(client, "bgc_cluster", None)
    client.close()
    if cluster is not None:
        cluster.close()


class _Counter:
    """Progress on stderr: chunks and instances done, failures so far."""

    def __init__(self, total_chunks, n, quiet=False):
        self.total, self.n, self.quiet = total_chunks, n, quiet
        self.t0 = time.perf_counter()

    def __call__(self, done, inst, failed):
        if self.quiet:
            return
        el = time.perf_counter() - self.t0
        rate = inst / el if el > 0 else 0.0
        tty = sys.stderr.isatty()  # a terminal: one line rewritten; a log: a line per chunk
        cr = "\r" if tty else ""
        print(f"{cr}sweep: {done}/{self.total} chunks, {inst}/{self.n} "
              f"instances, {failed} failed, {el:.1f} s ({rate:.1f} instances/s)",
              end="" if tty else "\n", file=sys.stderr, flush=True)

    def end(self):
        if not self.quiet and sys.stderr.isatty():
            print(file=sys.stderr, flush=True)


def run_sweep(prep: Prepared, out, client, chunk: int = 16, restart: bool = False,
              quiet: bool = False, after_chunk=None) -> SweepReport:
    """Run the sweep's missing chunks on the client's cluster, writing each to the store as it
    arrives. after_chunk(k): called after chunk k is written (tests use it to stop a run)."""
    from distributed import as_completed

    if chunk < 1:
        raise ModelError(None, "--chunk must be at least 1")
    t0 = time.perf_counter()
    spans = chunk_bounds(prep.n, chunk)
    done = open_or_create(prep, out, chunk, restart)
    todo = [k for k, d in enumerate(done) if not d]
    counter = _Counter(len(spans), prep.n, quiet)
    ndone = sum(done)
    inst = sum(b - a for (a, b), d in zip(spans, done) if d)
    counter(ndone, inst, 0)
    failed = computed = 0
    if todo:
        fprep = client.scatter(prep, broadcast=True, hash=False)
        run = uuid.uuid4().hex[:8]  # fresh keys: never those of an earlier, cancelled run
        slots = host_slots(client) if prep.backend == "c" else None
        futures = {client.submit(run_chunk, fprep, *spans[k], slots,
                                 key=f"bgc-sweep-{k}-{run}", pure=False): k for k in todo}
        try:
            for fut in as_completed(futures):
                k = futures[fut]
                res = fut.result()
                write_chunk(out, res, k, prep)
                computed += 1
                ndone += 1
                inst += res["b"] - res["a"]
                failed += int(np.sum(res["status"] != 0))
                counter(ndone, inst, failed)
                if after_chunk is not None:
                    after_chunk(k)
        finally:
            for fut in futures:
                fut.cancel()
            counter.end()
    else:
        counter.end()
    consolidate(out)
    return SweepReport(str(out), prep.n, len(spans), computed, len(spans) - len(todo), failed,
                       time.perf_counter() - t0)
