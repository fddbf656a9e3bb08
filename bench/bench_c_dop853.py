"""DOP853 in C against the same method through the Python step loop (issue 27).

Both runs use the C backend's compiled rhs; only the step loop differs: the C runtime's
DOP853 (templates/c/runtime/bgc_dop853.c, one call per run) against the numpy module's step
loop with scipy's DOP853 (``_np_simulate``, what `--backend c --method DOP853` ran before).
Models: non-stiff rigid chains of n rods (bench/planar_chain.py: derivative causality
eliminated, lightly damped joints), swinging 10 s from their start angles under a torque at
the pivot, at rtol 1e-9.
And the heavy symmetric top (models/top.yaml, scene top_precession: 12 states, spinning at
300 rad/s, 5 s), over its scene's span at rtol 1e-9, atol 1e-12.
Side by side in one run, best of 3 each; the results agree (max state difference reported).
The load average (os.getloadavg) is recorded beside the numbers.

    python bench/bench_c_dop853.py            # writes bench/RESULTS_c_dop853.md
"""
from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT / "bench"))

from planar_chain import chain_yaml  # noqa: E402

from bgc.backends import load as backends  # noqa: E402
from bgc.format.parse import parse_file, parse_text  # noqa: E402
from bgc.run.driver import compile_model  # noqa: E402


def best(fn, rounds=3):
    out, ts = None, []
    for _ in range(rounds):
        t0 = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t0)
    return min(ts), out


def top_row():
    """The heavy top over its scene's 5 s: (states, rhs C, rhs Python, t C, t Python, speed-up,
    max state difference)."""
    c = compile_model(parse_file(ROOT / "models" / "top.yaml"))
    _, mod = backends.load("top_dop", "c", None, lambda: c, None)
    kw = dict(method="DOP853", rtol=1e-9, atol=1e-12, dt=0.01)
    tc, rc = best(lambda: mod.simulate((0.0, 5.0), **kw))
    tp, rp = best(lambda: mod._np_simulate((0.0, 5.0), **kw))
    diff = float(np.max(np.abs(rc.x - rp.x)))
    return (mod.N_STATES, rc.stats["nfev"], rp.stats["nfev"], tc, tp, tp / tc, diff)


def main():
    load0 = os.getloadavg()
    rows = []
    for n in (2, 3, 5, 8):
        text = chain_yaml(n)
        with tempfile.TemporaryDirectory() as d:
            f = Path(d) / f"chain{n}.yaml"
            f.write_text(text)
            c = compile_model(parse_text(text, str(f)))
        _, mod = backends.load(f"chain{n}_dop", "c", None, lambda: c, None)
        kw = dict(method="DOP853", rtol=1e-9, atol=1e-12, dt=0.01)
        tc, rc = best(lambda: mod.simulate((0.0, 10.0), **kw))
        tp, rp = best(lambda: mod._np_simulate((0.0, 10.0), **kw))
        diff = float(np.max(np.abs(rc.x - rp.x)))
        rows.append((n, mod.N_STATES, rc.stats["nfev"], rp.stats["nfev"], tc, tp, tp / tc, diff))
        print(rows[-1], flush=True)
    lines = ["# DOP853 in C against the Python step loop", "",
             "`python bench/bench_c_dop853.py` (one run, side by side, best of 3; both with the "
             "C backend's compiled rhs). Rigid n-rod chains (bench/planar_chain.py), 10 s, rtol 1e-9, "
             "atol 1e-12.", "",
             "| rods | states | rhs calls C | rhs calls Python loop | C DOP853 [s] | "
             "Python loop [s] | speed-up | max state difference |",
             "|---|---|---|---|---|---|---|---|"]
    lines += [f"| {n} | {ns} | {fc} | {fp} | {tc:.4f} | {tp:.3f} | {s:.1f}x | {d:.1e} |"
              for n, ns, fc, fp, tc, tp, s, d in rows]
    top = top_row()
    print(top, flush=True)
    ns, fc, fp, tc, tp, s, d = top
    load1 = os.getloadavg()
    lines += ["", "The heavy symmetric top (models/top.yaml: 12 states, 300 rad/s spin), its scene's "
              "5 s, rtol 1e-9, atol 1e-12 (target: C at least 10x faster):", "",
              "| model | states | rhs calls C | rhs calls Python loop | C DOP853 [s] | "
              "Python loop [s] | speed-up | max state difference |",
              "|---|---|---|---|---|---|---|---|",
              f"| top | {ns} | {fc} | {fp} | {tc:.4f} | {tp:.3f} | {s:.1f}x | {d:.1e} |", "",
              f"Load average (1 min) {load0[0]:.1f} before the run, {load1[0]:.1f} after, on "
              f"{os.cpu_count()} cores (a shared machine: the ratios, measured side by side, "
              "are what to read)."]
    (ROOT / "bench" / "RESULTS_c_dop853.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
