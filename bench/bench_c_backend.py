"""The C backend against the numpy module, side by side in one run (ratios; absolute times on
this shared machine are noisy). Writes bench/RESULTS_c.md.

    python bench/bench_c_backend.py [--quick] [--out bench/RESULTS_c.md]

Measures, on the circle scene of the 3R2S (models/scenes/3r2s_circle.yaml, its specialised
module in both backends):
  * rhs and Jacobian per call at batch 1 (through the Python wrapper, and inside C: the
    library's loop over one instance) and per instance at batch 1000;
  * the circle integration at rtol 1e-6 (scene atol): C Rodas4, C Radau, numpy Radau, with
    the largest joint-angle error of each against a tight reference (C Radau at rtol 1e-10,
    itself checked against numpy Radau at rtol 1e-9);
  * a warm `bgc simulate SCENE --backend c --out r.npz` (cache hit, no plots) end to end
    against the hand-written Newton-Euler script (tests/reference/mech3r2s.py) at rtol 1e-6;
  * the symbolic compile (CPU seconds) and the C build (cold, runtime objects included).
"""
from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "models" / "scenes" / "3r2s_circle.yaml"
ANGLES = ("theta1", "theta2", "theta3", "theta4")


def per_call(fn, n_min=20, t_min=0.3):
    n, t0 = 0, time.perf_counter()
    while n < n_min or time.perf_counter() - t0 < t_min:
        fn()
        n += 1
    return (time.perf_counter() - t0) / n


def best(fn, rounds=3):
    out = []
    for _ in range(rounds):
        t0 = time.perf_counter()
        r = fn()
        out.append(time.perf_counter() - t0)
    return min(out), r


def _has_sparse_lu() -> bool:
    try:
        import bgc.lower.sparse_lu  # noqa: F401
        return True
    except ImportError:
        return False


def cpu_children():
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


_SYMBOLIC = r"""
import json, sys, time
t0 = time.process_time()
import bgc.run.driver, bgc.run.runner, bgc.format.scene  # sympy, networkx, symengine, jinja2 with them
t1 = time.process_time()
sc = bgc.format.scene.parse_scene(sys.argv[1])
bgc.run.runner._compiled(sc)
print(json.dumps([t1 - t0, time.process_time() - t1]))
"""


def symbolic_cpu(rounds: int) -> tuple[float, float]:
    """(imports, compile) CPU seconds of the circle scene's symbolic compile, each in a fresh
    interpreter (no warm sympy cache), the best of ``rounds``."""
    import json

    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    runs = [json.loads(subprocess.run([sys.executable, "-c", _SYMBOLIC, str(SCENE)], check=True,
                                      env=env, capture_output=True, text=True).stdout)
            for _ in range(rounds)]
    return min(r[0] for r in runs), min(r[1] for r in runs)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=str(ROOT / "bench" / "RESULTS_c.md"))
    ap.add_argument("--quick", action="store_true", help="skip the hand-written reference run")
    args = ap.parse_args()
    cache_dir = tempfile.mkdtemp(prefix="bgc-bench-cache-")
    os.environ["BGC_CACHE_DIR"] = cache_dir
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    sys.path.insert(0, str(ROOT / "src"))
    from bgc.backends import load as backends
    from bgc.backends.c import build as cbuild
    from bgc.backends.load import load_module
    from bgc.format.scene import parse_scene
    from bgc.run.cache import Cache
    from bgc.run.runner import _compiled, runtime_params

    L = ["# C backend against the numpy module", "",
         f"`python bench/bench_c_backend.py` on {os.cpu_count()} CPUs (shared machine: compare "
         "ratios), compiler `" + cbuild.identity().splitlines()[1] + "`, flags "
         f"`{' '.join(cbuild.flags())}`. C runtime: templates/c/runtime/ "
         f"({len(cbuild.runtime_sources())} files); LU: "
         + ("the sparse plan of bgc.lower.sparse_lu where it beats the dense LU"
            if _has_sparse_lu() else "dense (bgc.lower.sparse_lu absent)") + ".", ""]

    def say(line=""):
        print(line, flush=True)
        L.append(line)

    sc = parse_scene(SCENE)
    # compile: symbolic (CPU, in a fresh interpreter: the libraries' import apart, best of 3)
    # then the C build (cold: an empty cache, runtime objects too)
    t_imp, t_sym = symbolic_cpu(3)
    compiled, _ = _compiled(sc)
    npm = load_module(compiled.source, "circle_np_bench")
    w0, k0 = time.perf_counter(), cpu_children()
    _, cm = backends.load("circle_c_bench", "c", "bench" + "0" * 59, lambda: compiled, Cache())
    t_build, cpu_build = time.perf_counter() - w0, cpu_children() - k0
    files, _ = backends.c_files(compiled)
    nlines = sum(t.count("\n") for t in files.values())
    say("## Compile")
    say()
    say("| stage | time |")
    say("|---|---|")
    say(f"| symbolic compile of the circle scene's 3R2S ({len(npm.STATE_NAMES)} states, "
        f"{int(npm.JAC_SPARSITY.sum())} Jacobian entries), CPU, fresh interpreter | "
        f"{t_sym:.2f} s (+ {t_imp:.2f} s importing sympy, networkx, symengine, jinja2: "
        f"{t_imp + t_sym:.2f} s in all) |")
    say(f"| C build, cold ({len(files)} model units, {nlines} lines, + runtime), wall | "
        f"{t_build:.2f} s (compiler CPU {cpu_build:.1f} s) |")
    say()

    # rhs and Jacobian
    p = runtime_params(sc, npm)
    t = 1.0
    x = np.asarray(npm.X0, dtype=float)
    rng = np.random.default_rng(0)
    X = x[:, None] * (1 + 1e-3 * rng.standard_normal((len(x), 1000)))
    r_np1 = per_call(lambda: npm.rhs(t, x, p))
    r_c1 = per_call(lambda: cm.rhs(t, x, p))
    j_np1 = per_call(lambda: npm.jacobian(t, x, p), n_min=5)
    j_c1 = per_call(lambda: cm.jacobian(t, x, p))
    lib = cm._LIB
    n, nnz = cm.N_STATES, cm._C_NNZ
    P = cm._P_flat(cm._params(p)[0])
    T = np.array([t])
    Xc = np.ascontiguousarray(X.T)
    DX = np.empty((1000, n))
    JV = np.empty((1000, nnz))
    xc = np.ascontiguousarray(x)
    # inside C: 1000 calls on one instance (strides 0), and 1000 distinct instances
    r_c_in = per_call(lambda: lib.bgcm_eval_rhs(1000, cm._ptr(T), 0, cm._ptr(xc), 0,
                                                cm._ptr(P), 0, cm._ptr(DX), None)) / 1000
    j_c_in = per_call(lambda: lib.bgcm_eval_jac(1000, cm._ptr(T), 0, cm._ptr(xc), 0,
                                                cm._ptr(P), 0, cm._ptr(JV), None)) / 1000
    r_npB = per_call(lambda: npm.rhs(t, X, p), n_min=5) / 1000
    r_cB = per_call(lambda: lib.bgcm_eval_rhs(1000, cm._ptr(T), 0, cm._ptr(Xc), n,
                                              cm._ptr(P), 0, cm._ptr(DX), None)) / 1000
    r_cBw = per_call(lambda: cm.rhs(t, X, p), n_min=5) / 1000
    j_npB = per_call(lambda: npm.jacobian(t, X, p), n_min=3) / 1000
    j_cB = per_call(lambda: lib.bgcm_eval_jac(1000, cm._ptr(T), 0, cm._ptr(Xc), n,
                                              cm._ptr(P), 0, cm._ptr(JV), None)) / 1000
    assert np.allclose(cm.rhs(t, X, p), npm.rhs(t, X, p), rtol=1e-12, atol=1e-12)
    say("## rhs and Jacobian")
    say()
    say("| | numpy | C | ratio |")
    say("|---|---|---|---|")
    say(f"| rhs, batch 1, per call in C (library loop) | {r_np1 * 1e6:.1f} us | "
        f"{r_c_in * 1e6:.3f} us | {r_np1 / r_c_in:.0f}x |")
    say(f"| rhs, batch 1, per call through the Python wrapper | {r_np1 * 1e6:.1f} us | "
        f"{r_c1 * 1e6:.1f} us | {r_np1 / r_c1:.1f}x |")
    say(f"| rhs, batch 1000, per instance (in C) | {r_npB * 1e6:.3f} us | {r_cB * 1e6:.3f} us "
        f"| {r_npB / r_cB:.1f}x |")
    say(f"| rhs, batch 1000, per instance (wrapper) | {r_npB * 1e6:.3f} us | "
        f"{r_cBw * 1e6:.3f} us | {r_npB / r_cBw:.1f}x |")
    say(f"| Jacobian, batch 1, per call in C | {j_np1 * 1e6:.0f} us | {j_c_in * 1e6:.2f} us | "
        f"{j_np1 / j_c_in:.0f}x |")
    say(f"| Jacobian, batch 1, through the wrapper | {j_np1 * 1e6:.0f} us | {j_c1 * 1e6:.1f} us "
        f"| {j_np1 / j_c1:.0f}x |")
    say(f"| Jacobian, batch 1000, per instance | {j_npB * 1e6:.2f} us | {j_cB * 1e6:.2f} us | "
        f"{j_npB / j_cB:.1f}x |")
    say()

    # the circle integration
    kw = dict(dt=sc.dt, p=p, breakpoints=sc.breakpoints, atol=sc.atol)
    wall_ref, ref = best(lambda: cm.simulate(sc.t_span, method="Radau", rtol=1e-10,
                                             atol=sc.atol * 1e-4, max_steps=10 ** 7,
                                             **{k: v for k, v in kw.items() if k != "atol"}), 1)
    runs = {}
    for label, mod, meth, rounds in (("C Rodas4", cm, "Rodas4", 3), ("C Radau", cm, "Radau", 3),
                                     ("numpy Radau", npm, "Radau", 1)):
        wall, res = best(lambda: mod.simulate(sc.t_span, method=meth, rtol=sc.rtol, **kw), rounds)
        err = max(float(np.max(np.abs(res.y[a] - ref.y[a]))) for a in ANGLES)
        runs[label] = (wall, err, res.stats)
    check = npm.simulate(sc.t_span, method="Radau", rtol=1e-9, atol=sc.atol * 1e-3, **{
        k: v for k, v in kw.items() if k != "atol"})
    ref_err = max(float(np.max(np.abs(check.y[a] - ref.y[a]))) for a in ANGLES)
    base = runs["numpy Radau"][0]
    say(f"## Circle scene, rtol {sc.rtol:g}, atol {sc.atol:g}")
    say()
    say(f"Angle error: the largest joint-angle difference from C Radau at rtol 1e-10 "
        f"({wall_ref:.2f} s), which agrees with numpy Radau at rtol 1e-9 within {ref_err:.1e} rad.")
    say()
    say("| run | wall | speed-up vs numpy Radau | angle error | steps | rhs calls | LU |")
    say("|---|---|---|---|---|---|---|")
    for label, (wall, err, st) in runs.items():
        say(f"| {label} | {wall:.3f} s | {base / wall:.1f}x | {err:.1e} rad | {st['nsteps']} | "
            f"{st['nfev']} | {st['nlu']} |")
    say()

    # a batch of circle instances over threads (OpenMP): every instance its own step size
    ncpu = os.cpu_count() or 1
    nb = 4 * ncpu
    x0 = np.asarray(cm.initial_state(p) if p else cm.X0, dtype=float)
    rng = np.random.default_rng(1)
    XB = x0[:, None] * (1 + 1e-6 * rng.standard_normal((len(x0), nb)))  # nearby starts
    say(f"## A batch of {nb} circle instances (C Radau, rtol {sc.rtol:g}), over threads")
    say()
    if not cbuild.flags().count("-fopenmp"):
        say("The compiler has no OpenMP: instances run one after another.")
    say("| threads | wall | per instance | speed-up vs 1 thread |")
    say("|---|---|---|---|")
    one = None
    for th in sorted({1, 2, ncpu}):
        if th > ncpu:
            continue
        wall, _ = best(lambda: cm.simulate(sc.t_span, method="Radau", rtol=sc.rtol, x0=XB,
                                           nthreads=th, **kw), 3)
        one = one or wall
        say(f"| {th} | {wall:.3f} s | {wall / nb * 1e3:.1f} ms | {one / wall:.2f}x |")
    say()

    # warm bgc simulate end to end against the hand-written script
    with tempfile.TemporaryDirectory() as d:
        cmd = [sys.executable, "-m", "bgc", "simulate", str(SCENE), "--backend", "c", "--out",
               str(Path(d) / "r.npz"), "-q"]
        env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
        # as on a user's machine: Python keeps the byte code of bgc's modules (a run with
        # PYTHONDONTWRITEBYTECODE, as here by default, recompiles them at every start)
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        subprocess.run(cmd, check=True, env=env, capture_output=True)  # fills the cache
        warm, proc = best(lambda: subprocess.run(cmd, check=True, env=env, capture_output=True,
                                                 text=True), 7)
        summary = proc.stdout.strip().splitlines()[-1]
        # the same run the full way (straight into click: the scene parsed, the cache key
        # computed, the module loaded from the cache), without the run record's replay
        full_cmd = [sys.executable, "-c", "import sys; from bgc.cli.commands import main; "
                    "main(sys.argv[1:])", *cmd[3:]]
        full, _ = best(lambda: subprocess.run(full_cmd, check=True, env=env,
                                              capture_output=True), 7)
        say("## Warm `bgc simulate` end to end")
        say()
        say(f"`bgc simulate models/scenes/3r2s_circle.yaml --backend c --out r.npz` with the "
            f"module in the cache (best of 7, interpreter start-up included, byte code kept): "
            f"{warm:.3f} s, replaying its run record (bgc.run.record: no click, PyYAML or parser); "
            f"the full way with the module from the cache: {full:.3f} s.")
        say(f"Its summary line: `{summary}`")
        say()
        if not args.quick:
            script = ("import sys, numpy as np; sys.path.insert(0, %r); "
                      "from reference import mech3r2s as ref; "
                      "out = ref.simulate('circle', t_eval=np.linspace(0, 6, 1201), rtol=1e-6, "
                      "atol=5e-7); np.savez(%r, **{k: out[k] for k in ('theta1', 'theta2', "
                      "'theta3', 'theta4')})" % (str(ROOT / "tests"), str(Path(d) / "h.npz")))
            hand, _ = best(lambda: subprocess.run([sys.executable, "-c", script], check=True,
                                                  env=env, capture_output=True), 3)
            a, b = np.load(Path(d) / "r.npz"), np.load(Path(d) / "h.npz")
            diff = max(float(np.max(np.abs(a[k] - b[k]))) for k in ANGLES)
            say("| circle, rtol 1e-6, end to end | wall | hand-written script / this |")
            say("|---|---|---|")
            say(f"| hand-written script (solve_ivp Radau), best of 3 | {hand:.3f} s | 1.0x |")
            say(f"| bgc simulate --backend c, warm (run record) | {warm:.3f} s | "
                f"{hand / warm:.1f}x |")
            say(f"| the same, the full way (module from the cache) | {full:.3f} s | "
                f"{hand / full:.1f}x |")
            say()
            say(f"The two runs' joint angles agree within {diff:.1e} rad.")
            say()
    Path(args.out).write_text("\n".join(L) + "\n", encoding="utf-8")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
