"""Energy drift per period of scipy's integrators and bgc's Rodas4 on a lossless model: the
frictionless pendulum (models/pendulum.yaml) released at theta0 = 2 rad.

    python bench/energy_drift.py [--periods 10000] [--rtol 1e-8] [--atol 1e-8]
                                 [--methods RK45,DOP853,Radau,BDF,LSODA,Rodas4] [--budget 2000]
                                 [--out docs/accuracy]

Nothing dissipates, so the energy E(t) = E0 = m g l (1 - cos theta0) exactly; the relative
error (E - E0) / E0 at the end of every period (T = 4 K(sin^2(theta0/2)) sqrt(l/g), closed
form) is integration error. For each method this runs `--periods` periods in one simulate
call (a short calibration run first: if the whole run would take longer than `--budget`
seconds, it runs as many periods as fit, and says so) and reports the drift per period (the
least-squares slope of the relative error against the period count), the error after the
last period, the largest error, rhs calls, steps and wall time. Writes
<out>/pendulum_energy_drift.{md,csv,png}.

Wall times are single-threaded BLAS (OPENBLAS_NUM_THREADS=1, set below before numpy loads):
on a shared 2-core machine OpenBLAS threads make numpy's small products many times slower.
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import csv  # noqa: E402
import io  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
METHODS = ("RK45", "DOP853", "Radau", "BDF", "LSODA", "Rodas4")


def load_pendulum():
    from bgc.backends.load import load_module
    from bgc.run.driver import compile_file

    c = compile_file(ROOT / "models" / "pendulum.yaml")
    return load_module(c.source, "pendulum_bench")


def closed_forms(mod):
    from scipy.special import ellipk

    P = mod.PARAM_DEFAULTS
    T = 4.0 * ellipk(math.sin(P["theta0"] / 2) ** 2) * math.sqrt(P["l"] / P["g"])
    E0 = P["m"] * P["g"] * P["l"] * (1.0 - math.cos(P["theta0"]))
    return T, E0


def run(mod, method, periods, T, E0, rtol, atol):
    k = np.arange(periods + 1)
    t0 = time.perf_counter()
    res = mod.simulate((0.0, periods * T), t_eval=k * T, method=method, rtol=rtol, atol=atol)
    wall = time.perf_counter() - t0
    rel = (np.asarray(res.y["energy"]) - E0) / E0
    return {"method": method, "periods": periods, "wall": wall, "rel": rel,
            "slope": float(np.polyfit(k, rel, 1)[0]) if periods > 1 else float(rel[-1]),
            "final": float(rel[-1]), "max": float(np.max(np.abs(rel))),
            "nfev": int(res.stats["nfev"]), "nsteps": int(res.stats.get("nsteps", 0)),
            "theta_end": float(res.y["theta"][-1])}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--periods", type=int, default=10_000)
    ap.add_argument("--rtol", type=float, default=1e-8)
    ap.add_argument("--atol", type=float, default=1e-8)
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--budget", type=float, default=2000.0, help="seconds per method")
    ap.add_argument("--out", default=str(ROOT / "docs" / "accuracy"))
    args = ap.parse_args(argv)
    start = time.perf_counter()

    def say(msg):
        print(f"[{time.perf_counter() - start:7.1f} s] {msg}", file=sys.stderr, flush=True)

    mod = load_pendulum()
    T, E0 = closed_forms(mod)
    say(f"pendulum: theta0 = {mod.PARAM_DEFAULTS['theta0']:g} rad, T = {T:.9f} s, "
        f"E0 = {E0:.9f} J; rtol {args.rtol:g}, atol {args.atol:g}, {args.periods} periods")
    results = []
    for method in args.methods.split(","):
        cal = run(mod, method, 50, T, E0, args.rtol, args.atol)
        per = cal["wall"] / 50
        n = args.periods
        if per * n > args.budget:
            n = max(20, int(args.budget / per) // 10 * 10)
            say(f"{method}: {per * 1e3:.1f} ms per period: {args.periods} periods would take "
                f"~{per * args.periods:.0f} s > budget {args.budget:g} s: running {n}")
        else:
            say(f"{method}: {per * 1e3:.1f} ms per period: running {n} periods "
                f"(~{per * n:.0f} s)")
        r = run(mod, method, n, T, E0, args.rtol, args.atol)
        say(f"{method}: {r['periods']} periods in {r['wall']:.1f} s, {r['nsteps']} steps, "
            f"{r['nfev']} rhs; drift per period {r['slope']:.3e}, after the last period "
            f"{r['final']:.3e}, largest {r['max']:.3e}")
        results.append(r)

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["method", "rtol", "atol", "periods", "drift_per_period", "rel_error_end",
                "rel_error_max", "extrapolated_10000", "nsteps", "nfev", "wall_s"])
    for r in results:
        w.writerow([r["method"], f"{args.rtol:g}", f"{args.atol:g}", r["periods"],
                    f"{r['slope']:.4e}", f"{r['final']:.4e}", f"{r['max']:.4e}",
                    f"{r['slope'] * 1e4:.3e}", r["nsteps"], r["nfev"], f"{r['wall']:.2f}"])
    (out / "pendulum_energy_drift.csv").write_text(buf.getvalue(), encoding="utf-8")
    png = plot(results, args, T, out / "pendulum_energy_drift.png")
    lines = [
        "# Energy drift of scipy's integrators and bgc's Rodas4 on a lossless model\n",
        f"The frictionless pendulum (`models/pendulum.yaml`, theta0 = "
        f"{mod.PARAM_DEFAULTS['theta0']:g} rad, period T = {T:.6f} s), rtol "
        f"{args.rtol:g}, atol {args.atol:g}, relative energy error (E - E0)/E0 sampled at "
        f"the end of every period; drift per period = its least-squares slope. Command: "
        f"`python bench/energy_drift.py` (single-threaded BLAS).\n",
        "| method | periods run | drift per period | error after the last period | "
        "largest error | over 1e4 periods (extrapolated) | steps | rhs calls | wall [s] |",
        "|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        extra = "" if r["periods"] == args.periods else " (budget)"
        lines.append(f"| {r['method']} | {r['periods']}{extra} | {r['slope']:.2e} | "
                     f"{r['final']:.2e} | {r['max']:.2e} | {r['slope'] * 1e4:.1e} | "
                     f"{r['nsteps']} | {r['nfev']} | {r['wall']:.1f} |")
    lines.append(f"\n![energy drift]({png.name})\n")
    (out / "pendulum_energy_drift.md").write_text("\n".join(lines), encoding="utf-8")
    print("\n".join(lines[2:-1]))
    for f in ("csv", "md", "png"):
        say(f"wrote {out / f'pendulum_energy_drift.{f}'}")


def plot(results, args, T, path):
    from bgc.run.plots import _mpl

    plt = _mpl()
    fig, ax = plt.subplots(figsize=(8, 5))
    for r in results:
        k = np.arange(1, r["periods"] + 1)
        err = np.abs(r["rel"][1:])
        ax.loglog(k, np.maximum(err, 1e-17), lw=1.2,
                  label=f"{r['method']}: {r['slope']:+.1e} per period")
    ax.axhline(1e-3, color="k", ls=":", lw=1, label="bound 1e-3")
    ax.set_xlabel(f"periods (T = {T:.4f} s)")
    ax.set_ylabel("|E - E0| / E0")
    ax.set_title(f"Pendulum, lossless: energy drift at rtol {args.rtol:g}, atol {args.atol:g}")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


if __name__ == "__main__":
    main()
