"""The bouncing ball two ways: the event model (models/bouncing_ball.yaml: an impact event with
restitution e_r) and a smooth penalty law (a stiff damped floor, 1e6 N/m, damping chosen for
the same restitution 0.8, acting only in contact). rhs calls, steps, LU factorisations, wall
time and the height's largest error against the piecewise-analytic solution over 3 s.

    PYTHONPATH=src python bench/bench_events.py        # writes nothing; prints a table
    PYTHONPATH=src python bench/bench_events.py batch  # numpy batches: own against shared
    PYTHONPATH=src python bench/bench_events.py timed  # time events: breakpoint against crossing

batch: bouncing balls with e_r from 0.8 to 0.9 as one batch, each instance on its own
(batch_events="own") against one solver for the batch ("shared"). timed: a sampler's periodic
event (`every: P`, a breakpoint) against the same event written as a crossing
(`when: t - P*(1 + cnt)`), numpy and C: rhs calls, steps, and the sampled value's error.
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
from test_events import SAMPLER, ball_height  # noqa: E402

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


def batch():
    model = bgc.compile(str(ROOT / "models" / "bouncing_ball.yaml"))
    kw = dict(dt=1e-3, rtol=1e-8, atol=1e-10)
    model.simulate((0.0, 3.0), **kw)  # warm
    print("| instances | batch_events | time [s] | rhs calls | events |")
    print("|---|---|---|---|---|")
    for n in (16, 128):
        e = np.linspace(0.8, 0.9, n)
        for mode in ("own", "shared"):
            best, r = np.inf, None
            for _ in range(3):
                t0 = time.perf_counter()
                r = model.simulate((0.0, 3.0), p={"e_r": e}, batch_events=mode, **kw)
                best = min(best, time.perf_counter() - t0)
            print(f"| {n} | {mode} | {best:.2f} | {r.stats['nfev']} | {r.stats['nevents']} |")


CROSSING = SAMPLER.replace("states:\n", "states:\n  cnt: {initial: \"0\", derivative: \"0\"}\n")


def timed():
    print("| backend | method | rtol | way | rhs calls | steps | sampled value error |")
    print("|---|---|---|---|---|---|---|")
    for target in ("numpy", "c"):
        ways = (("breakpoint", bgc.compile(SAMPLER.replace("EVENT", 'every: "P"'),
                                           target=target)),
                ("crossing", bgc.compile(CROSSING.replace(
                    "EVENT", 'when: "t - P*(1 + cnt)"\n    direction: rising').replace(
                    'do: {held: "e(cap)"}', 'do: {held: "e(cap)", cnt: "cnt + 1"}'),
                    target=target)))
        for method in ("Radau", "Rodas4", "DOP853"):
            for rtol in (1e-6, 1e-10):
                for way, model in ways:
                    r = model.simulate((0.0, 1.05), dt=0.01, rtol=rtol, atol=rtol * 1e-2,
                                       method=method)
                    h = list(model.STATE_NAMES).index("held")
                    err = max(abs(ev[4][h] - np.exp(-ev[0] / 0.5)) for ev in r.events)
                    print(f"| {target} | {method} | {rtol:g} | {way} | {r.stats['nfev']} | "
                          f"{r.stats['nsteps']} | {err:.1e} |")


if __name__ == "__main__":
    {"batch": batch, "timed": timed}.get(sys.argv[1] if len(sys.argv) > 1 else "", main)()
