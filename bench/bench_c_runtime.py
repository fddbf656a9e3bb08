"""The C runtime's speed: time per run and steps per second of Rodas4 and Radau5 on the test
models of tests/c_models, and dense against plan-ordered sparse LU (factorisation + solve of
c*I - J) on the 3R2S's Jacobian pattern and on long spring-damper chains, all measured side by
side in one run.

    python bench/bench_c_runtime.py [--quick]

The 3R2S pattern comes from `bgc compile models/3r2s.yaml` (JAC_SPARSITY); its values here
are random (the factorisation's cost depends on the pattern only)."""

from __future__ import annotations

import argparse
import ctypes as C
import importlib.util
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
import c_runtime_harness as H  # noqa: E402

from bgc.lower.sparse_lu import flops, make_plan  # noqa: E402


def build(tmp: Path) -> H.Lib:
    cc = H.compiler()
    if cc is None:
        sys.exit("no C compiler (CC or cc)")
    srcs = sorted(str(p) for p in H.RUNTIME.glob("*.c")) + [str(H.MODELS),
                                                           str(ROOT / "bench/c/lu_bench.c")]
    out = tmp / "bench.so"
    omp = ["-fopenmp"] if H.openmp_works(cc, tmp) else []
    subprocess.run(cc.split() + H.FLAGS + omp + ["-I", str(H.RUNTIME), "-o", str(out)] + srcs
                   + ["-lm"], check=True)
    lib = H.Lib(out)
    lib.lib.bench_linsys.restype = C.c_double
    lib.lib.bench_linsys.argtypes = [C.POINTER(H.Model), H.DBLP, C.c_double, C.c_int, C.c_int]
    return lib


def best_time(fn, repeat=5):
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def runs(lib, quick):
    chain_p = [2, 1e6, 1.0, 1e4, 1.0]
    r2, c2 = H.chain_pattern(2)
    cases = [
        ("pendulum, t = 0..10", lib.model("pend", 2, [0, 1], [1, 0], 1), [9.81], [1.0, 0.0], 10.0),
        ("forced msd, t = 0..5", lib.model("msd", 2, [0, 1, 1], [1, 0, 1], 5, time_inputs=True),
         [1.0, 40.0, 0.8, 2.0, 3.0], [1.0, 0.0], 5.0),
        ("Van der Pol eps=1e-6, t = 0..2", lib.model("vdp", 2, [0, 1, 1], [1, 0, 1], 1), [1e-6],
         [2.0, 0.0], 2.0),
        ("stiff 2-mass chain, t = 0..2", lib.model("chain", 4, r2, c2, 5), chain_p,
         [0.01, 0.0, 0.0, 1.0], 2.0),
    ]
    print("\n## Integration (time per run, best of 5; rtol = atol = tol, 101 output times)\n")
    print("| model | method | tol | steps | time per run | steps/s |")
    print("|---|---|---|---|---|---|")
    for name, mod, p, x0, t1 in cases:
        t = np.linspace(0, t1, 101)
        for method in ("Rodas4", "Radau5"):
            for tol in ((1e-6,) if quick else (1e-4, 1e-6, 1e-8)):
                status, Y, st = mod.run(p, 0.0, t1, x0, method=method, rtol=tol, atol=tol, t_out=t)
                assert status == 0, st.message
                dt = best_time(lambda: mod.run(p, 0.0, t1, x0, method=method, rtol=tol,
                                               atol=tol, t_out=t))
                print(f"| {name} | {method} | {tol:g} | {st.naccept} | {dt * 1e6:.0f} µs | "
                      f"{st.naccept / dt:.3g} |")


def lu_row(lib, label, n, rows, cols, reps):
    rng = np.random.default_rng(0)
    jv = rng.normal(size=len(rows))
    cval = 1.0 + np.abs(jv).sum() / max(n, 1) * 4
    plan = make_plan(n, rows, cols)
    dense = lib.model("chain", n, rows, cols, 0)
    sparse = lib.model("chain", n, rows, cols, 0, plan=plan)
    out = []
    for cplx in (0, 1):
        td = min(lib.lib.bench_linsys(C.byref(dense.s), H.ptr(jv), cval, reps, cplx)
                 for _ in range(3))
        ts = min(lib.lib.bench_linsys(C.byref(sparse.s), H.ptr(jv), cval, reps * 10, cplx)
                 for _ in range(3))
        out.append((td, ts))
    (dr, sr), (dz, sz) = out
    print(f"| {label} | {n} | {len(rows)} | {plan.nnz_lu} | {flops(plan)} | "
          f"{dr * 1e6:.1f} | {sr * 1e6:.2f} | {dr / sr:.1f} | {dz * 1e6:.1f} | {sz * 1e6:.2f} | "
          f"{dz / sz:.1f} |")


def three_r2s_pattern(tmp: Path):
    cached = ROOT / "bench" / "c" / "3r2s_pattern.npz"
    if cached.exists():
        S = np.load(cached)["S"]
    else:
        out = tmp / "m3r2s.py"
        subprocess.run([sys.executable, "-m", "bgc", "compile", str(ROOT / "models/3r2s.yaml"),
                        "-o", str(out)], check=True, capture_output=True)
        spec = importlib.util.spec_from_file_location("m3r2s", out)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        S = np.asarray(mod.JAC_SPARSITY, dtype=bool)
    return np.nonzero(S), S.shape[0]


def lu(lib, tmp, quick):
    print("\n## Linear algebra: factorise c*I - J and solve once (µs; best of 3)\n")
    print("| pattern | n | J nonzeros | L+U with fill | sparse flops | dense real | "
          "sparse real | ratio | dense complex | sparse complex | ratio |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    (r, c), n = three_r2s_pattern(tmp)
    lu_row(lib, "3R2S", n, r, c, 200)
    for N in ((50, 100) if quick else (10, 50, 100, 250, 500, 1000)):
        r, c = H.chain_pattern(N)
        lu_row(lib, "chain", 2 * N, r, c, max(1, int(2e7 / (2 * N) ** 3)))


def chain_integration(lib, quick):
    print("\n## Chains, whole runs: dense against sparse LU (Rodas4 and Radau5, rtol 1e-6)\n")
    print("| n | method | steps | dense | sparse | ratio |")
    print("|---|---|---|---|---|---|")
    for N in ((25, 100) if quick else (10, 25, 50, 100, 250)):
        r, c = H.chain_pattern(N)
        p = [N, 1e5, 10.0, 2.0, 1.0]
        x0 = np.zeros(2 * N)
        x0[-1] = 1.0
        t = np.linspace(0, 1, 11)
        d = lib.model("chain", 2 * N, r, c, 5)
        s = lib.model("chain", 2 * N, r, c, 5, plan=make_plan(2 * N, r, c))
        for method in ("Rodas4", "Radau5"):
            kw = dict(method=method, rtol=1e-6, atol=1e-8, t_out=t)
            st = d.run(p, 0.0, 1.0, x0, **kw)[2]
            td = best_time(lambda: d.run(p, 0.0, 1.0, x0, **kw), 3)
            ts = best_time(lambda: s.run(p, 0.0, 1.0, x0, **kw), 3)
            print(f"| {2 * N} | {method} | {st.naccept} | {td * 1e3:.2f} ms | "
                  f"{ts * 1e3:.2f} ms | {td / ts:.1f} |")


def batches(lib, quick):
    print("\n## Batches: 1000 pendulums (own parameters, own steps), Radau5 and Rodas4 rtol 1e-6\n")
    print("| method | serial loop of single runs | batch, 1 thread | batch, 2 threads |")
    print("|---|---|---|---|")
    m = lib.model("pend", 2, [0, 1], [1, 0], 1)
    nb = 200 if quick else 1000
    rng = np.random.default_rng(0)
    P = rng.uniform(1, 20, (nb, 1))
    X0 = np.column_stack([rng.uniform(-2, 2, nb), np.zeros(nb)])
    t = np.linspace(0, 10, 101)
    for method in ("Rodas4", "Radau5"):
        kw = dict(method=method, rtol=1e-6, atol=1e-6, t_out=t)
        single = best_time(lambda: [m.run(P[k], 0.0, 10.0, X0[k], **kw) for k in range(nb)], 3)
        b1 = best_time(lambda: m.run_batch(P, 0.0, 10.0, X0, nthreads=1, **kw), 3)
        b2 = best_time(lambda: m.run_batch(P, 0.0, 10.0, X0, nthreads=2, **kw), 3)
        print(f"| {method} | {single * 1e3:.1f} ms | {b1 * 1e3:.1f} ms | {b2 * 1e3:.1f} ms "
              f"({b1 / b2:.2f}x) |")


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="fewer sizes and tolerances")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        lib = build(tmp)
        print(f"# bench_c_runtime ({'quick' if args.quick else 'full'}), "
              f"OpenMP: {bool(lib.lib.bgc_have_openmp())}")
        runs(lib, args.quick)
        lu(lib, tmp, args.quick)
        chain_integration(lib, args.quick)
        batches(lib, args.quick)


if __name__ == "__main__":
    main()
