"""What the 3R2S's penalty couplings cost: joint stiffness k_t against constraint violation
and wall time.

    python bench/stiffness_sweep.py [--values 1e5:1e10] [--t-end 6] [--rtol 1e-6]
                                    [--atol 5e-7] [--gap-atol 1e-3] [--tight-rtol 1e-8]
                                    [--no-uniform] [--check 1e6,1e8,1e10] [--check-t-end 6]
                                    [--budget 600] [--repeats 1] [--out docs/accuracy]

The joints of the 3R2S are not constraints but stiff springs (k_t, with dampers r_t): the
closed chain closes only up to the springs' deflections. For each k_t (half decades from
1e5 to 1e10 N/m by default) this simulates the circle scene (models/scenes/3r2s_circle.yaml,
the whole 6 s: the straight run out along X0, then the circle, during which the drive pulls
link 4 radially with 100-250 N) with Radau and the analytic Jacobian, and records

* the loop-closure error max_t | ||p3 - P4|| - l4 |: link 4 runs from P3 (the tip of link 3)
  to the fixed ball joint P4, so this is how far the closed chain opens;
* the joint separations max_t ||q(j.C)|| of J1..J5 (output `joint_gap`), and the largest;
* wall time (median of --repeats), steps, rhs and Jacobian evaluations, LU decompositions.

Tolerances (the point of the study: the violation must be measured, not guessed):
rtol 1e-6; atol 5e-7 (the scene's) for every state except the joint-coupling deflections
q(j1.C)..q(j5.C), whose atol is --gap-atol * W / k_t, W = sum(m_i) g = 21.6 N: 1e-3 of the
deflection of a joint that carries the whole weight. With one scalar atol of 5e-7 the gaps
(1e-6 m at 1e8, 1e-8 m at 1e10) lie below atol from k_t ~ 1e6 on and their error is not
controlled at all; with this per-state atol the error control always covers them. --check
recomputes a few k_t at rtol 1e-9 and 1000x smaller atols (over the whole span unless
--check-t-end) and reports
how far the sweep's maxima are from that reference. Two more series run every k_t: with
the scalar atol (unless --no-uniform), for comparison of cost and result; and at
--tight-rtol 1e-8 with every atol 100x smaller (unless --tight-rtol 0). The loop closure is
computed through the links' positions and rotation matrices, whose integration error at
rtol 1e-6 is a few 1e-9 m: from k_t ~ 3e9 on that, not the joints, sets the closure at
rtol 1e-6; the rtol 1e-8 series measures it down to 1e-10 m.

Wall times are single-threaded BLAS (OPENBLAS_NUM_THREADS=1, set below before numpy loads):
on a shared 2-core machine OpenBLAS threads make the small products inside Radau many times
slower and the timings erratic.
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import csv  # noqa: E402
import inspect  # noqa: E402
import io  # noqa: E402
import math  # noqa: E402
import re  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
GAP_STATE = re.compile(r"^j[1-5]\.C\.q\[\d\]$")


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


def sweep_values(text):
    if ":" in text:
        a, b = (float(s) for s in text.split(":"))
        ka, kb = math.log10(a), math.log10(b)
        n = int(round((kb - ka) * 2)) + 1  # half decades
        return [float(f"{v:.3g}") for v in np.logspace(ka, kb, n)]
    return [float(s) for s in text.split(",")]


class Setup:
    def __init__(self, scene_path, t_end):
        from bgc.format.scene import free_values, parse_scene
        from bgc.run.runner import compile_scene

        self.scene = parse_scene(scene_path)
        t0 = time.perf_counter()
        _, self.mod = compile_scene(self.scene)
        self.compile_time = time.perf_counter() - t0
        mod = self.mod
        if "k_t" not in mod.PARAM_DEFAULTS:
            sys.exit("the scene's module has no run-time parameter k_t")
        self.p = free_values(self.scene) or {}
        pv = {**mod.PARAM_DEFAULTS, **self.p}
        self.P4, self.l4 = ground_point(pv), float(pv["l4"])
        self.weight = float(pv["g"]) * sum(float(pv[f"m{i}"]) for i in range(1, 5))
        self.gap_rows = np.array([i for i, n in enumerate(mod.STATE_NAMES) if GAP_STATE.match(n)])
        if len(self.gap_rows) != 15:
            sys.exit("expected the 15 joint-coupling states j1..j5.C.q, found "
                     f"{len(self.gap_rows)}")
        t0s, t1s = self.scene.t_span
        self.t_span = (t0s, t1s if t_end is None else float(t_end))
        self.dt = self.scene.dt or (self.t_span[1] - self.t_span[0]) / 1000
        self.has_max_wall = "max_wall" in inspect.signature(mod.simulate).parameters

    def atol(self, k, base, gap_fraction):
        """Per-state atol: base, except gap_fraction * W / k on the joint deflections."""
        if gap_fraction is None:
            return base
        a = np.full(self.mod.N_STATES, float(base))
        a[self.gap_rows] = gap_fraction * self.weight / k
        return a

    def run(self, k, rtol, atol, t_end=None, budget=None):
        span = (self.t_span[0], self.t_span[1] if t_end is None else t_end)
        kw = {"max_wall": budget} if (self.has_max_wall and budget) else {}
        bps = tuple(b for b in self.scene.breakpoints if span[0] < b < span[1])
        t0 = time.perf_counter()
        res = self.mod.simulate(span, dt=self.dt, method="Radau", rtol=rtol, atol=atol,
                                p={**self.p, "k_t": k}, breakpoints=bps,
                                max_step=self.scene.max_step, **kw)
        wall = time.perf_counter() - t0
        y = res.y
        closure = np.abs(np.linalg.norm(np.asarray(y["p3"]) - self.P4[:, None], axis=0) - self.l4)
        gaps = np.asarray(y["joint_gap"])  # (5, nt)
        return {"wall": wall, "stats": dict(res.stats), "closure": float(np.max(closure)),
                "gaps": np.max(gaps, axis=1), "gap": float(np.max(gaps)),
                "closure_series": closure, "gap_series": gaps, "t": np.asarray(res.t)}


def measure(setup, k, rtol, atol, repeats, budget):
    """(status, message, result) with the median wall time of the repeats."""
    walls, res = [], None
    for _ in range(max(1, repeats)):
        try:
            r = setup.run(k, rtol, atol, budget=budget)
        except Exception as exc:  # noqa: BLE001 - reported in the table
            if res is not None:
                break
            kind = "budget" if "max_wall" in str(exc) else "failed"
            return kind, str(exc).splitlines()[0][:160], None
        walls.append(r["wall"])
        res = res or r
    res["wall"] = float(np.median(walls))
    return "ok", "", res


def series_of(args):
    """(label, rtol, atol of the other states, atol fraction of the gaps or None)."""
    out = [("scaled", args.rtol, args.atol, args.gap_atol)]
    if not args.no_uniform:
        out.append(("uniform", args.rtol, args.atol, None))
    if args.tight_rtol:
        f = args.tight_rtol / args.rtol
        out.append(("tight", args.tight_rtol, args.atol * f, args.gap_atol * f))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default=str(ROOT / "models" / "scenes" / "3r2s_circle.yaml"))
    ap.add_argument("--t-end", type=float, default=None, help="default: the scene's end")
    ap.add_argument("--values", default="1e5:1e10", help="k_t values: a:b (half decades) or list")
    ap.add_argument("--rtol", type=float, default=1e-6)
    ap.add_argument("--atol", type=float, default=5e-7, help="atol of the other states")
    ap.add_argument("--gap-atol", type=float, default=1e-3,
                    help="atol of the joint deflections, as a fraction of W / k_t")
    ap.add_argument("--no-uniform", action="store_true",
                    help="skip the comparison series with the scalar atol")
    ap.add_argument("--tight-rtol", type=float, default=1e-8,
                    help="rtol of the accurate series (atols scaled alike); 0: skip it")
    ap.add_argument("--check", default="1e6,1e8,1e10",
                    help="k_t values recomputed at rtol 1e-9, atols / 1000 ('' for none)")
    ap.add_argument("--check-t-end", type=float, default=None, help="default: the whole span")
    ap.add_argument("--budget", type=float, default=600.0, help="seconds per run")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--out", default=str(ROOT / "docs" / "accuracy"))
    args = ap.parse_args(argv)
    start = time.perf_counter()

    def say(msg):
        print(f"[{time.perf_counter() - start:7.1f} s] {msg}", file=sys.stderr, flush=True)

    say(f"compiling {args.scene}")
    setup = Setup(args.scene, args.t_end)
    name = Path(args.scene).stem
    values = sweep_values(args.values)
    say(f"{name}: {setup.mod.N_STATES} states, t = {setup.t_span[0]:g}..{setup.t_span[1]:g} s, "
        f"Radau rtol {args.rtol:g}; atol {args.atol:g}, joint deflections {args.gap_atol:g} W/k_t "
        f"(W = {setup.weight:.4g} N); k_t = {', '.join(f'{v:.3g}' for v in values)}")
    setup.run(1e8, 1e-3, 1e-3, t_end=setup.t_span[0] + 1e-3)  # warm up (imports)

    rows = []
    for k in values:
        for label, rtol, base, frac in series_of(args):
            status, msg, r = measure(setup, k, rtol, setup.atol(k, base, frac),
                                     args.repeats, args.budget)
            rows.append({"k": k, "series": label, "status": status, "message": msg, "r": r})
            if r is None:
                say(f"k_t = {k:.3g} ({label} atol): {status.upper()} {msg}")
            else:
                st = r["stats"]
                say(f"k_t = {k:.3g} ({label} atol): {r['wall']:.2f} s, {st.get('nsteps', 0)} steps,"
                    f" {st['nfev']} rhs; closure {r['closure']:.3e} m, largest gap "
                    f"{r['gap']:.3e} m (J{int(np.argmax(r['gaps'])) + 1})")

    checks = []
    for k in [float(v) for v in args.check.split(",") if v.strip()]:
        t_end = setup.t_span[1]
        if args.check_t_end is not None:
            t_end = min(args.check_t_end, t_end)
        a = setup.run(k, args.rtol, setup.atol(k, args.atol, args.gap_atol), t_end=t_end)
        try:
            b = setup.run(k, 1e-9, setup.atol(k, args.atol * 1e-3, args.gap_atol * 1e-3),
                          t_end=t_end, budget=args.budget)
        except Exception as exc:  # noqa: BLE001
            say(f"check k_t = {k:.3g}: the reference did not finish: {exc}")
            checks.append({"k": k, "t_end": t_end, "ok": False, "message": str(exc)[:120]})
            continue
        d = {"k": k, "t_end": t_end, "ok": True,
             "gap_rel": abs(a["gap"] / b["gap"] - 1),
             "closure_rel": abs(a["closure"] / b["closure"] - 1),
             "wall": a["wall"], "wall_ref": b["wall"],
             "gap_ref": b["gap"], "closure_ref": b["closure"]}
        checks.append(d)
        say(f"check k_t = {k:.3g} over {t_end:g} s: largest gap {a['gap']:.4e} vs reference "
            f"{b['gap']:.4e} (rel {d['gap_rel']:.1e}), closure {a['closure']:.4e} vs "
            f"{b['closure']:.4e} (rel {d['closure_rel']:.1e}); reference {b['wall']:.1f} s")

    write(setup, name, args, rows, checks, Path(args.out), say)


def write(setup, name, args, rows, checks, out, say):
    out.mkdir(parents=True, exist_ok=True)
    stem = f"{name}_stiffness_sweep"
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["k_t", "atol", "status", "message", "wall_s", "nsteps", "nfev", "njev", "nlu",
                "closure_max_m", "gap_max_m", "gap_J1_m", "gap_J2_m", "gap_J3_m", "gap_J4_m",
                "gap_J5_m"])
    for row in rows:
        r = row["r"]
        if r is None:
            w.writerow([f"{row['k']:g}", row["series"], row["status"], row["message"]] + [""] * 12)
            continue
        st = r["stats"]
        w.writerow([f"{row['k']:g}", row["series"], "ok", "", f"{r['wall']:.4g}",
                    st.get("nsteps", ""), st["nfev"], st["njev"], st["nlu"],
                    f"{r['closure']:.6e}", f"{r['gap']:.6e}"] + [f"{g:.6e}" for g in r["gaps"]])
    (out / f"{stem}.csv").write_text(buf.getvalue(), encoding="utf-8")
    png = plot(setup, args, rows, out / f"{stem}.png")

    t0, t1 = setup.t_span
    L = [f"# 3R2S: joint stiffness k_t against constraint violation and cost\n",
         f"Scene `{Path(args.scene).name}`, t = {t0:g}..{t1:g} s, Radau with the analytic "
         f"Jacobian, rtol {args.rtol:g}; atol {args.atol:g} for every state except the 15 "
         f"joint deflections q(j1.C)..q(j5.C), whose atol is {args.gap_atol:g} W/k_t "
         f"(W = sum m_i g = {setup.weight:.4g} N). Only k_t (J1..J5) varies; the dampers "
         f"stay. Wall time: one core, single-threaded BLAS, {args.repeats} run(s) per point "
         f"(median). Command: `python bench/stiffness_sweep.py`.\n",
         "closure = max_t | ||p3 - P4|| - l4 | (how far the closed chain opens at link 4); "
         "largest gap = max_t max_j ||q(j.C)|| over J1..J5 (output `joint_gap`), with the "
         "joint where it occurs.\n",
         "| k_t [N/m] | closure [m] | largest gap [m] | joint | k_t x gap [N] | wall [s] | "
         "steps | rhs | LU |" + "".join(f" {h} |" for h in extra_heads(args)),
         "|---|---|---|---|---|---|---|---|---|" + "---|" * len(extra_heads(args))]
    by = {(row["k"], row["series"]): row for row in rows}
    for k in sorted({row["k"] for row in rows}):
        row = by[(k, "scaled")]
        r = row["r"]
        if r is None:
            line = f"| {k:.3g} | **{row['status']}**: {row['message']} | | | | | | | |"
        else:
            st = r["stats"]
            j = int(np.argmax(r["gaps"])) + 1
            line = (f"| {k:.3g} | {r['closure']:.3e} | {r['gap']:.3e} | J{j} | "
                    f"{k * r['gap']:.3g} | {r['wall']:.2f} | {st.get('nsteps', '')} | "
                    f"{st['nfev']} | {st['nlu']} |")
        if not args.no_uniform:
            u = by[(k, "uniform")]
            line += (f" {u['r']['wall']:.2f} | {u['r']['closure']:.3e} |" if u["r"] is not None
                     else f" **{u['status']}** | |")
        if args.tight_rtol:
            u = by[(k, "tight")]
            line += (f" {u['r']['wall']:.2f} | {u['r']['closure']:.3e} | {u['r']['gap']:.3e} |"
                     if u["r"] is not None else f" **{u['status']}** | | |")
        L.append(line)
    if checks:
        L += ["", f"Check against a tighter solve (rtol 1e-9, every atol 1000x smaller), "
                  f"over the first {checks[0]['t_end']:g} s:", "",
              "| k_t [N/m] | largest gap, reference [m] | relative difference | closure, "
              "reference [m] | relative difference | wall, sweep / reference [s] |",
              "|---|---|---|---|---|---|"]
        for c in checks:
            if c["ok"]:
                L.append(f"| {c['k']:.3g} | {c['gap_ref']:.4e} | {c['gap_rel']:.1e} | "
                         f"{c['closure_ref']:.4e} | {c['closure_rel']:.1e} | "
                         f"{c['wall']:.1f} / {c['wall_ref']:.1f} |")
            else:
                L.append(f"| {c['k']:.3g} | did not finish: {c['message']} | | | | |")
    L.append(f"\n![stiffness sweep]({png.name})\n")
    (out / f"{stem}.md").write_text("\n".join(L), encoding="utf-8")
    print("\n".join(L[3:]))
    for f in (out / f"{stem}.csv", out / f"{stem}.md", png):
        say(f"wrote {f}")


def extra_heads(args):
    heads = []
    if not args.no_uniform:
        heads += [f"wall, scalar atol {args.atol:g} [s]", "closure, scalar atol [m]"]
    if args.tight_rtol:
        heads += [f"wall, rtol {args.tight_rtol:g} [s]", f"closure, rtol {args.tight_rtol:g} [m]",
                  f"largest gap, rtol {args.tight_rtol:g} [m]"]
    return heads


def plot(setup, args, rows, path):
    from bgc.run.plots import _mpl

    plt = _mpl()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(13, 6.8))
    a3 = a2.twinx()
    a3.grid(False)
    shrink = args.rtol / args.tight_rtol if args.tight_rtol else 1.0
    styles = {"scaled": ("o", "tab:blue",
                         f"rtol {args.rtol:g}, gaps' atol {args.gap_atol:g} W/k_t"),
              "uniform": ("s", "tab:orange", f"rtol {args.rtol:g}, scalar atol {args.atol:g}"),
              "tight": ("D", "tab:green", f"rtol {args.tight_rtol:g}, atols / {shrink:g}")}
    guide = None
    for label, (mk, col, desc) in styles.items():
        ok = [row for row in rows if row["series"] == label and row["r"] is not None]
        if not ok:
            continue
        k = np.array([row["k"] for row in ok])
        wall = np.array([row["r"]["wall"] for row in ok])
        clo = np.array([row["r"]["closure"] for row in ok])
        gap = np.array([row["r"]["gap"] for row in ok])
        a1.loglog(wall, clo, marker=mk, color=col, ls="-", label=f"loop closure, {desc}")
        a1.loglog(wall, gap, marker=mk, color=col, ls=":", alpha=0.6,
                  label=f"largest joint gap, {desc}")
        if label in ("scaled", "tight"):
            for kk, x, yv in zip(k, wall, clo):
                a1.annotate(f"{kk:.0e}", (x, yv), textcoords="offset points", xytext=(4, 3),
                            fontsize=6, color=col)
        a2.loglog(k, clo, marker=mk, color=col, ls="-", label=f"loop closure, {desc}")
        if label != "uniform":
            a2.loglog(k, gap, marker=mk, color=col, ls=":", alpha=0.6,
                      label=f"largest joint gap, {desc}")
        a3.loglog(k, wall, marker=mk, color=col, ls="--", mfc="none", alpha=0.8,
                  label=f"wall time, {desc}")
        if label == "tight":
            guide = (k, clo[0] * k[0] / k)
    if guide is not None:
        a2.loglog(*guide, "k:", lw=1, label="~ 1/k_t")
    a1.set_xlabel("wall time [s] (one core)")
    a1.set_ylabel("max constraint violation [m]")
    a1.set_title("violation against cost (labels: k_t [N/m])")
    a1.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=2)
    a2.set_xlabel("joint stiffness k_t [N/m]")
    a2.set_ylabel("max constraint violation [m] (solid, dotted)")
    a3.set_ylabel("wall time [s] (dashed, open markers)")
    h1, l1 = a2.get_legend_handles_labels()
    h2, l2 = a3.get_legend_handles_labels()
    a2.legend(h1 + h2, l1 + l2, fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.13),
              ncol=2)
    bad = [row for row in rows if row["r"] is None]
    a2.set_title("violation and wall time against k_t"
                 + (f" ({len(bad)} runs failed/over budget)" if bad else ""))
    t0, t1 = setup.t_span
    fig.suptitle(f"3R2S penalty joints, circle scene t = {t0:g}..{t1:g} s, Radau", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


if __name__ == "__main__":
    main()
