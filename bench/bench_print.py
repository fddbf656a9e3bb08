"""CPU of the back half of a compile, in one process per checkout: lowering, printing the numpy
module, printing the C units (issue 27).

    python bench/bench_print.py [--model models/3r2s.yaml] [--repeats 5] [--before /tmp/before/src]

Each round runs, in a fresh process per checkout (this one's src, and ``--before``'s when
given, interleaved), the equations of MODEL once, then times with ``time.process_time``:
``bgc.lower.ir.lower`` (rhs, Jacobian, outputs and the linearisation's B, C, D), the numpy
module's text from that IR (``render``, its skeleton check left out) and the C units' text
(``render_c``). Prints the median of the rounds per stage and checkout and whether both
checkouts printed the same text (their digests). Times on a shared machine move with the
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
import gc, hashlib, json, sys, time
from bgc.run import driver
from bgc.lower.ir import lower
from bgc.backends.c.printer import render_c

c = driver.compile_model(driver.parse(sys.argv[1]), target="c")
gc.disable()
t0 = time.process_time()
low = lower(c.equations, None, linear=True)
t1 = time.process_time()
text = driver.print_numpy(c.model, low, c.notes, None, None, True, False)
t2 = time.process_time()
units = render_c(low, source="m.yaml", source_hash="0")
t3 = time.process_time()
csrc = json.dumps(units.files)
print(json.dumps({"lower": t1 - t0, "print numpy": t2 - t1, "print C": t3 - t2,
                  "numpy digest": hashlib.sha256(text.encode()).hexdigest()[:12],
                  "C digest": hashlib.sha256(csrc.encode()).hexdigest()[:12]}))
"""


def one_round(src: str, model: str) -> dict:
    env = {**os.environ, "PYTHONPATH": src}
    r = subprocess.run([sys.executable, "-c", _ROUND, model], env=env, capture_output=True,
                       text=True, check=True)
    return json.loads(r.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default=str(ROOT / "models" / "3r2s.yaml"))
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--before", default=None, help="src folder of the bgc to compare with")
    a = ap.parse_args()
    sides = {"this": str(ROOT / "src")}
    if a.before:
        sides["before"] = a.before
    got: dict[str, list[dict]] = {k: [] for k in sides}
    for _ in range(a.repeats):
        for name, src in sides.items():
            got[name].append(one_round(src, a.model))
    print(f"CPU seconds, median of {a.repeats} rounds, {Path(a.model).name} "
          f"(load {os.getloadavg()[0]:.1f} at the end):")
    for stage in ("lower", "print numpy", "print C"):
        cells = "   ".join(f"{name} {statistics.median(r[stage] for r in rows):6.3f}"
                           for name, rows in got.items())
        print(f"  {stage:12s} {cells}")
    for what in ("numpy digest", "C digest"):
        digests = {name: {r[what] for r in rows} for name, rows in got.items()}
        print(f"  {what}: " + ", ".join(f"{k} {' '.join(sorted(v))}" for k, v in digests.items()))


if __name__ == "__main__":
    main()
