"""Small batches in the numpy runtime (issue 27): the vectorised rhs and Jacobian against the
loop over instances through the single-instance path, side by side in one run.

A generated numpy module evaluates a batch (x of shape (n, *batch)) as one numpy array per
expression. numpy's cost per operation on an array of a few entries is several times its cost
on one number, so below some batch size a loop of single-instance calls is cheaper. The
runtime's solver-facing wrappers loop below SMALL_BATCH (templates/numpy/runtime.py); this
script measures where the loop pays:

* per call: for each model and batch size, rhs and jacobian on the vectorised path
  (``mod.rhs(t, x, p)``) and on the loop (``mod._each(...)``, what the wrappers call), each
  instance with its own parameters (every scalar parameter scaled per instance), interleaved,
  best of several rounds;
* end to end: ``simulate`` of the 3R2S circle scene (its own solver settings, a short span)
  for batches of 2, 4 and 8 mass variants, with the loop off (SMALL_BATCH set to 0: the
  vectorised path, the runtime before the loop) and on (the default), on the same module.
  The two trajectories must be equal bit for bit (the same arithmetic per instance).

    python bench/bench_small_batch.py --span 0.1 --budget 0.3   # writes RESULTS_small_batch.md
    python bench/bench_small_batch.py --models msd --sizes 2,4 --span 0.1 --out /tmp/r.md

CPU-bound and noisy on a shared machine: the ratios within a row are the result, not the
times.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from bgc.backends import load as backends  # noqa: E402
from bgc.format.parse import parse_file  # noqa: E402
from bgc.format.scene import parse_scene  # noqa: E402
from bgc.run.driver import compile_model  # noqa: E402
from bgc.run.runner import scene_module  # noqa: E402

MODELS = ("msd", "rlc", "pendulum", "quarter_car", "dc_motor", "double_pendulum_rigid",
          "fourbar_rigid", "top", "3r2s")
SIZES = (1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 64)


def numpy_module(stem):
    c = compile_model(parse_file(ROOT / "models" / f"{stem}.yaml"))
    return backends.load(stem, "numpy", None, lambda: c, None)[1]


def per_call(fns, budget, rounds=9):
    """Seconds per call of each of fns: interleaved rounds of repeated calls (each round about
    budget / rounds s in all), the best round of each (the machine is shared: the least
    disturbed round is the cost)."""
    once = []
    for fn in fns:
        fn()
        t0 = time.perf_counter()
        fn()
        once.append(max(time.perf_counter() - t0, 1e-7))
    ks = [max(1, int(budget / rounds / len(fns) / o)) for o in once]
    best = [np.inf] * len(fns)
    for _ in range(rounds):
        for j, (fn, k) in enumerate(zip(fns, ks)):
            t0 = time.perf_counter()
            for _ in range(k):
                fn()
            best[j] = min(best[j], (time.perf_counter() - t0) / k)
    return best


def variants(mod, nb, rng):
    """Per-instance parameters (every scalar parameter scaled by 0.9-1.1) and states around
    the initial state."""
    p = {k: v * rng.uniform(0.9, 1.1, nb) for k, v in mod.PARAM_DEFAULTS.items()
         if np.ndim(v) == 0}
    x0 = np.asarray(mod.initial_state(p), dtype=float).reshape(mod.N_STATES, -1)
    x = np.broadcast_to(x0, (mod.N_STATES, nb)) * (1 + 1e-3 * rng.standard_normal(
        (mod.N_STATES, nb))) + 1e-4 * rng.standard_normal((mod.N_STATES, nb))
    return p, np.ascontiguousarray(x)


def per_call_rows(stem, sizes, budget):
    mod = numpy_module(stem)
    rng = np.random.default_rng(0)
    rows = []
    for nb in sizes:
        p, x = variants(mod, nb, rng)
        if nb == 1:  # one instance as simulate gives it: x of shape (n,), scalar parameters
            p, x = {k: float(v[0]) for k, v in p.items()}, x[:, 0].copy()
        pu, y, t = mod._params(p), x.ravel(), 0.3
        row = {"model": stem, "n": mod.N_STATES, "nb": nb,
               "size": {f: getattr(mod, f).__code__.co_nlocals for f in ("rhs", "jacobian")}}
        for name, fn in (("rhs", mod.rhs), ("jacobian", mod.jacobian)):
            if nb == 1:  # one instance: the vectorised call is the single-instance path
                vec, = per_call([lambda fn=fn: fn(t, x, pu, None)], budget)
                loop = vec
            else:
                vec, loop = per_call([lambda fn=fn: fn(t, x, pu, None),
                                      lambda name=name: mod._each(name, t, y, x.shape, pu,
                                                                  None)], budget)
                a = np.asarray(fn(t, x, pu, None)).reshape(mod._each(
                    name, t, y, x.shape, pu, None).shape)
                assert np.array_equal(a, mod._each(name, t, y, x.shape, pu, None)), (stem, nb)
            row[name] = (vec, loop)
        rows.append(row)
        print(f"{stem:22s} n={mod.N_STATES:3d} nb={nb:3d}  rhs vec {row['rhs'][0]*1e3:8.3f} "
              f"loop {row['rhs'][1]*1e3:8.3f} ms   jac vec {row['jacobian'][0]*1e3:8.3f} "
              f"loop {row['jacobian'][1]*1e3:8.3f} ms", flush=True)
    return mod, rows


def end_to_end(batches, span, repeats):
    scene = parse_scene(ROOT / "models" / "scenes" / "3r2s_circle.yaml")
    _, mod = scene_module(scene, backend="numpy")
    kw = dict(dt=scene.dt, method=scene.method, rtol=scene.rtol, atol=scene.atol,
              breakpoints=scene.breakpoints)
    default = dict(mod.SMALL_BATCH)
    rng = np.random.default_rng(3)
    rows = []
    for nb in batches:
        p = {k: mod.PARAM_DEFAULTS[k] * rng.uniform(0.8, 1.2, nb)
             for k in ("m1", "m2", "m3", "m4")}
        runs = [("vectorised", {"rhs": (0, 0), "jacobian": (0, 0)}, None),
                ("loop", default, None)]
        if not mod._use_sparse(nb):  # (a batch of 95 x 2 or more is sparse by default now)
            runs.append(("loop, sparse LU", default, True))
        out = {}
        for _ in range(repeats):  # interleaved; the best of the repeats
            for label, limits, sparse in runs:
                mod.SMALL_BATCH.update(limits)
                t0 = time.perf_counter()
                r = mod.simulate((0.0, span), p=p, sparse=sparse, **kw)
                wall = time.perf_counter() - t0
                out[label] = (min(wall, out.get(label, (np.inf,))[0]), r)
        mod.SMALL_BATCH.update(default)
        same = np.array_equal(out["vectorised"][1].x, out["loop"][1].x)
        sparse_wall = out["loop, sparse LU"][0] if "loop, sparse LU" in out else None
        rows.append((nb, out["vectorised"][0], out["loop"][0], same,
                     out["loop"][1].stats["nfev"], out["loop"][1].stats["njev"],
                     sparse_wall, mod._use_sparse(nb)))
        print(f"3r2s circle 0-{span} s, batch {nb}: vectorised {out['vectorised'][0]:.2f} s, "
              f"loop {out['loop'][0]:.2f} s, bit-identical {same}; loop with the sparse LU "
              f"{sparse_wall}", flush=True)
    # single runs for scale
    single = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        mod.simulate((0.0, span), **kw)
        single = min(single, time.perf_counter() - t0)
    return rows, single, default


def write(out, table, e2e, single, limits, span, repeats, cmd, load_before, load_after):
    lines = ["# Small batches in the numpy runtime: vectorised against the per-instance loop",
             "", f"Command: `{cmd}` (written by it).", "",
             f"Machine: `uptime` before: {load_before}; after: {load_after} (2 cores, shared).",
             "", f"SMALL_BATCH in the runtime when measured: {limits}.", "",
             "## Per call (ms), each instance with its own parameters", "",
             "loop/vec below 1: the loop is cheaper. One instance (nb = 1) is the same call.", "",
             "| model | n | nb | rhs vec | rhs loop | loop/vec | jac vec | jac loop | loop/vec |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in table:
        (rv, rl), (jv, jl) = r["rhs"], r["jacobian"]
        lines.append(f"| {r['model']} | {r['n']} | {r['nb']} | {rv*1e3:.4f} | {rl*1e3:.4f} | "
                     f"{rl/rv:.2f} | {jv*1e3:.4f} | {jl*1e3:.4f} | {jl/jv:.2f} |")
    lines += ["", f"## End to end: the 3R2S circle scene, 0-{span} s, its solver settings, "
              "batches of mass variants", "",
              f"One instance alone: {single:.2f} s. Best of {repeats} interleaved runs each. "
              "Vectorised: SMALL_BATCH set to 0 (the runtime before the loop); loop: the "
              "default limits; both with the default choice of LU (the column 'default LU sparse': "
              "SPARSE_MIN_SIZE, SPARSE_MAX_DENSITY). The last column: the loop with "
              "simulate(..., sparse=True), where the default is dense.", "",
              "| batch | vectorised (s) | loop (s) | loop/vec | x bit-identical | nfev | njev "
              "| default LU sparse | loop, sparse=True (s) |",
              "|---|---|---|---|---|---|---|---|---|"]
    for nb, tv, tl, same, nfev, njev, ts, sp in e2e:
        lines.append(f"| {nb} | {tv:.2f} | {tl:.2f} | {tl/tv:.2f} | {same} | {nfev} | {njev} "
                     f"| {sp} | {'-' if ts is None else f'{ts:.2f}'} |")
    Path(out).write_text("\n".join(lines) + "\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--models", default=",".join(MODELS))
    ap.add_argument("--sizes", default=",".join(map(str, SIZES)))
    ap.add_argument("--batches", default="2,4,8")
    ap.add_argument("--span", type=float, default=0.3, help="end-to-end span (s)")
    ap.add_argument("--repeats", type=int, default=3, help="end-to-end runs of each")
    ap.add_argument("--budget", type=float, default=0.15, help="seconds per measurement")
    ap.add_argument("--out", default=str(ROOT / "bench" / "RESULTS_small_batch.md"))
    a = ap.parse_args()
    load_before = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    sizes = [int(s) for s in a.sizes.split(",")]
    table, limits = [], None
    for stem in filter(None, a.models.split(",")):
        mod, rows = per_call_rows(stem, sizes, a.budget)
        table += rows
        limits = dict(mod.SMALL_BATCH)
    batches = [int(b) for b in a.batches.split(",") if b]
    e2e, single, limits = (end_to_end(batches, a.span, a.repeats) if batches
                           else ([], float("nan"), limits))
    load_after = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    cmd = "python bench/bench_small_batch.py" + "".join(
        f" {arg}" for arg in sys.argv[1:])
    write(a.out, table, e2e, single, limits, a.span, a.repeats, cmd, load_before, load_after)
    print(f"wrote {os.path.relpath(a.out)}")


if __name__ == "__main__":
    main()
