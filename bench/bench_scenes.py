"""What scene specialisation saves, for every scene in models/scenes/.

    python bench/bench_scenes.py [--scenes NAME ...] [--rounds 7] [--out bench/RESULTS_scenes.md]

For each scene, its full model (the model with the scene's signals and parameter values, every
effect on, every output) and the scene's specialised module are compiled in this one run and
compared side by side: states, operations after CSE in rhs and jacobian (counted in the
generated code), the cost of one rhs call (median of interleaved rounds at the initial state),
and the wall time of the whole scene simulated with each module (the scene's solver settings,
one run each, full first). A shared machine is noisy: read the ratios, not the absolute times.

OpenBLAS is limited to one thread (before numpy loads): the LU factorisations of these small
implicit-solver matrices gain nothing from threads, and on a busy 2-core machine threads that
wait for each other make the wall times erratic (measured: the same 0.05 s of the 3R2S circle
took 21.5 s with the default threads under load and 0.7 s with one).
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def wall(mod, scene, p):
    t0 = time.perf_counter()
    res = mod.simulate(scene.t_span, dt=scene.dt, method=scene.method, rtol=scene.rtol,
                       atol=scene.atol, p=p, breakpoints=scene.breakpoints,
                       max_step=scene.max_step)
    return time.perf_counter() - t0, res.stats["nfev"]


def _warm_up():
    """Load scipy's solver and numpy's code paths once, so the first scene is not charged."""
    import numpy as np
    from scipy.integrate import solve_ivp

    solve_ivp(lambda t, y: -y, (0, 1), np.ones(2), method="Radau", jac=lambda t, y: -np.eye(2))


def main(argv=None):
    from bgc.run.runner import explain_scene

    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", nargs="*", help="scene file stems (default: all)")
    ap.add_argument("--rounds", type=int, default=7, help="interleaved rhs timing rounds")
    ap.add_argument("--out", type=Path, help="also write the table (markdown) here")
    args = ap.parse_args(argv)
    paths = sorted((ROOT / "models" / "scenes").glob("*.yaml"))
    if args.scenes:
        paths = [p for p in paths if p.stem in args.scenes]
    head = ("| scene | states full → scene | rhs ops full → scene | jacobian ops full → scene "
            "| rhs call [µs] full → scene (ratio) | scene wall [s] full → scene (ratio) "
            "| rhs calls full / scene | compile [s] full / scene |")
    rows = [head, "|" + "---|" * 8]
    print(head, flush=True)
    print(rows[1], flush=True)
    _warm_up()
    t_all = time.perf_counter()
    for path in paths:
        ex = explain_scene(path)
        (of, os_), (cf, cs) = ex.ops(), ex.rhs_cost(args.rounds)
        wf, nf = wall(ex.full_module, ex.scene, ex.full_params)
        if ex.same:
            ws, ns = wf, nf
        else:
            ws, ns = wall(ex.module, ex.scene, ex.params)
        nfull, nspec = len(ex.full_module.STATE_NAMES), len(ex.module.STATE_NAMES)
        same = " (same module)" if ex.same else ""
        row = (f"| {path.stem}{same} | {nfull} → {nspec} | {of['rhs']} → {os_['rhs']} "
               f"| {of['jacobian']} → {os_['jacobian']} "
               f"| {cf * 1e6:.0f} → {cs * 1e6:.0f} ({cs / cf:.2f}) "
               f"| {wf:.2f} → {ws:.2f} ({ws / wf:.2f}) | {nf} / {ns} "
               f"| {ex.compile_time[0]:.1f} / {ex.compile_time[1]:.1f} |")
        rows.append(row)
        print(row, flush=True)
    total = time.perf_counter() - t_all
    print(f"\n{len(paths)} scenes in {total:.0f} s", flush=True)
    if args.out:
        cmd = "python bench/bench_scenes.py" + (f" --scenes {' '.join(args.scenes)}"
                                                if args.scenes else "")
        text = (f"# Scene specialisation: full model against scene\n\n"
                f"Command: `{cmd} --out {args.out}` "
                f"({time.strftime('%Y-%m-%d')}, Python {platform.python_version()}, "
                f"{os.cpu_count()} CPUs, OPENBLAS_NUM_THREADS="
                f"{os.environ.get('OPENBLAS_NUM_THREADS')}; one run, {total:.0f} s).\n\n"
                + "\n".join(rows) + "\n\n"
                "Operations: arithmetic operators and numpy calls in the generated `rhs` and "
                "`jacobian` after common-subexpression elimination. rhs call: median of "
                f"{args.rounds} interleaved rounds at the initial state with the modules' "
                "default parameters. Scene wall: one `simulate` of the whole scene with the "
                "scene's solver settings (the full module first). Compile times include the "
                "first compile's warm-up (full model first).\n")
        args.out.write_text(text, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
