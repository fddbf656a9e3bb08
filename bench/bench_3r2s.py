"""Speed of the 3R2S model: compile time, right-hand-side cost, scene wall times.

    python bench/bench_3r2s.py [--scenes circle figure8 gearshift]

Everything is measured in this one run (shared machines are noisy): compare the ratios.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def per_call(fn, n_min=20, t_min=0.5):
    n, t0 = 0, time.perf_counter()
    while n < n_min or time.perf_counter() - t0 < t_min:
        fn()
        n += 1
    return (time.perf_counter() - t0) / n


def main():
    from bgc.compiler import compile_file
    from bgc.runner import compile_scene
    from bgc.scene import param_values, parse_scene

    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", nargs="*", default=["circle", "figure8", "gearshift"])
    args = ap.parse_args()
    t0 = time.perf_counter()
    c = compile_file(ROOT / "models" / "3r2s.yaml")
    t_compile = time.perf_counter() - t0
    print(f"compile models/3r2s.yaml: {t_compile:.2f} s ({len(c.equations.states)} states, "
          f"{len(c.equations.jacobian)} Jacobian nonzeros)")
    from bgc.scene import load_module

    m = load_module(c.source, "mech3r2s_bench")
    x = m.X0 + 1e-6 * np.random.default_rng(0).standard_normal(m.X0.shape)
    r1 = per_call(lambda: m.rhs(0.1, x))
    j1 = per_call(lambda: m.jacobian(0.1, x))
    xb = np.repeat(x[:, None], 1000, axis=1)
    rb = per_call(lambda: m.rhs(0.1, xb), n_min=5)
    print(f"rhs, batch 1: {r1 * 1e6:.0f} us per call")
    print(f"rhs, batch 1000: {rb * 1e3:.2f} ms per call = {rb / 1000 * 1e6:.2f} us per instance "
          f"({r1 / (rb / 1000):.0f}x cheaper per instance than batch 1)")
    print(f"jacobian, batch 1: {j1 * 1e3:.2f} ms per call ({j1 / r1:.1f} rhs calls; a finite-"
          f"difference Jacobian costs {len(x)} rhs calls)")
    print()
    print("| scene | method | rtol | atol | wall [s] | rhs calls | Jacobians | LU |")
    print("|---|---|---|---|---|---|---|---|")
    for name in args.scenes:
        sc = parse_scene(ROOT / "models" / "scenes" / f"3r2s_{name}.yaml")
        _, mod = compile_scene(sc)
        t0 = time.perf_counter()
        res = mod.simulate(sc.t_span, dt=sc.dt, method=sc.method, rtol=sc.rtol, atol=sc.atol,
                           p=param_values(sc) or None, breakpoints=sc.breakpoints)
        wall = time.perf_counter() - t0
        s = res.stats
        print(f"| {name} | {sc.method} | {sc.rtol:g} | {sc.atol:g} | {wall:.2f} | {s['nfev']} | "
              f"{s['njev']} | {s['nlu']} |", flush=True)


if __name__ == "__main__":
    main()
