"""Rigid joints (derivative causality eliminated) against compliant joints (stiff C || R).

For the double pendulum and the three-rod chain (bench/planar_chain.py), every model is
compiled by bgc and integrated over 0..T by its generated module; the error is the largest
joint-angle difference from a reference, the rigid model at rtol 1e-12 (DOP853). The
compliant model's error is its modelling error (~1/k) plus the integration error; the rigid
model has only the latter. Times are wall-clock seconds of `simulate` in this one run (best
of 3), side by side.

    .venv/bin/python bench/bench_rigid.py [--T 5]
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

from bgc.compiler import compile_model  # noqa: E402
from bgc.parse import parse_text  # noqa: E402
from bgc.scene import load_module  # noqa: E402
from planar_chain import NAMES, chain_yaml  # noqa: E402


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


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--T", type=float, default=5.0)
    args = ap.parse_args()
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
