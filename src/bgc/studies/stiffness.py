"""Parameter sweeps of a work-precision study's setup (bgc.studies.accuracy): one method and
tolerance, one parameter stepped through values (the 3R2S's penalty stiffness), each run in a
forked child with a budget, with metrics the caller computes from each solution."""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from bgc.studies.runs import GRACE, BudgetExceeded, Setup, run_isolated, solve


@dataclass
class SweepPoint:
    value: float
    status: str
    message: str = ""
    wall: float = math.nan
    nfev: int = 0
    njev: int = 0
    nlu: int = 0
    metrics: dict = field(default_factory=dict)
    nsteps: int = 0


def param_sweep(setup: Setup, param, values, metrics_fn, method="Radau", rtol=1e-6,
                atol=1e-9, budget=60.0, repeats=1, progress=None) -> list:
    """Simulate with p[param] = each value; metrics_fn(setup, p, res) -> {name: float}."""
    say = progress or (lambda msg: None)
    pts = []
    for v in values:
        s = replace(setup, p={**(setup.p or {}), param: float(v)})

        def work():
            walls, start, out = [], time.perf_counter(), None
            for _ in range(max(1, repeats)):
                t0 = time.perf_counter()
                try:
                    res, st = solve(s, method, rtol, atol, "analytic", start + budget)
                except BudgetExceeded:
                    if walls:
                        break
                    raise
                walls.append(time.perf_counter() - t0)
                out = out or (res, st)
                if time.perf_counter() - start + walls[-1] > budget:
                    break
            res, st = out
            return float(np.median(walls)), st, metrics_fn(s, s.p, res)

        status, val = run_isolated(work, budget + GRACE)
        if status == "ok":
            wall, st, met = val
            pt = SweepPoint(float(v), "ok", "", wall, st["nfev"], st["njev"], st["nlu"], met,
                            st["nsteps"])
            say(f"{param} = {v:.3g}: {wall:.2f} s, {st['nfev']} rhs, " + ", ".join(
                f"{k} {x:.3g}" for k, x in met.items()))
        else:
            kind = "budget" if isinstance(val, BudgetExceeded) else "failed"
            pt = SweepPoint(float(v), kind, str(val)[:200])
            say(f"{param} = {v:.3g}: {kind.upper()} {val}")
        pts.append(pt)
    return pts
