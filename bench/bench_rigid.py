"""Rigid joints (derivative causality eliminated) against compliant joints (stiff C || R).

For the double pendulum and the three-rod chain (bench/planar_chain.py), every model is
compiled by bgc and integrated over 0..T by its generated module; the error is the largest
joint-angle difference from a reference, the rigid model at rtol 1e-12 (DOP853). The
compliant model's error is its modelling error (~1/k) plus the integration error; the rigid
model has only the latter. Times are wall-clock seconds of `simulate` in this one run (best
of 3), side by side.

`--backends` instead times the numpy and the C backend side by side on the scene
models/scenes/double_pendulum_swing.yaml (10 s, rtol 1e-8): as written (derivative
causality's 2x2 system solved symbolically) and compiled with symbolic_max=0 (the mass-matrix
form: a numeric linear solve in every rhs and Jacobian call, an LU per instance in C).

    .venv/bin/python bench/bench_rigid.py [--T 5] [--backends]
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

# one BLAS thread, as the tests do: the small dense LUs of the implicit methods only contend
# with other processes on a shared machine
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT / "bench"))

from planar_chain import NAMES, chain_yaml  # noqa: E402

from bgc.backends.load import load_module  # noqa: E402
from bgc.format.parse import parse_text  # noqa: E402
from bgc.run.driver import compile_model  # noqa: E402


def build(text, name):
    c = compile_model(parse_text(text, f"{name}.yaml"))
    return load_module(c.source, name)


def angles(m, x, n):
    return np.array([x[m.STATE_NAMES.index(f"rod{i + 1}.th")] for i in range(n)])


def run(m, n, T, t_eval, reps=3, **kw):
    best = np.inf
    for _ in range(reps):
        t0 = time.perf_counter()
        _, x, _ = m.simulate((0, T), t_eval=t_eval, **kw)
        best = min(best, time.perf_counter() - t0)
    return angles(m, x, n), best, x


def best_of(f, reps=3):
    best = np.inf
    for _ in range(reps):
        t0 = time.perf_counter()
        out = f()
        best = min(best, time.perf_counter() - t0)
    return best, out


def backends_table(reps=3):
    """numpy vs C backend on the double pendulum swing scene, side by side in this run."""
    from bgc.backends import load as backends
    from bgc.format.scene import initial_state, parse_scene
    from bgc.run.driver import compile_file
    from bgc.run.runner import runtime_params, scene_module

    scene = parse_scene(ROOT / "models" / "scenes" / "double_pendulum_swing.yaml")
    mods = {b: scene_module(scene, None, b, use_cache=False)[1] for b in ("numpy", "c")}
    c0 = compile_file(ROOT / "models" / "double_pendulum_rigid.yaml", symbolic_max=0)
    num = {"numpy": load_module(c0.source, "dp_lu_np"),
           "c": backends.load("dp_lu_c", "c", None, lambda: c0, None)[1]}
    print(f"double_pendulum_swing, {scene.t_span[1] - scene.t_span[0]:g} s, dt {scene.dt}, "
          f"rtol {scene.rtol:g}, atol {scene.atol:g}; best of {reps}")
    print("| model | method | numpy [s] | C [s] | numpy / C "
          "| max abs(x_C - x_numpy) |")
    print("|---|---|---|---|---|---|")
    for label, ms in (("scene (symbolic 2x2 solve)", mods),
                      ("symbolic_max=0 (numeric LU solve)", num)):
        for method in (scene.method, "Radau", "Rodas4"):
            t, xs = {}, {}
            for b, m in ms.items():
                p = runtime_params(scene, m) if ms is mods else {"c1": 0.02, "c2": 0.02}
                x0 = initial_state(scene, m, p) if ms is mods else None
                t[b], r = best_of(lambda: m.simulate(scene.t_span, dt=scene.dt, method=method,
                                                     rtol=scene.rtol, atol=scene.atol, p=p,
                                                     x0=x0), reps)
                xs[b] = r.x
            d = float(np.max(np.abs(xs["c"] - xs["numpy"])))
            print(f"| {label} | {method} | {t['numpy']:.3f} | {t['c']:.4f} | "
                  f"{t['numpy'] / t['c']:.1f} | {d:.1e} |")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--T", type=float, default=5.0)
    ap.add_argument("--backends", action="store_true",
                    help="numpy vs C backend on the double pendulum swing scene")
    args = ap.parse_args()
    if args.backends:
        backends_table()
        return
    T = args.T
    t_eval = np.linspace(0, T, 101)
    print(f"| model | joints | k [N/m] | method | rtol | states | time [s] | max angle error [rad] |")
    print("|---|---|---|---|---|---|---|---|")
    for n in (2, 3):
        rigid = build(chain_yaml(n), f"r{n}")
        ref, _, _ = run(rigid, n, T, t_eval, reps=1, method="DOP853", rtol=1e-12, atol=1e-12)
        ns = len(rigid.STATE_NAMES)
        for method, rtol in (("DOP853", 1e-6), ("DOP853", 1e-8), ("Radau", 1e-6),
                             ("Radau", 1e-8)):
            th, dt, _ = run(rigid, n, T, t_eval, method=method, rtol=rtol, atol=rtol * 1e-2)
            print(f"| {NAMES[n]} | rigid | - | {method} | {rtol:g} | {ns} | {dt:.3f} | "
                  f"{np.abs(th - ref).max():.2e} |")
        for k in (1e4, 1e6, 1e8):
            comp = build(chain_yaml(n, compliant=True, k=k, r=0.2 * np.sqrt(k)), f"c{n}_{int(k)}")
            nc = len(comp.STATE_NAMES)
            for rtol in (1e-6, 1e-8):
                try:
                    th, dt, _ = run(comp, n, T, t_eval, method="Radau", rtol=rtol,
                                    atol=rtol * 1e-2, max_wall=120)
                    err = f"{np.abs(th - ref).max():.2e}"
                except Exception as exc:  # a run past the wall limit: say so
                    dt, err = float("nan"), f"failed: {type(exc).__name__}"
                print(f"| {NAMES[n]} | compliant | {k:.0e} | Radau | {rtol:g} | {nc} | "
                      f"{dt:.3f} | {err} |")


if __name__ == "__main__":
    main()
