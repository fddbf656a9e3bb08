"""CPU of the back end of `bgc compile MODEL` (issue 27, `print3`): printing the numpy module
(``bgc.run.driver.print_numpy``: the expressions, the template, the skeleton check) and the
start check (``bgc.run.runner.check_module_start``), in one process per checkout.

    env -u PYTHONDONTWRITEBYTECODE python bench/bench_backend.py [--model models/3r2s.yaml] \
        [--repeats 3] [--before /tmp/before/src]

Each round runs, in a fresh process per checkout (this one's src, and ``--before``'s when
given, alternating), the compile as `bgc compile MODEL` runs it (``compile_source(...,
linear=False)``, then ``check_module_start``) and reads ``time.process_time`` around the
two stages, and the digest of the module's text. Prints each round, the medians per
checkout, their ratio and whether both checkouts printed the same text. Run it with bytecode
kept (as an installed bgc runs: Python's ``.pyc`` and the template's compiled code); a
first, discarded round per checkout writes them. Times on a shared machine move with the
load: compare the columns of one run.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_ROUND = r"""
import hashlib, json, sys, time
from bgc.run import driver
from bgc.run.runner import check_module_start
spent = {"print": 0.0}
real = driver.print_numpy
def timed(*a, **k):
    t0 = time.process_time()
    try:
        return real(*a, **k)
    finally:
        spent["print"] += time.process_time() - t0
driver.print_numpy = timed
c = driver.compile_source(sys.argv[1], None, None, False, linear=False)
t0 = time.process_time()
check_module_start(c)
spent["start"] = time.process_time() - t0
spent["digest"] = hashlib.sha256(c.source.encode()).hexdigest()[:16]
print(json.dumps(spent))
"""


def one(src: str, model: str) -> dict:
    env = {**os.environ, "PYTHONPATH": src}
    out = subprocess.run([sys.executable, "-c", _ROUND, model], env=env, check=True,
                         capture_output=True, text=True, cwd=ROOT).stdout
    return json.loads(out.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="models/3r2s.yaml")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--before", default=None, help="src folder of the bgc to compare with")
    a = ap.parse_args()
    sides = {"after": str(ROOT / "src")}
    if a.before:
        sides = {"before": a.before, **sides}
    for src in sides.values():  # bytecode written, not measured
        one(src, a.model)
    rows: dict = {k: [] for k in sides}
    for r in range(a.repeats):
        for side, src in sides.items():
            got = one(src, a.model)
            rows[side].append(got)
            print(f"round {r + 1} {side:6s}: print_numpy {got['print']:.3f} s, "
                  f"check_module_start {got['start']:.3f} s, together "
                  f"{got['print'] + got['start']:.3f} s")
    med = {}
    for side, got in rows.items():
        med[side] = statistics.median(g["print"] + g["start"] for g in got)
        print(f"{side:6s} median: print_numpy {statistics.median(g['print'] for g in got):.3f} s,"
              f" check_module_start {statistics.median(g['start'] for g in got):.3f} s, "
              f"together {med[side]:.3f} s")
    if a.before:
        print(f"after / before: {med['after'] / med['before']:.2f}")
        same = {g["digest"] for got in rows.values() for g in got}
        print("the same module text" if len(same) == 1 else f"texts differ: {sorted(same)}")


if __name__ == "__main__":
    main()
