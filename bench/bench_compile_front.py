"""The compile's front, stage by stage: CPU and Python calls of parse, graph, causality and the
equations without the Jacobian's sweep, each round a fresh process per checkout (issue 27).

    python bench/bench_compile_front.py [--model models/3r2s.yaml] [--repeats 5] \
        [--before /tmp/before/src]

Each round runs this file with ``--child`` in a new interpreter, for this checkout and,
alternating, for ``--before``'s src folder. The child imports the libraries first (sympy's
tensor module too, which sympy's first sum imports: an import, not the derivation's work),
then times with the collector paused, as the driver runs them: ``driver.parse``,
``driver.graph_of``, ``driver.causality_of`` and ``equations.derive``, the Jacobian's forward
sweep (``equations.jacobian``, not the front's) timed apart and taken out. CPU is
``time.process_time``; one more child per checkout (``--count``) counts instead the Python
calls each stage makes (``sys.setprofile``: function and C calls; the Jacobian's left out),
the load-independent measure of the work. Prints every round, then the CPU minimum and
median and the calls of each stage.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

import alternate  # bench/, beside this script: the before/after harness

STAGES = ("parse", "graph", "causality", "equations without the Jacobian", "the Jacobian")


def child(model: str, count: bool) -> dict:
    import networkx  # noqa: F401
    import numpy  # noqa: F401
    import symengine  # noqa: F401
    import sympy
    import sympy.tensor.tensor  # noqa: F401

    from bgc.base.collector import gc_paused
    from bgc.core import equations
    from bgc.run import driver

    jac = [0.0]
    real = equations.jacobian

    def timed_jacobian(*a, **k):
        t0 = time.process_time()
        try:
            return real(*a, **k)
        finally:
            jac[0] += time.process_time() - t0
    equations.jacobian = timed_jacobian

    def run(clock) -> dict:
        out = {}
        t = clock()
        m = driver.parse(model)
        out["parse"], t = clock() - t, clock()
        g = driver.graph_of(m)
        out["graph"], t = clock() - t, clock()
        c = driver.causality_of(g, True)
        out["causality"], t = clock() - t, clock()
        jac[0] = 0.0
        equations.derive(g, c)
        out["equations without the Jacobian"] = clock() - t - jac[0]
        out["the Jacobian"] = jac[0]
        return out

    if not count:
        with gc_paused():
            return run(time.process_time)
    calls = [0]
    counting = [True]

    def prof(frame, event, arg):
        if counting[0] and event in ("call", "c_call"):
            calls[0] += 1

    def clock():  # the calls so far
        return calls[0]

    def counted_jacobian(*a, **k):  # (the Jacobian's calls left out: not the front's)
        counting[0] = False
        try:
            return real(*a, **k)
        finally:
            counting[0] = True
    equations.jacobian = counted_jacobian
    sys.setprofile(prof)
    with gc_paused():
        n = run(clock)
    sys.setprofile(None)
    n["the Jacobian"] = 0
    return {k: int(v) for k, v in n.items()}


def main() -> None:
    ap = alternate.parser(__doc__, repeats=5)
    ap.add_argument("--count", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        print(json.dumps(child(a.model, a.count)))
        return
    srcs = alternate.checkouts(a.before)

    def one(src: str, *more: str) -> dict:
        return alternate.child(__file__, src, ["--model", a.model, *more])
    rows = alternate.rounds(srcs, a.repeats, one)
    calls = {label: one(src, "--count") for label, src in srcs.items()}
    print(f"\nCPU seconds, min / median of {a.repeats}; Python calls ({Path(a.model).name}):")
    print("| stage | " + " | ".join(f"{lb} CPU | {lb} calls" for lb in srcs) + " |")
    print("|---|" + "---|---|" * len(srcs))
    for k in STAGES:
        cells = []
        for lb in srcs:
            v = [t[k] for t in rows[lb]]
            cells.append(f"{min(v):.3f} / {statistics.median(v):.3f} | {calls[lb][k]:,}")
        print(f"| {k} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
