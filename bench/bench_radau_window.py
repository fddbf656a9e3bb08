"""C Radau5's step-size freeze window, measured on the example scenes. Writes
bench/RESULTS_radau_window.md.

    python bench/bench_radau_window.py [--windows 1.2,1.4,1.6,2.0] [--scenes a,b,...]

With the Jacobian kept, C Radau5 keeps the step size (and both LUs) unless its controller asks
for more than FREEZE_MAX times it (templates/c/runtime/bgc_radau5.c). Each window is built as
its own C runtime (``CC="cc -DBGC_RADAU_FREEZE_MAX=w"``, a compile cache of its own); every scene
runs with its own solver settings (method Radau), best of 5 in one process, and is compared with
a reference run at rtol 1e-10 (atol 1e-4 of the scene's) of the default build: the largest
joint-angle error for the 3R2S scenes, else the largest output error relative to the output's
range. Windows and scenes run one after another in this one invocation (ratios matter: the
machine is shared).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCENES = ("3r2s_circle", "3r2s_figure8", "3r2s_gearshift", "quarter_car_bump", "motor_full",
          "double_pendulum_swing", "dc_motor_load_step", "msd_step", "pendulum_swing",
          "motor_electrothermal")


def _module(scene: Path):
    """(module, the run's simulate arguments) from the scene's run record (bgc.run.record),
    written by a `bgc simulate` just before."""
    from bgc.backends.load import load_entry
    from bgc.run import record
    from bgc.run.cache import Cache

    opts = record.options_text("Radau", None, None, None, "c", False)
    rec = record.load(Cache(), record.record_key(str(scene), scene.read_bytes(), opts))
    mod = load_entry(Cache().get("c", rec["key"]), "c", scene.stem, trusted=True)
    return mod, dict(rec["run"])


def worker(scenes, ref_dir: Path, make_ref: bool) -> None:
    """In a process whose environment selects the window: each scene's time, counts, error."""
    import numpy as np

    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    for name in scenes:
        scene = ROOT / "models" / "scenes" / f"{name}.yaml"
        subprocess.run([sys.executable, "-m", "bgc", "simulate", str(scene), "--backend", "c",
                        "--method", "Radau", "-q"], check=True, env=env, capture_output=True)
        mod, run = _module(scene)
        x0 = run.pop("x0")
        x0 = None if x0 is None else np.array(x0, dtype=float)
        span = tuple(run.pop("t_span"))
        ref = ref_dir / f"{name}.npz"
        if make_ref:
            tight = dict(run, rtol=1e-10, atol=run["atol"] * 1e-4, max_steps=10**7)
            np.savez(ref, **mod.simulate(span, x0=x0, **tight)[2])
            continue
        best = None
        for _ in range(5):
            t0 = time.perf_counter()
            res = mod.simulate(span, x0=x0, **run)
            dt = time.perf_counter() - t0
            best = dt if best is None else min(best, dt)
        y, R = res[2], np.load(ref)
        angles = [k for k in R.files if k.startswith("theta")]
        if angles:
            err = max(float(np.max(np.abs(R[k] - y[k]))) for k in angles)
        else:
            err = max(float(np.max(np.abs(R[k] - y[k])) / max(1e-300, np.ptp(R[k]) or
                                                              float(np.max(np.abs(R[k])))))
                      for k in R.files if k in y)
        st = res.stats
        print(json.dumps({"scene": name, "time": best, "err": err, "steps": st["nsteps"],
                          "rejected": st["nrejected"], "lu_pairs": st["nlu"] // 2,
                          "jac": st["njev"], "nfev": st["nfev"]}), flush=True)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--windows", default="1.2,1.4,1.6,2.0")
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--out", default=str(ROOT / "bench" / "RESULTS_radau_window.md"))
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--ref-dir", help=argparse.SUPPRESS)
    ap.add_argument("--make-ref", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    scenes = args.scenes.split(",")
    if args.worker:
        sys.path.insert(0, str(ROOT / "src"))
        worker(scenes, Path(args.ref_dir), args.make_ref)
        return
    cc = os.environ.get("CC", "cc")
    rows: dict[str, list[dict]] = {}
    with tempfile.TemporaryDirectory(prefix="bgc-window-") as d:
        d = Path(d)

        def run(window, make_ref=False):
            env = {**os.environ, "BGC_CACHE_DIR": str(d / f"cache-{window or 'default'}")}
            env.pop("PYTHONDONTWRITEBYTECODE", None)
            if window:
                env["CC"] = f"{cc} -DBGC_RADAU_FREEZE_MAX={window}"
            cmd = [sys.executable, __file__, "--worker", "--scenes", args.scenes,
                   "--ref-dir", str(d)] + (["--make-ref"] if make_ref else [])
            out = subprocess.run(cmd, check=True, env=env, capture_output=True, text=True)
            return [json.loads(ln) for ln in out.stdout.splitlines() if ln.startswith("{")]

        print("references (rtol 1e-10)", flush=True)
        run(None, make_ref=True)
        for w in args.windows.split(","):
            print(f"window {w}", flush=True)
            rows[w] = run(w)
    L = ["# C Radau5's freeze window", "",
         f"`python bench/bench_radau_window.py` (one run, 2 shared CPUs; {cc}). With the "
         "Jacobian kept, the step size (and both LUs) stays unless the controller asks for more "
         "than the window times it. Time: best of 5 in one process. Error: the largest "
         "joint-angle error (rad) for the 3R2S scenes, else the largest output error relative "
         "to the output's range, against rtol 1e-10.", "",
         "| scene | window | time | steps | rejected | LU pairs | Jacobians | rhs calls | error |",
         "|---|---|---|---|---|---|---|---|---|"]
    for s in scenes:
        for w, rs in rows.items():
            r = next((r for r in rs if r["scene"] == s), None)
            if r is None:
                continue
            L.append(f"| {s} | {w} | {r['time'] * 1e3:.2f} ms | {r['steps']} | {r['rejected']} "
                     f"| {r['lu_pairs']} | {r['jac']} | {r['nfev']} | {r['err']:.2e} |")
    L += ["", "| window | total time of the scenes |", "|---|---|"]
    for w, rs in rows.items():
        L.append(f"| {w} | {sum(r['time'] for r in rs) * 1e3:.1f} ms |")
    Path(args.out).write_text("\n".join(L) + "\n", encoding="utf-8")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
