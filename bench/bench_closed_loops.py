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

`--watch`: the watch of dropped components (bgc.run.watch), numbers only (no timing):
tests/loops/parallelogram_slider.yaml (numpy and C), Radau at rtol 1e-9 over 2 s, its dropped
O1.q[1]'s velocity residual against -l cos(th1) w1 from the run's own crank (relative to its
largest value), O1.q[1] against -l (1 + sin th1), and the warning; the largest dropped
residuals of tests/loops/parallelogram.yaml and tests/loops/fourbar_3dpins.yaml.

`--fmu3d`: tests/loops/fourbar_3dpins.yaml exported as an FMU (both kinds), FMPy's validation,
and its angles under FMPy (Model Exchange, Co-Simulation; relative tolerance 1e-9, 2 s)
against the C backend's run (Radau, rtol 1e-11).

    PYTHONPATH=src .venv/bin/python bench/bench_closed_loops.py [--drift] [--compare] [--3r2s]
        [--3dpins] [--watch] [--fmu3d]
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


def watch() -> None:
    import warnings

    import yaml

    from bgc.run.watch import dropped_residuals

    loops = ROOT / "tests" / "loops"
    slider = loops / "parallelogram_slider.yaml"
    pv = {k: v["value"] for k, v in yaml.safe_load(slider.read_text())["parameters"].items()}
    l, m1 = pv["l"], pv["m1"]
    te = np.linspace(0.0, 2.0, 201)

    def run(m):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            r = m.simulate((0.0, 2.0), t_eval=te, method="Radau", rtol=1e-9, atol=1e-11)
        return r, [str(w.message) for w in caught]

    for target in ("numpy", "c"):
        m = bgc.compile(str(slider), target=target)
        r, said = run(m)
        names, res = dropped_residuals(m.module, r.t, r.x)
        n = list(m.module.STATE_NAMES)
        th1 = r.x[n.index("crank1.th")]
        w1 = r.x[n.index("crank1.Ir.p")] / (m1 * l ** 2 / 12)
        want = -l * np.cos(th1) * w1
        got = res[:, names.index("O1.q[1]")]
        print(f"slider {target}: dropped {names}, residual vs -l cos(th1) w1: "
              f"{np.abs(got - want).max() / np.abs(want).max():.2e} of {np.abs(want).max():.3g}"
              f"; O1.q[1] vs -l (1 + sin th1): "
              f"{np.abs(r.x[n.index('O1.q[1]')] + l * (1 + np.sin(th1))).max():.2e} m")
        print(f"  {said}")
    for name, target in (("parallelogram.yaml", "numpy"), ("fourbar_3dpins.yaml", "c")):
        m = bgc.compile(str(loops / name), target=target)
        r, said = run(m)
        names, res = dropped_residuals(m.module, r.t, r.x)
        print(f"{name}: dropped {names}, largest residual {np.abs(res).max():.2e}, "
              f"warnings {said}")


def fmu3d() -> None:
    import tempfile

    import fmpy
    from fmpy.validation import validate_fmu

    from bgc.run.fmu import export_fmu

    model = ROOT / "tests" / "loops" / "fourbar_3dpins.yaml"
    te = np.linspace(0.0, 2.0, 201)
    ref = bgc.compile(str(model), target="c").simulate((0.0, 2.0), t_eval=te, method="Radau",
                                                       rtol=1e-11, atol=1e-13)
    with tempfile.TemporaryDirectory() as d:
        fmu = export_fmu(model, Path(d) / "fourbar_3dpins.fmu", kind="both")
        print(f"validation: {validate_fmu(str(fmu))}")
        for kind in ("ModelExchange", "CoSimulation"):
            r = fmpy.simulate_fmu(str(fmu), fmi_type=kind, stop_time=2.0, output_interval=0.01,
                                  relative_tolerance=1e-9, output=["th1", "th2", "th3"])
            errs = [np.abs(np.unwrap(np.asarray(r[f"th{i}"]))
                           - np.unwrap(np.asarray(ref.y[f"th{i}"]))).max() for i in (1, 2, 3)]
            print(f"{kind}: th1..th3 within " + ", ".join(f"{e:.2e}" for e in errs) + " rad")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--drift", action="store_true")
    ap.add_argument("--compare", action="store_true")
    ap.add_argument("--3r2s", dest="r3r2s", action="store_true")
    ap.add_argument("--3dpins", dest="pins", action="store_true")
    ap.add_argument("--watch", action="store_true")
    ap.add_argument("--fmu3d", action="store_true")
    a = ap.parse_args()
    if a.watch:
        watch()
    if a.fmu3d:
        fmu3d()
    if a.pins:
        three_d_pins()
    if a.compare:
        compare()
    if a.r3r2s:
        three_r_two_s()
    if a.drift or not (a.compare or a.r3r2s or a.pins or a.watch or a.fmu3d):
        drift()


if __name__ == "__main__":
    main()
