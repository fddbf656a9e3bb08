"""CPU of each progress stage of one in-process `bgc compile` of a model (cold compile cache),
each round a fresh process per checkout, alternating (issue 27).

    python bench/bench_compile_stages.py [--model models/3r2s.yaml] [--repeats 5] \
        [--before /tmp/before/src]

The child compiles as `bgc compile MODEL` does (`bgc.run.driver.compile_source`, the numpy
module with its linearisation) and reads time.process_time at every progress message the
driver prints ("deriving the Jacobian", "lowering rhs", ...); the lowering's end is marked
too, so "emitting the linearisation's B, C, D" is that stage alone, not the printing after
it. Prints every round and the medians and minima per stage; a shared machine's load moves
them, so compare the columns of one run. ``--calls``: instead, the Python function calls of
the middle (the Jacobian's forward sweep and the lowering, under cProfile), sympy's
``Basic.__hash__`` among them: a count the load does not move.
"""
from __future__ import annotations

import itertools
import json
import statistics
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

import alternate  # bench/, beside this script: the before/after harness

MIDDLE = ("deriving the Jacobian", "lowering rhs", "lowering jacobian", "lowering outputs",
          "emitting the linearisation's B, C, D")


def child(model: str, calls: bool = False) -> dict:
    from bgc.core import equations
    from bgc.lower import ir
    from bgc.run.driver import compile_source

    if calls:
        return _calls(model, equations, ir, compile_source)

    marks: list = []

    def progress(msg: str) -> None:
        marks.append((msg, time.process_time()))
    real = ir.lower

    def lower(*a, **k):  # (looked up by the driver at call time)
        try:
            return real(*a, **k)
        finally:
            marks.append(("(after lowering)", time.process_time()))
    ir.lower = lower
    compile_source(model, None, progress)
    marks.append(("(end)", time.process_time()))
    out: dict = {}
    for (m, t), (_, t2) in itertools.pairwise(marks):
        out[m] = out.get(m, 0.0) + t2 - t
    out["middle: the Jacobian and lowering"] = sum(out.get(k, 0.0) for k in MIDDLE)
    return out


def _calls(model, equations, ir, compile_source) -> dict:
    import cProfile
    import pstats

    prof = cProfile.Profile()
    for owner, name in ((equations, "jacobian"), (ir, "lower")):
        real = getattr(owner, name)

        def wrapper(*a, _real=real, **k):
            prof.enable()
            try:
                return _real(*a, **k)
            finally:
                prof.disable()
        setattr(owner, name, wrapper)
    compile_source(model)
    st = pstats.Stats(prof).stats
    return {"python calls (Jacobian and lowering)": sum(v[1] for v in st.values()),
            "of them sympy's Basic.__hash__": sum(v[1] for k, v in st.items()
                                                 if k[2] == "__hash__" and
                                                 k[0].endswith("basic.py")),
            "sympy cse calls": sum(v[0] for k, v in st.items()
                                   if k[2] == "cse" and k[0].endswith("cse_main.py"))}


def main() -> None:
    ap = alternate.parser(__doc__, repeats=5)
    ap.add_argument("--calls", action="store_true", help="count calls instead of timing")
    a = ap.parse_args()
    if a.child:
        print(json.dumps(child(a.model, a.calls)))
        return
    srcs = alternate.checkouts(a.before)
    rows = alternate.rounds(srcs, a.repeats, lambda src: alternate.child(
        __file__, src, ["--model", a.model] + (["--calls"] if a.calls else [])))
    what = "calls" if a.calls else "CPU seconds per stage"
    print(f"\n{what}, median (min) of {a.repeats} ({Path(a.model).name}):")
    print("| stage | " + " | ".join(srcs) + " |\n|---|" + "---|" * len(srcs))
    for k in rows["after"][0]:
        cells = []
        for lb in srcs:
            v = [t.get(k, 0.0) for t in rows[lb]]
            cells.append(f"{statistics.median(v):.0f} ({min(v):.0f})" if a.calls else
                         f"{statistics.median(v):.3f} ({min(v):.3f})")
        print(f"| {k} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
