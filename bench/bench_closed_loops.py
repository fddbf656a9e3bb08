"""Closed kinematic loops (issue 24): the constraint's drift against its stabilisation, and the
rigid four-bar beside its compliant twin.

`--drift` (default): models/fourbar_rigid.yaml compiled (C backend) with
`constraints: {stabilisation: alpha}` for several alpha, with its `closure:` (the Baumgarte law
on the geometric residual) and without it (the law on the integrated violation q), integrated by Radau over 5 s and
100 s at rtol 1e-6 and 1e-10 (atol = rtol / 100); for each run the largest |q| (the integrated
violation the reaction holds at zero), the largest geometric closure error |tip - O2| from
the model's own output angles (tip = l1 u(th1) + l2 u(th2) + l3 u(th3)), the same over the
last tenth of the run (secular growth shows as a tail larger than the head), the steps taken
and the wall time of `simulate`.

`--compare`: the rigid four-bar and models/fourbar_compliant.yaml (k = 1e6, 1e7, 1e8 N/m) over
5 s, each at rtol 1e-6, 1e-8 and 1e-10: the largest angle error against the independent
reference (tests/reference/fourbar_lagrange.py, rtol 1e-12) and the wall time of `simulate`
(best of 3), side by side in one run.

`--3r2s`: the circle scene on the rigid 3R2S (models/scenes/3r2s_circle_rigid.yaml: five
rigid joints, the drive coupling compliant) and on the all-compliant model
(models/scenes/3r2s_circle.yaml), C backend, Radau at rtol 1e-6 and 1e-8 (atol = rtol / 2,
as the scenes): the largest distance of the angles from the closed-form IK of the model's own
p3 (tests/reference/ik3r2s.py), of p3 from the sphere |p3 - P4| = l4, the steps and the wall
time of the run (compiles excluded; the cache keeps them).

`--3dpins`: the crank-rocker written with spatial rods and full 3-D revolute joints
(tests/loops/fourbar_3dpins.yaml: 20 constraint components on 18 degrees of freedom, three of
them redundant) beside the planar models/fourbar_rigid.yaml, C backend, Radau over 5 s at rtol
1e-6, 1e-8 and 1e-10 (atol = rtol / 100), side by side in one run: the largest angle and rate
errors against the reference (rtol 1e-12), the largest out-of-plane coordinate or velocity of
the 3-D model, the steps and the wall time of `simulate` (best of 3); then the 3-D model once
on the numpy backend at rtol 1e-10.

    PYTHONPATH=src .venv/bin/python bench/bench_closed_loops.py [--drift] [--compare] [--3r2s]
        [--3dpins]
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT / "tests" / "reference"))

import bgc  # noqa: E402

RIGID = ROOT / "models" / "fourbar_rigid.yaml"
COMPLIANT = ROOT / "models" / "fourbar_compliant.yaml"
ALPHAS = (1e-6, 1.0, 5.0, 20.0, 100.0, 1000.0)


def _with_alpha(alpha: float, closure: bool = True) -> str:
    """The rigid four-bar at stabilisation rate alpha; without its `closure:` (the Baumgarte
    law then acts on the integrated violation q) where ``closure`` is False."""
    text = RIGID.read_text()
    if not closure:
        start = text.index("    closure:")
        end = text.index("\n", text.index("+ l3", start))
        text = text[:start] + text[end + 1:]
    return text.replace("\nparameters:", f"\nconstraints: {{stabilisation: {alpha!r}}}\n"
                        "parameters:", 1)


def _run(m, T, rtol, n=2001):
    t = np.linspace(0.0, T, n)
    t0 = time.perf_counter()
    r = m.simulate((0.0, T), t_eval=t, method="Radau", rtol=rtol, atol=rtol * 1e-2,
                   max_steps=10_000_000)
    return r, time.perf_counter() - t0


def drift() -> None:
    import fourbar_lagrange as fl

    d = fl.model_params()["d"]
    print("| law on | alpha (1/s) | T (s) | rtol | max abs(q) (m) | max closure (m) | "
          "closure, last tenth (m) | steps | wall (s) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for alpha in ALPHAS:
        for closure in (False, True):
            m = bgc.compile(_with_alpha(alpha, closure), target="c")
            qi = [k for k, s in enumerate(m.STATE_NAMES) if s.startswith("pivot2.q")]
            for T in (5.0, 100.0):
                for rtol in (1e-6, 1e-10):
                    r, wall = _run(m, T, rtol)
                    q = np.abs(np.asarray(r.x)[qi]).max()
                    gap = np.hypot(r.y["tip"][0] - d, r.y["tip"][1])
                    tail = gap[int(0.9 * len(gap)):].max()
                    print(f"| {'closure' if closure else 'q'} | {alpha:g} | {T:g} | {rtol:g} | "
                          f"{q:.2e} | {gap.max():.2e} | {tail:.2e} | {r.stats['nsteps']} | "
                          f"{wall:.3f} |", flush=True)


def compare() -> None:
    import fourbar_lagrange as fl

    T = 5.0
    t = np.linspace(0.0, T, 501)
    ref = fl.simulate(t)
    rigid = bgc.compile(str(RIGID), target="c")
    comp = bgc.compile(str(COMPLIANT), target="c")
    print("| model | rtol | max angle error (rad) | steps | wall (s), best of 3 |")
    print("|---|---|---|---|---|")
    cases = [("rigid (constraint)", rigid, None)] + [
        (f"compliant, k = {k:g} N/m", comp, {"k": k}) for k in (1e6, 1e7, 1e8)]
    for rtol in (1e-6, 1e-8, 1e-10):
        for name, m, p in cases:
            best, r = np.inf, None
            for _ in range(3):
                t0 = time.perf_counter()
                r = m.simulate((0.0, T), t_eval=t, method="Radau", rtol=rtol,
                               atol=rtol * 1e-2, p=p, max_steps=10_000_000)
                best = min(best, time.perf_counter() - t0)
            err = max(np.abs(r.y[n] - ref[n]).max() for n in ("th1", "th2", "th3"))
            print(f"| {name} | {rtol:g} | {err:.2e} | {r.stats['nsteps']} | {best:.4f} |",
                  flush=True)


def three_r_two_s() -> None:
    import ik3r2s

    from bgc.run.runner import run_scene

    print("| model | rtol | max angle from IK (rad) | max sphere residual (m) | steps | run (s) |")
    print("|---|---|---|---|---|---|")
    for rtol in (1e-6, 1e-8):
        for name, scene in (("rigid joints", "3r2s_circle_rigid.yaml"),
                            ("compliant joints", "3r2s_circle.yaml")):
            res = run_scene(ROOT / "models" / "scenes" / scene, backend="c", rtol=rtol,
                            atol=rtol / 2)
            p3 = np.asarray(res.y["p3"])
            th = ik3r2s.ik(p3)
            ang = max(np.abs(np.angle(np.exp(1j * (th[i] - np.asarray(res.y[f"theta{i + 1}"])))
                                      )).max() for i in range(4))
            sph = np.abs(np.linalg.norm(p3 - ik3r2s.P4[:, None], axis=0) - ik3r2s.L[3]).max()
            print(f"| {name} | {rtol:g} | {ang:.2e} | {sph:.2e} | {res.stats.get('nsteps')} | "
                  f"{res.run_time:.3f} |", flush=True)


def three_d_pins() -> None:
    import fourbar_lagrange as fl

    T = 5.0
    t = np.linspace(0.0, T, 501)
    ref = fl.simulate(t)
    pins = ROOT / "tests" / "loops" / "fourbar_3dpins.yaml"
    cases = [("planar (fourbar_rigid)", "c", bgc.compile(str(RIGID), target="c")),
             ("3-D pins and locks", "c", bgc.compile(str(pins), target="c"))]
    print("| model | backend | rtol | max angle error (rad) | max rate error (rad/s) | "
          "max out of plane | steps | wall (s) |")
    print("|---|---|---|---|---|---|---|---|")
    runs = [(rtol, case, 3) for rtol in (1e-6, 1e-8, 1e-10) for case in cases]
    runs.append((1e-10, ("3-D pins and locks", "numpy", bgc.compile(str(pins))), 1))
    for rtol, (name, backend, m), tries in runs:
        best, r = np.inf, None
        for _ in range(tries):
            t0 = time.perf_counter()
            r = m.simulate((0.0, T), t_eval=t, method="Radau", rtol=rtol, atol=rtol * 1e-2,
                           max_steps=10_000_000)
            best = min(best, time.perf_counter() - t0)
        ang = max(np.abs(np.unwrap(np.asarray(r.y[f"th{i}"])) - ref[f"th{i}"]).max()
                  for i in (1, 2, 3))
        rate = max(np.abs(np.asarray(r.y[f"w{i}"]) - ref[f"w{i}"]).max() for i in (1, 2, 3))
        out = (max(np.abs(r.y["out_pos"]).max(), np.abs(r.y["out_vel"]).max())
               if "out_pos" in r.y else float("nan"))
        print(f"| {name} | {backend} | {rtol:g} | {ang:.2e} | {rate:.2e} | {out:.1e} | "
              f"{r.stats['nsteps']} | {best:.3f} |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--drift", action="store_true")
    ap.add_argument("--compare", action="store_true")
    ap.add_argument("--3r2s", dest="r3r2s", action="store_true")
    ap.add_argument("--3dpins", dest="pins", action="store_true")
    a = ap.parse_args()
    if a.pins:
        three_d_pins()
    if a.compare:
        compare()
    if a.r3r2s:
        three_r_two_s()
    if a.drift or not (a.compare or a.r3r2s or a.pins):
        drift()


if __name__ == "__main__":
    main()
