"""Beyond the paper: the 3R2S with rigid joints where bgc can eliminate them.

The paper joins every link through stiff couplings (k_t = 1e8 N/m at J1..J5, C || R). Here
the translational couplings J1..J4 are rigid (the links' translational inertias fall into
derivative causality and bgc eliminates them: a 12-unknown linear system per call, solved
numerically in the generated code); the loop stays closed by the compliant coupling at P4
(J5), the drive coupling stays compliant, and so do the rotational couplings r1..r3 (see
below). Both models run the circle scene's signal at the scene's tolerances; the table gives
time and the largest differences of the joint angles and of P3 from the all-compliant model.

What stopped rigid revolute joints: the rotational coupling locks two of the three components
of the relative angular velocity through a 2x3 MTF; the third (the rotation about the axis)
has no storage element of its own (the link's inertia is a 3x3 tensor on its whole angular
velocity), so one of the two angular-velocity multibonds is only partly determined. bgc says
so (`bgc check` on the variant with `lock: {type: Sf, flow: "[0, 0]"}` in place of the
coupling's C || R names the multibond); eliminating it needs joint coordinates (a revolute
joint as a scalar relative rate with a 3x1 MTF along the axis, and the distal link's rotational
inertia in derivative causality through that axis), which this study did not do.

    .venv/bin/python bench/bench_3r2s_rigid.py [--c]
"""
from __future__ import annotations

import os
import sys
import time
from pathlib import Path

# one BLAS thread, as the tests do: the small dense LUs of the implicit methods only contend
# with other processes on a shared machine
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "src"))

from bgc.backends.load import load_module  # noqa: E402
from bgc.format.parse import parse_file, parse_text  # noqa: E402
from bgc.format.scene import apply_scene, parse_scene
from bgc.run.driver import compile_model  # noqa: E402


def rigid_translational(text: str) -> str:
    """models/3r2s.yaml with the couplings j1..j4 replaced by rigid connections."""
    t = text.replace("name: mech3r2s", "name: mech3r2s_rigid_t")
    for a, j, d in [("ground_v1", "j1", "link1.Q"), ("link1.P", "j2", "link2.Q"),
                    ("link2.P", "j3", "link3.Q"), ("link3.P", "j4", "link4.Q")]:
        old = f"  - {{from: {a}, to: {j}.a, n: 3}}\n  - {{from: {j}.b, to: {d}, n: 3}}\n"
        assert old in t, old
        t = t.replace(old, f"  - {{from: {a}, to: {d}, n: 3}}\n")
        t = t.replace(f"  {j}: {{type: tcoupling", f"  #{j}: {{type: tcoupling")
        t = t.replace(f"power({j}.R) + ", "").replace(f"dot(q({j}.C), e({j}.C)) + ", "")
        t = t.replace(f"dot(q({j}.C), e({j}.C))\n       + ", "")
    t = t.replace('joint_gap: "[norm(q(j1.C)), norm(q(j2.C)), norm(q(j3.C)), norm(q(j4.C)), '
                  'norm(q(j5.C))]"', 'joint_gap: "norm(q(j5.C))"')
    return t


def main():
    import argparse

    ap = argparse.ArgumentParser()
    ap.add_argument("--c", action="store_true",
                    help="also run both models on the C backend (numeric solves in C)")
    args = ap.parse_args()
    scene = parse_scene(ROOT / "models" / "scenes" / "3r2s_circle.yaml")
    text = (ROOT / "models" / "3r2s.yaml").read_text()
    models = {"all compliant (paper)": apply_scene(parse_file(ROOT / "models" / "3r2s.yaml"),
                                                   scene),
              "rigid J1..J4": apply_scene(parse_text(rigid_translational(text),
                                                     str(ROOT / "models" / "3r2s_rt.yaml")),
                                          scene)}
    res = {}
    mods = {}
    for label, m in models.items():
        t0 = time.perf_counter()
        c = compile_model(m)
        mods[(label, "numpy")] = (load_module(c.source, c.model.name + "_bench"), c,
                                  time.perf_counter() - t0)
        if args.c:
            from bgc.backends import load as backends

            t1 = time.perf_counter()
            _, cm = backends.load(c.model.name + "_bench_c", "c", None, lambda c=c: c, None)
            mods[(label, "c")] = (cm, c, time.perf_counter() - t1)
    for (label, backend), (mod, c, tc) in mods.items():
        for rtol, atol in ((scene.rtol, scene.atol), (1e-8, 1e-9)):
            t0 = time.perf_counter()
            r = mod.simulate(scene.t_span, dt=scene.dt, method=scene.method, rtol=rtol,
                             atol=atol, breakpoints=scene.breakpoints)
            res[(label, backend, rtol)] = (r, tc, time.perf_counter() - t0,
                                           len(mod.STATE_NAMES))
    ref_key = ("all compliant (paper)", "numpy", 1e-8)
    base = res[ref_key][0]
    print(f"circle scene, {scene.method}; differences from the all-compliant model (numpy) at "
          "rtol 1e-8 (atol 1e-9); compile: symbolic for numpy, the C build for c\n")
    print("| model | backend | states | rtol | compile [s] | simulate [s] | rhs calls | "
          "max angle diff [rad] | max P3 diff [m] |")
    print("|---|---|---|---|---|---|---|---|---|")
    for (label, backend, rtol), (r, tc, ts, ns) in res.items():
        da = max(np.abs(r.y[f"theta{i}"] - base.y[f"theta{i}"]).max() for i in range(1, 5))
        dp = np.abs(r.y["p3"] - base.y["p3"]).max()
        print(f"| {label} | {backend} | {ns} | {rtol:g} | {tc:.1f} | {ts:.2f} | "
              f"{r.stats['nfev']} | {da:.2e} | {dp:.2e} |")
    print()
    print("notes:", *mods[("rigid J1..J4", "numpy")][1].equations.loops, sep="\n  ")


if __name__ == "__main__":
    main()
