"""What the linearisation's B, C, D cost at compile time: each model compiled with and
without them (the latter by stubbing bgc.backends.numpy.printer.linear_parts with empty parts), interleaved,
median of a few rounds; one run, one machine, ratios side by side.

    python bench/bench_linear_parts.py [ROUNDS]
"""
from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

import bgc.backends.numpy.printer as emit  # noqa: E402
from bgc.core.forward import LinearParts, linear_parts  # noqa: E402
from bgc.run.driver import compile_file  # noqa: E402


def main() -> None:
    rounds = int(sys.argv[1]) if len(sys.argv) > 1 else 3
    models = ["quarter_car", "dc_motor", "motor_thermal", "3r2s"]
    print("| model | with B, C, D [s] | without [s] | ratio |\n|---|---|---|---|")
    for name in models:
        path = ROOT / "models" / f"{name}.yaml"
        with_, without = [], []
        for _ in range(rounds):
            emit.linear_parts = linear_parts
            t0 = time.perf_counter()
            compile_file(path)
            with_.append(time.perf_counter() - t0)
            emit.linear_parts = lambda eq: LinearParts({}, (), {}, {}, (), (), ())
            t0 = time.perf_counter()
            compile_file(path)
            without.append(time.perf_counter() - t0)
        emit.linear_parts = linear_parts
        a, b = statistics.median(with_), statistics.median(without)
        print(f"| {name} | {a:.2f} | {b:.2f} | {a / b:.2f} |")


if __name__ == "__main__":
    main()
