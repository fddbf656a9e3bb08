"""The bouncing ball two ways: the event model (models/bouncing_ball.yaml: an impact event with
restitution e_r) and a smooth penalty law (a stiff damped floor, 1e6 N/m, damping chosen for
the same restitution 0.8, acting only in contact). rhs calls, steps, LU factorisations, wall
time and the height's largest error against the piecewise-analytic solution over 3 s.

    PYTHONPATH=src python bench/bench_events.py        # writes nothing; prints a table
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
sys.path.insert(0, str(ROOT / "tests"))
os.environ.setdefault("BGC_CACHE_DIR", tempfile.mkdtemp())

import bgc  # noqa: E402
from test_events import ball_height  # noqa: E402

K, E = 1.0e6, 0.8
ZETA = -np.log(E) / np.sqrt(np.pi ** 2 + np.log(E) ** 2)  # restitution of a linear contact
PENALTY = f"""
bgc: 1
name: ball_penalty
parameters:
  m: 0.1
  g: 9.81
  h0: 1.0
  kc: {K}
  cc: {float(2 * ZETA * np.sqrt(K * 0.1))!r}
elements:
  gravity: {{type: Se, effort: "-m*g"}}
  floor:   {{type: Se, effort: "where(h < 0, -kc*h - cc*f(ball), 0)"}}
  ball:    {{type: I, inertia: "m"}}
  v:       {{type: "1"}}
bonds: [[gravity, v], [floor, v], [v, ball]]
states:
  h: {{initial: "h0", derivative: "f(ball)"}}
outputs:
  height: "h"
"""


def run(model, method, rtol, repeat=3):
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        r = model.simulate((0.0, 3.0), dt=1e-3, rtol=rtol, atol=rtol * 1e-2, method=method)
        best = min(best, time.perf_counter() - t0)
    err = np.max(np.abs(r.y["height"] - ball_height(r.t, 1.0, E)))
    return r.stats, best, err


def main():
    event = bgc.compile(str(ROOT / "models" / "bouncing_ball.yaml"))
    penalty = bgc.compile(PENALTY)
    print("| model | method | rtol | rhs calls | steps | LU | events | time [s] | max height error [m] |")
    print("|---|---|---|---|---|---|---|---|---|")
    for rtol in (1e-6, 1e-10):
        for method in ("Radau", "Rodas4"):
            for label, model in (("event", event), ("penalty", penalty)):
                st, wall, err = run(model, method, rtol)
                print(f"| {label} | {method} | {rtol:g} | {st['nfev']} | {st['nsteps']} | "
                      f"{st['nlu']} | {st.get('nevents', '-')} | {wall:.3f} | {err:.2g} |")


if __name__ == "__main__":
    main()
