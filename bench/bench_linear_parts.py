"""What the linearisation's B, C, D cost at compile time: each model compiled with and
without them (the latter by stubbing bgc.lower.ir.linear_parts with empty parts), interleaved,
median of a few rounds, CPU seconds of this process; one run, one machine, ratios side by
side.

    python bench/bench_linear_parts.py [ROUNDS] [--src OTHER/src] [--models a,b,...]

``--src``: measure another checkout's bgc (its src folder) instead of this one's, e.g. the
clean copy of main a change is compared with (run the two one after the other, at the same
load). Each model's first compile (sympy's caches filling) is not counted.
"""
from __future__ import annotations

import argparse
import resource
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rounds", type=int, nargs="?", default=3)
    ap.add_argument("--src", default=str(ROOT / "src"))
    ap.add_argument("--models", default="quarter_car,dc_motor,motor_thermal,3r2s")
    a = ap.parse_args()
    sys.path.insert(0, a.src)
    import bgc.lower.ir as ir
    from bgc.core.forward import LinearParts, linear_parts
    from bgc.run.driver import compile_file

    def empty(eq):
        return LinearParts({}, (), {}, {}, (), (), ())

    print(f"bgc from {a.src}")
    print("| model | with B, C, D [s] | without [s] | ratio |\n|---|---|---|---|")
    for name in a.models.split(","):
        path = ROOT / "models" / f"{name}.yaml"
        compile_file(path)  # (warm-up: not counted)
        with_, without = [], []
        for _ in range(a.rounds):
            for fn, into in ((linear_parts, with_), (empty, without)):
                ir.linear_parts = fn
                t0 = _cpu()
                compile_file(path)
                into.append(_cpu() - t0)
        ir.linear_parts = linear_parts
        w, wo = statistics.median(with_), statistics.median(without)
        print(f"| {name} | {w:.2f} | {wo:.2f} | {w / wo:.2f} |")


if __name__ == "__main__":
    main()
