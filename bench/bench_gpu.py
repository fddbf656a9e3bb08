"""The generated 3R2S module's rhs and Jacobian on a GPU: CuPy and JAX beside numpy.

    python bench/bench_gpu.py [--sizes 100,1000,10000,100000,1000000] [--out RESULTS_gpu.md]

The golden module `generated/mech3r2s.py` (101 states, the compliant 3R2S) is imported as a
plain file. Its `rhs(t, x)` and `jacobian(t, x)` take the array namespace from x (array API
standard, through array-api-compat): numpy arrays run on the CPU, CuPy arrays on the GPU,
unchanged. `bgc.fused.jax_functions` rewrites both into one `jax.jit` computation each.
For each batch size N (states of shape (101, N): N instances at random states near the
assembled pose), side by side in one process, the median of `--repeats` calls after a
warm-up call (JAX's compile and CuPy's kernel builds excluded; the GPU synchronised before
the clock stops):

* numpy on the CPU, CuPy, and JAX (jit) on the GPU: seconds per call and instances per second;
* every GPU result against numpy's: the largest difference relative to the entry's scale.

The Jacobian (101 x 101 x N) runs up to `--jac-max` instances (through JAX only with
`--jax-jacobian`). The JAX column's first call (tracing and XLA's compile) is in the JSON. No GPU, CuPy or JAX: their
columns say so and the rest still runs. Writes a markdown table to --out (default: stdout).
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def load_golden(name="mech3r2s"):
    spec = importlib.util.spec_from_file_location(f"golden_{name}", ROOT / "generated" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def timed(call, sync, repeats):
    call()
    sync()  # warm-up: JIT compiles, kernel caches
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        call()
        sync()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def rel_diff(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


def backends():
    out = {}
    try:
        import cupy as cp

        cp.cuda.runtime.getDeviceCount()
        out["cupy"] = cp
    except Exception as exc:  # noqa: BLE001 - reported in the table
        out["cupy"] = f"unavailable ({type(exc).__name__})"
    try:
        sys.path.insert(0, str(ROOT / "src"))
        from bgc import fused

        if not fused.available():
            raise ImportError("no jax")
        import jax

        out["jax"] = (fused, jax)
    except Exception as exc:  # noqa: BLE001
        out["jax"] = f"unavailable ({type(exc).__name__})"
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="100,1000,10000,100000,1000000")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--jac-max", type=int, default=10000)
    ap.add_argument("--out", default=None)
    ap.add_argument("--json", default=None)
    ap.add_argument("--jax-jacobian", action="store_true",
                    help="also the Jacobian through JAX (XLA's compile of its 1914 entries "
                         "takes minutes)")
    a = ap.parse_args()
    mod = load_golden()
    n = mod.N_STATES
    have = backends()
    rng = np.random.default_rng(1)
    rows = []
    for size in [int(s) for s in a.sizes.split(",") if s]:
        x0 = np.asarray(mod.X0, dtype=float)[:, None]
        x = x0 + 1e-3 * np.maximum(np.abs(x0), 1e-2) * rng.standard_normal((n, size))
        t = 0.37
        funcs = [("rhs", mod.rhs)] + ([("jacobian", mod.jacobian)] if size <= a.jac_max else [])
        for fname, f in funcs:
            row = {"function": fname, "N": size}
            ref = f(t, x)
            row["numpy"] = timed(lambda: f(t, x), lambda: None, a.repeats)
            cp = have["cupy"]
            if isinstance(cp, str):
                row["cupy"] = cp
            else:
                xg = cp.asarray(x)
                sync = cp.cuda.Device().synchronize
                row["cupy"] = timed(lambda: f(t, xg), sync, a.repeats)
                row["cupy_err"] = rel_diff(cp.asnumpy(f(t, xg)), ref)
                del xg
                cp.get_default_memory_pool().free_all_blocks()
            jx = have["jax"]
            if fname == "jacobian" and not a.jax_jacobian:
                row["jax"] = "not run"
            elif isinstance(jx, str):
                row["jax"] = jx
            else:
                fused, jax = jx
                rhs_j, jac_j = fused.jax_functions(mod)
                g = rhs_j if fname == "rhs" else jac_j
                xj = jax.device_put(x)
                t0 = time.perf_counter()
                g(t, xj).block_until_ready()
                row["jax_first"] = time.perf_counter() - t0  # tracing and XLA's compile
                row["jax"] = timed(lambda: g(t, xj).block_until_ready(), lambda: None,
                                   a.repeats)
                row["jax_err"] = rel_diff(np.asarray(g(t, xj)), ref)
                row["jax_device"] = str(xj.devices())
                del xj
            rows.append(row)
            print(json.dumps(row), flush=True)
    lines = [f"# The 3R2S's rhs and Jacobian on numpy, CuPy and JAX\n",
             f"`python bench/bench_gpu.py --sizes {a.sizes}` (median of {a.repeats} calls after "
             f"a warm-up; {platform.node()}, Python {platform.python_version()}, numpy "
             f"{np.__version__}). Seconds per call; the speed-up is numpy's time over the "
             "GPU's; err is the largest difference from numpy's result relative to the "
             "result's largest entry.\n",
             "| function | N | numpy [s] | CuPy [s] | CuPy speed-up | CuPy err | JAX jit [s] "
             "| JAX speed-up | JAX err |", "|---|---|---|---|---|---|---|---|---|"]

    def cell(r, k):
        v = r.get(k)
        return f"{v:.3g}" if isinstance(v, float) else (v or "-")

    for r in rows:
        sp = {k: (f"{r['numpy'] / r[k]:.1f}x" if isinstance(r.get(k), float) else "-")
              for k in ("cupy", "jax")}
        lines.append(f"| {r['function']} | {r['N']} | {r['numpy']:.3g} | {cell(r, 'cupy')} | "
                     f"{sp['cupy']} | {cell(r, 'cupy_err')} | {cell(r, 'jax')} | {sp['jax']} | "
                     f"{cell(r, 'jax_err')} |")
    text = "\n".join(lines) + "\n"
    if a.out:
        Path(a.out).write_text(text)
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1))
    print(text)


if __name__ == "__main__":
    main()
