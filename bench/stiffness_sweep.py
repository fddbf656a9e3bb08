"""What the 3R2S's penalty couplings cost: joint stiffness k_t against constraint violation
and wall time.

    python bench/stiffness_sweep.py [--t-end 2] [--values 1e5:1e10] [--rtol 1e-6]
                                    [--atol 1e-12] [--budget 120] [--out docs/accuracy]

The joints of the 3R2S are not constraints but stiff springs (k_t, with dampers r_t): the
mechanism closes only up to the springs' deflection. For each k_t this simulates the scene
(default: the first 2 s of the circle scene, P3's straight run out along X0, with Radau and
the analytic Jacobian) and records

* the loop-closure error max_t | ||p3 - P4|| - l4 |: link 4 runs from P3 (the tip of link 3)
  to the fixed ball joint P4, so this is how far the closed chain opens;
* the largest joint gap max_t max_j ||q(j.C)|| (output `joint_gap`, J1..J5);
* wall time, rhs and Jacobian evaluations.

atol must stay below the gaps it is asked to resolve (about 20 N / k_t): hence atol 1e-12
by default rather than the scene's 1e-9.
"""
from __future__ import annotations

import argparse
import csv
import io
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def ground_point(pv: dict) -> np.ndarray:
    """P4, the fixed end of link 4, from the parameters (as in models/3r2s.yaml)."""
    c, s = math.cos(pv["th1"]), math.sin(pv["th1"])
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    phi2 = pv["th2"]
    phi3 = phi2 + pv["th3"]
    phi4 = phi3 + pv["th4"]

    def along(phi):
        return Rz @ np.array([math.cos(phi), 0.0, math.sin(phi)])

    P3 = Rz @ np.array([pv["l1"], 0.0, 0.0]) + pv["l2"] * along(phi2) + pv["l3"] * along(phi3)
    return P3 + pv["l4"] * along(phi4)


def violation_3r2s(setup, p, res) -> dict:
    pv = {**setup.module.PARAM_DEFAULTS, **(p or {})}
    P4 = ground_point(pv)
    p3 = np.asarray(res.y["p3"])  # (3, nt)
    closure = np.abs(np.linalg.norm(p3 - P4[:, None], axis=0) - pv["l4"])
    gaps = np.asarray(res.y["joint_gap"])  # (5, nt)
    return {"closure": float(np.max(closure)), "joint_gap": float(np.max(gaps)),
            "closure_t0": float(closure[0])}


def sweep_values(text):
    if ":" in text:
        a, b = (float(s) for s in text.split(":"))
        ka, kb = math.log10(a), math.log10(b)
        n = int(round((kb - ka) * 2)) + 1  # half decades
        return list(np.logspace(ka, kb, n))
    return [float(s) for s in text.split(",")]


def main(argv=None):
    from bgc.accuracy import _progress, _warm_up, _write, param_sweep, prepare

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default=str(ROOT / "models" / "scenes" / "3r2s_circle.yaml"))
    ap.add_argument("--t-end", type=float, default=2.0)
    ap.add_argument("--values", default="1e5:1e10", help="k_t values: a:b (half decades) or list")
    ap.add_argument("--method", default="Radau")
    ap.add_argument("--rtol", type=float, default=1e-6)
    ap.add_argument("--atol", type=float, default=1e-12)
    ap.add_argument("--budget", type=float, default=120.0)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--out", default=str(ROOT / "docs" / "accuracy"))
    args = ap.parse_args(argv)
    say = _progress(False)
    say(f"compiling {args.scene}")
    setup = prepare(args.scene, t_end=args.t_end)
    if "k_t" not in setup.module.PARAM_DEFAULTS:
        sys.exit("the scene's module has no run-time parameter k_t")
    _warm_up(setup)
    values = sweep_values(args.values)
    say(f"{setup.name}: t = {setup.t_span[0]:g}..{setup.t_span[1]:g} s, {args.method} rtol "
        f"{args.rtol:g} atol {args.atol:g}; k_t = {', '.join(f'{v:.3g}' for v in values)}")
    pts = param_sweep(setup, "k_t", values, violation_3r2s, args.method, args.rtol, args.atol,
                      args.budget, args.repeats, say)
    out = Path(args.out)
    stem = f"{setup.name}_stiffness_sweep"
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["k_t", "status", "message", "wall_s", "nfev", "njev", "nlu",
                "closure_max_m", "joint_gap_max_m", "closure_t0_m"])
    for p in pts:
        m = p.metrics
        w.writerow([f"{p.value:g}", p.status, p.message, f"{p.wall:.6g}", p.nfev, p.njev,
                    p.nlu, f"{m.get('closure', math.nan):.6e}",
                    f"{m.get('joint_gap', math.nan):.6e}", f"{m.get('closure_t0', math.nan):.3e}"])
    _write(out / f"{stem}.csv", buf.getvalue())
    png = plot(pts, setup, args, out / f"{stem}.png")
    L = [f"# 3R2S: joint stiffness k_t against constraint violation and cost\n",
         f"Scene `{Path(args.scene).name}`, t = {setup.t_span[0]:g}..{setup.t_span[1]:g} s "
         f"(of the scene's {setup.scene.t_span[1]:g} s: P3's straight run out along X0), "
         f"{args.method}, rtol {args.rtol:g}, atol {args.atol:g}, analytic Jacobian, "
         f"{args.repeats} run(s) per point; only k_t (J1..J5) varies, the dampers "
         f"r_t = {setup.module.PARAM_DEFAULTS['r_t']:g} N s/m stay.\n",
         "closure = max_t | ||p3 - P4|| - l4 | (how far the closed chain opens); joint gap = "
         "max_t max_j ||q(j.C)|| over J1..J5 (output `joint_gap`).\n",
         "| k_t [N/m] | status | closure [m] | joint gap [m] | wall [s] | rhs | Jac | LU |",
         "|---|---|---|---|---|---|---|---|"]
    for p in pts:
        if p.status == "ok":
            L.append(f"| {p.value:.3g} | ok | {p.metrics['closure']:.2e} | "
                     f"{p.metrics['joint_gap']:.2e} | {p.wall:.2f} | {p.nfev} | {p.njev} | "
                     f"{p.nlu} |")
        else:
            L.append(f"| {p.value:.3g} | **{p.status}** | {p.message} | | | | | |")
    L.append(f"\n![stiffness sweep]({png.name})\n")
    _write(out / f"{stem}.md", "\n".join(L))
    for f in (out / f"{stem}.csv", out / f"{stem}.md", png):
        say(f"wrote {f}")


def plot(pts, setup, args, path):
    from bgc.plots import _mpl

    plt = _mpl()
    ok = [p for p in pts if p.status == "ok"]
    k = np.array([p.value for p in ok])
    wall = np.array([p.wall for p in ok])
    clo = np.array([p.metrics["closure"] for p in ok])
    gap = np.array([p.metrics["joint_gap"] for p in ok])
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.4))
    a1.loglog(wall, clo, "o-", label="loop closure | ||p3 - P4|| - l4 |")
    a1.loglog(wall, gap, "s--", label="largest joint gap")
    for kk, x, y in zip(k, wall, clo):
        a1.annotate(f"{kk:.0e}", (x, y), textcoords="offset points", xytext=(4, 3), fontsize=7)
    a1.set_xlabel("wall time [s]")
    a1.set_ylabel("max constraint violation [m]")
    a1.set_title("violation against cost (labels: k_t [N/m])")
    a1.legend(fontsize=8)
    a2.loglog(k, clo, "o-", label="loop closure")
    a2.loglog(k, gap, "s--", label="largest joint gap")
    if len(k):
        a2.loglog(k, gap[0] * k[0] / k, "k:", lw=1, label="~ 1/k_t")
    a2.set_xlabel("k_t [N/m]")
    a2.set_ylabel("max constraint violation [m]")
    a3 = a2.twinx()
    a3.loglog(k, wall, "^-", color="tab:red", label="wall time")
    a3.set_ylabel("wall time [s]", color="tab:red")
    a3.grid(False)
    h1, l1 = a2.get_legend_handles_labels()
    h2, l2 = a3.get_legend_handles_labels()
    a2.legend(h1 + h2, l1 + l2, fontsize=8, loc="upper center")
    bad = [p for p in pts if p.status != "ok"]
    extra = f"; {len(bad)} over budget/failed" if bad else ""
    a2.set_title(f"violation and wall time against k_t{extra}")
    fig.suptitle(f"3R2S penalty joints: t = {setup.t_span[0]:g}..{setup.t_span[1]:g} s, "
                 f"{args.method} rtol {args.rtol:g} atol {args.atol:g}", fontsize=10)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


if __name__ == "__main__":
    main()
