"""Where sparse linear algebra pays in the numpy runtime's implicit methods (issue 27).

The numpy module's ``simulate(..., sparse=True)`` hands scipy's Radau and BDF a
``scipy.sparse.csc_matrix`` Jacobian (they factorise with splu) and makes bgc's Rodas4
factorise with splu; ``sparse=False`` gives all three a dense array (LAPACK's LU). This
script runs both on the same compiled module, side by side, and reports the ratio
dense / sparse per size: the threshold ``SPARSE_MIN_SIZE`` in templates/numpy/runtime.py is
where the ratio crosses 1.

Problems: the RC ladder of bench/bench_scale.py (states = size; a tridiagonal Jacobian), 10 s,
rtol 1e-6, atol 1e-9; and a batch of mass-spring-dampers (models/msd.yaml, 2 states each,
the stiffness spread over the batch: a block-diagonal Jacobian), 20 s.

    python bench/bench_sparse.py                       # ladders 10,30,60,100,200,300
    python bench/bench_sparse.py --ladder 10,100 --batch 5,50,500 --methods Radau

Writes bench/RESULTS_sparse.md. CPU-bound and noisy on a shared machine: the ratios within a
row are the result, not the times.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT / "bench"))

from bench_scale import ladder_yaml  # noqa: E402

from bgc.backends import load as backends  # noqa: E402
from bgc.format.parse import parse_file, parse_text  # noqa: E402
from bgc.run.driver import compile_model  # noqa: E402


def best(fn, rounds):
    out, ts = None, []
    for _ in range(rounds):
        t0 = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t0)
    return min(ts), out


def numpy_module(name, text=None, path=None):
    if path is None:
        with tempfile.TemporaryDirectory() as d:
            f = Path(d) / f"{name}.yaml"
            f.write_text(text)
            c = compile_model(parse_text(text, str(f)))
    else:
        c = compile_model(parse_file(path))
    return backends.load(name, "numpy", None, lambda: c, None)[1]


def compare(mod, label, size, methods, rounds, **kw):
    rows = []
    for method in methods:
        td, rd = best(lambda: mod.simulate(method=method, sparse=False, **kw), rounds)
        ts, rs = best(lambda: mod.simulate(method=method, sparse=True, **kw), rounds)
        diff = float(np.max(np.abs(rd.x - rs.x)))
        rows.append((label, size, method, td, ts, td / ts, diff))
        print(rows[-1], flush=True)
    return rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ladder", default="10,30,60,100,200,300")
    ap.add_argument("--batch", default="5,25,100,250")
    ap.add_argument("--methods", default="Radau,BDF,Rodas4")
    ap.add_argument("--rounds", type=int, default=2)
    a = ap.parse_args()
    methods = a.methods.split(",")
    rows = []
    for n in (int(s) for s in a.ladder.split(",") if s):
        mod = numpy_module(f"ladder{n}", ladder_yaml(n))
        rows += compare(mod, "RC ladder", n, methods, a.rounds, t_span=(0.0, 10.0), dt=0.01,
                        rtol=1e-6, atol=1e-9, max_steps=10**6)
    if a.batch:
        mod = numpy_module("msd", path=str(ROOT / "models" / "msd.yaml"))
        for k in (int(s) for s in a.batch.split(",") if s):
            rows += compare(mod, "msd batch", 2 * k, methods, a.rounds, t_span=(0.0, 20.0),
                            dt=0.05, rtol=1e-6, atol=1e-9, max_steps=10**6,
                            p={"k": np.linspace(100.0, 1e5, k)})
    load = os.getloadavg()[0]
    cmd = (f"python bench/bench_sparse.py --ladder {a.ladder} --batch {a.batch} "
           f"--methods {a.methods} --rounds {a.rounds}")
    lines = ["# Sparse against dense linear algebra in the numpy runtime", "",
             f"`{cmd}` (one run, side by side on the same module, best of {a.rounds}; load "
             f"average {load:.1f} at the end on {os.cpu_count()} cores).", "",
             "| problem | flat states | method | dense [s] | sparse [s] | dense / sparse | "
             "max state difference |", "|---|---|---|---|---|---|---|"]
    lines += [f"| {p} | {n} | {m} | {td:.3f} | {ts:.3f} | {r:.2f} | {d:.1e} |"
              for p, n, m, td, ts, r, d in rows]
    (ROOT / "bench" / "RESULTS_sparse.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
