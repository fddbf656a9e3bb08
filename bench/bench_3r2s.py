"""Speed of the 3R2S model: compile time by stage, right-hand-side cost, scene wall times,
where a scene's time goes, and what the circle's accuracy costs.

    python bench/bench_3r2s.py [--scenes circle figure8 gearshift] [--no-accuracy]
                               [--out bench/RESULTS.md]

Everything is measured in this one run (these machines are shared and noisy): compare the
ratios, not the seconds across runs. The report is printed and written as markdown.
"""
from __future__ import annotations

import argparse
import cProfile
import io
import os
import pstats
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: see tests/conftest.py

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
ANGLES = ("theta1", "theta2", "theta3", "theta4")


def per_call(fn, n_min=20, t_min=0.5):
    """Mean seconds per call over at least n_min calls and t_min seconds."""
    n, t0 = 0, time.perf_counter()
    while n < n_min or time.perf_counter() - t0 < t_min:
        fn()
        n += 1
    return (time.perf_counter() - t0) / n


def compile_stages(path):
    """Compile with a progress hook that timestamps every stage."""
    from bgc.run.driver import compile_file

    marks = []
    t0 = time.perf_counter()
    c = compile_file(path, progress=lambda msg: marks.append((time.perf_counter() - t0, msg)))
    total = time.perf_counter() - t0
    marks.append((total, "done"))
    stages = [(msg, marks[k + 1][0] - at) for k, (at, msg) in enumerate(marks[:-1])]
    return c, total, stages


def run_scene(mod, sc, rtol=None, atol=None, profile=False):
    kw = dict(dt=sc.dt, method=sc.method, rtol=rtol or sc.rtol, atol=atol or sc.atol,
              breakpoints=sc.breakpoints, max_step=sc.max_step)
    prof = cProfile.Profile() if profile else None
    t0 = time.perf_counter()
    if prof:
        prof.enable()
    res = mod.simulate(sc.t_span, **kw)
    if prof:
        prof.disable()
    return res, time.perf_counter() - t0, prof


def where_time_goes(prof):
    """Shares of a profiled run: generated rhs, generated Jacobian, LU work, the rest."""
    st = pstats.Stats(prof, stream=io.StringIO())
    share = {"rhs (generated)": 0.0, "jacobian (generated)": 0.0, "LU factor/solve": 0.0}
    for (file, _, fn), (_, _, _, cumulative, _) in st.stats.items():
        if fn == "rhs" and "bgc_" in file:
            share["rhs (generated)"] += cumulative
        elif fn == "jacobian" and "bgc_" in file:
            share["jacobian (generated)"] += cumulative
        elif fn in ("lu_factor", "lu_solve", "splu"):
            share["LU factor/solve"] += cumulative
    total = st.total_tt
    share["integrator and the rest (scipy, Python)"] = max(total - sum(share.values()), 0.0)
    return {k: v / total for k, v in share.items()}


def main():
    from bgc.backends.load import load_module
    from bgc.format.scene import parse_scene
    from bgc.run.runner import compile_scene

    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", nargs="*", default=["circle", "figure8", "gearshift"])
    ap.add_argument("--no-accuracy", action="store_true",
                    help="skip the rtol 1e-10 comparison run of the circle (about a minute)")
    ap.add_argument("--no-reference", action="store_true",
                    help="skip the hand-written reference model's circle run (about 10 s)")
    ap.add_argument("--out", default=str(ROOT / "bench" / "RESULTS.md"))
    args = ap.parse_args()
    L = ["# 3R2S benchmark", "",
         "`python bench/bench_3r2s.py` (all numbers from one run on one machine).", ""]

    def say(line=""):
        print(line, flush=True)
        L.append(line)

    c, total, stages = compile_stages(ROOT / "models" / "3r2s.yaml")
    eq = c.equations
    say(f"## Compile: {total:.2f} s for `models/3r2s.yaml`")
    say()
    say(f"{len(eq.states)} states, {len(eq.assignments)} causal assignments, "
        f"{len(eq.jacobian)} Jacobian nonzeros ({len(eq.jacobian) / len(eq.states) ** 2:.1%} "
        "of the matrix).")
    say()
    say("| stage | s | share |")
    say("|---|---|---|")
    for msg, dt in stages:
        say(f"| {msg} | {dt:.2f} | {dt / total:.0%} |")
    say()

    m = load_module(c.source, "mech3r2s_bench")
    x = m.X0 + 1e-6 * np.random.default_rng(0).standard_normal(m.X0.shape)
    r1 = per_call(lambda: m.rhs(0.1, x))
    j1 = per_call(lambda: m.jacobian(0.1, x))
    xb = np.repeat(x[:, None], 1000, axis=1)
    rb = per_call(lambda: m.rhs(0.1, xb), n_min=5)
    jb = per_call(lambda: m.jacobian(0.1, xb), n_min=3)
    say("## Right-hand side and Jacobian")
    say()
    say("| call | batch 1 | batch 1000, per instance | ratio |")
    say("|---|---|---|---|")
    say(f"| rhs | {r1 * 1e6:.0f} us | {rb / 1000 * 1e6:.2f} us | {r1 / (rb / 1000):.0f}x |")
    say(f"| jacobian (analytic) | {j1 * 1e6:.0f} us | {jb / 1000 * 1e6:.2f} us | "
        f"{j1 / (jb / 1000):.0f}x |")
    say()
    say(f"The analytic Jacobian costs {j1 / r1:.1f} rhs calls at batch 1; a finite-difference "
        f"Jacobian costs {len(x)} (dense) or one per colour group of JAC_SPARSITY.")
    say()

    say("## Scenes (each scene's own solver settings)")
    say()
    say("| scene | states | method | rtol | atol | compile [s] | integrate [s] | rhs calls "
        "| Jacobians | LU |")
    say("|---|---|---|---|---|---|---|---|---|---|")
    profiled = None
    circle = None
    for name in args.scenes:
        sc = parse_scene(ROOT / "models" / "scenes" / f"3r2s_{name}.yaml")
        t0 = time.perf_counter()
        _, mod = compile_scene(sc)
        ct = time.perf_counter() - t0
        res, wall, prof = run_scene(mod, sc, profile=(name == "circle"))
        if name == "circle":
            _, wall, _ = run_scene(mod, sc)  # the wall time without the profiler
            profiled, circle = prof, (sc, mod, res)
        s = res.stats
        say(f"| {name} | {mod.N_STATES} | {sc.method} | {sc.rtol:g} | {sc.atol:g} | {ct:.2f} | "
            f"{wall:.2f} | {s['nfev']} | {s['njev']} | {s.get('nlu', 0)} |")
    say()
    if profiled:
        shares = where_time_goes(profiled)
        say("## Where the circle's integration time goes (cProfile)")
        say()
        say("| part | share |")
        say("|---|---|")
        for k, v in shares.items():
            say(f"| {k} | {v:.0%} |")
        say()
    if circle and not args.no_reference:
        # the independent hand-written numpy model of the same machine (tests/reference/), run
        # as such a model usually is: solve_ivp's Radau with finite-difference Jacobians
        import sys

        sys.path.insert(0, str(ROOT / "tests"))
        from reference import mech3r2s as ref

        sc, mod, res = circle
        y0 = ref.initial_state()
        r_ref = per_call(lambda: ref.rhs(0.1, y0, "circle"))
        out = ref.simulate("circle", t_eval=res.t, rtol=sc.rtol, atol=sc.atol)
        _, wall_bgc, _ = run_scene(mod, sc)
        err = max(float(np.max(np.abs(out[a] - res.y[a]))) for a in ANGLES)
        say("## Against a hand-written numpy model (tests/reference/mech3r2s.py)")
        say()
        say("The same circle scene and tolerances; the hand-written model with solve_ivp's Radau "
            "and finite-difference Jacobians, bgc's module with its analytic one.")
        say()
        say("| | hand-written | bgc | ratio |")
        say("|---|---|---|---|")
        say(f"| rhs call, batch 1 | {r_ref * 1e6:.0f} us | {r1 * 1e6:.0f} us | "
            f"{r_ref / r1:.1f}x |")
        say(f"| circle scene, wall | {out['wall']:.2f} s | {wall_bgc:.2f} s | "
            f"{out['wall'] / wall_bgc:.1f}x |")
        say(f"| rhs calls | {out['nfev']} | {res.stats['nfev']} | |")
        say()
        say(f"The two models' angles agree within {err:.1e} rad.")
        say()
    if circle and not args.no_accuracy:
        sc, mod, res = circle
        ratio = sc.atol / sc.rtol
        tight, wall_t, _ = run_scene(mod, sc, rtol=1e-10, atol=1e-10 * ratio)
        err = max(float(np.max(np.abs(res.y[a] - tight.y[a]))) for a in ANGLES)
        p3 = float(np.max(np.abs(res.y["p3"] - tight.y["p3"])))
        say("## Circle: accuracy at the scene's settings")
        say()
        say(f"Against the same scene at rtol 1e-10 (atol {1e-10 * ratio:g}, {wall_t:.1f} s): "
            f"largest angle difference {err:.2e} rad, largest p3 difference {p3:.2e} m.")
        say()
    Path(args.out).write_text("\n".join(L) + "\n", encoding="utf-8")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
