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

Batches of larger models (``--cases``): the flat Jacobian of nb instances is block diagonal;
a dense LU factorises the (n nb)^2 matrix (cost ~ (n nb)^3), splu the blocks (~ nb x one
block's). For each case and batch size, dense and sparse end to end, interleaved, best of
--rounds, each instance with its own parameters, and which path the runtime's rule
(``_use_sparse``) picks; writes --out (the rule's table):

    python bench/bench_sparse.py --cases all --methods Radau,Rodas4 --rounds 2 \
        --out bench/RESULTS_sparse_batch.md

Writes bench/RESULTS_sparse.md (ladders and msd batches). CPU-bound and noisy on a shared
machine: the ratios within a row are the result, not the times. A dense LU under a
multithreaded BLAS is load-sensitive: OPENBLAS_NUM_THREADS=1 gives the other regime.
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


def _circle():
    from bgc.format.scene import parse_scene
    from bgc.run.runner import scene_module
    scene = parse_scene(ROOT / "models" / "scenes" / "3r2s_circle.yaml")
    mod = scene_module(scene, backend="numpy")[1]
    return mod, dict(t_span=(0.0, 0.05), dt=scene.dt, rtol=scene.rtol, atol=scene.atol,
                     breakpoints=scene.breakpoints), ("m1", "m2", "m3", "m4")


def _ladder(n):
    return (numpy_module(f"ladder{n}", ladder_yaml(n)),
            dict(t_span=(0.0, 1.0), dt=0.01, rtol=1e-6, atol=1e-9), ("R", "C"))


def _stem(stem, span, names, **kw):
    return (numpy_module(stem, path=str(ROOT / "models" / f"{stem}.yaml")),
            dict(t_span=(0.0, span), rtol=1e-6, atol=1e-9, **kw), names)


#: case -> (module, simulate's settings, parameters varied per instance), batch sizes
CASES = {
    "3r2s_circle": (_circle, (1, 2, 4, 8)),
    "ladder30": (lambda: _ladder(30), (1, 2, 4, 16)),
    "ladder100": (lambda: _ladder(100), (1, 2, 4)),
    "ladder300": (lambda: _ladder(300), (1, 2)),
    "double_pendulum_rigid": (lambda: _stem("double_pendulum_rigid", 1.0, ("m1", "m2")),
                              (2, 8, 32, 64)),
    "top": (lambda: _stem("top", 0.05, ("m",)), (2, 8, 16, 32)),
    "two_mass_chain": (lambda: _stem("two_mass_chain", 0.2, ("k1", "k2")), (1000,)),
}


def batch_cases(names, methods, rounds):
    """Dense against sparse LU end to end for each case, batch size and method, interleaved
    (dense, sparse, dense, ...), the best of rounds each; the rule's choice with it."""
    rows = []
    for name in names:
        make, sizes = CASES[name]
        mod, kw, varied = make()
        for nb in sizes:
            scale = np.linspace(0.9, 1.1, nb) if nb > 1 else np.ones(1)
            p = {k: float(mod.PARAM_DEFAULTS[k]) * (scale if nb > 1 else 1.0) for k in varied}
            for method in methods:
                best_t, res = {False: np.inf, True: np.inf}, {}
                for _ in range(rounds):
                    for sp in (False, True):
                        t0 = time.perf_counter()
                        res[sp] = mod.simulate(method=method, sparse=sp, p=p,
                                               max_steps=10**6, **kw)
                        best_t[sp] = min(best_t[sp], time.perf_counter() - t0)
                diff = float(np.max(np.abs(res[False].x - res[True].x)))
                rows.append((name, mod.N_STATES, nb, method, best_t[False], best_t[True],
                             bool(mod._use_sparse(nb, None, method)), diff))
                print(rows[-1], flush=True)
    return rows


def write_cases(rows, out, cmd, load_before, load_after):
    lines = ["# Dense or sparse LU for batches in the numpy runtime", "",
             f"`{cmd}` (written by it; interleaved, best of the rounds).", "",
             f"Machine (2 cores, shared): load average {load_before:.1f} before, "
             f"{load_after:.1f} after.", "",
             "picked: the runtime's rule (`_use_sparse`) when measured; picked / best: the "
             "picked path's time over the faster one's.", "",
             "| case | n | nb | flat | method | dense [s] | sparse [s] | dense / sparse | "
             "picked | picked / best | max state difference |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, n, nb, m, td, ts, use, d in rows:
        picked = ts if use else td
        lines.append(f"| {name} | {n} | {nb} | {n * nb} | {m} | {td:.3f} | {ts:.3f} | "
                     f"{td / ts:.2f} | {'sparse' if use else 'dense'} | "
                     f"{picked / min(td, ts):.2f} | {d:.1e} |")
    Path(out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", default="", help=f"comma-separated, or all: {', '.join(CASES)}")
    ap.add_argument("--out", default=str(ROOT / "bench" / "RESULTS_sparse_batch.md"))
    ap.add_argument("--ladder", default="10,30,60,100,200,300")
    ap.add_argument("--batch", default="5,25,100,250")
    ap.add_argument("--methods", default="Radau,BDF,Rodas4")
    ap.add_argument("--rounds", type=int, default=2)
    a = ap.parse_args()
    methods = a.methods.split(",")
    if a.cases:
        names = list(CASES) if a.cases == "all" else a.cases.split(",")
        before = os.getloadavg()[0]
        rows = batch_cases(names, methods, a.rounds)
        cmd = "python bench/bench_sparse.py" + "".join(f" {x}" for x in sys.argv[1:])
        write_cases(rows, a.out, cmd, before, os.getloadavg()[0])
        return
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
