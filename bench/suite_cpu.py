"""Where the test suite's time goes: CPU seconds per test, robust to a loaded machine.

As a pytest plugin it appends, for every test, the CPU time of its process and of the
children it waited for (compilers, `bgc` subprocesses), and its wall time, to
``$SUITE_CPU_OUT/<worker>.jsonl``; run as a script it prints the per-file totals and the
costliest tests of such a folder. Wall time on a shared machine moves with the load; CPU
time moves much less, so per-file costs measured side by side compare.

    SUITE_CPU_OUT=/tmp/cpu PYTHONPATH=src:bench python -m pytest -p suite_cpu -n 2 tests/...
    python bench/suite_cpu.py /tmp/cpu [N]
"""
from __future__ import annotations

import collections
import glob
import json
import os
import resource
import sys
import time

import pytest


def _cpu() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    cpu, wall = _cpu(), time.perf_counter()
    yield
    row = {"id": item.nodeid, "cpu": _cpu() - cpu, "wall": time.perf_counter() - wall}
    out = os.environ.get("SUITE_CPU_OUT", "suite-cpu")
    os.makedirs(out, exist_ok=True)
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    with open(os.path.join(out, f"{worker}.jsonl"), "a", encoding="utf-8") as f:
        f.write(json.dumps(row) + "\n")


def report(folder: str, n: int = 40) -> None:
    rows = []
    for path in glob.glob(os.path.join(folder, "*.jsonl")):
        worker = os.path.basename(path)[:-6]
        with open(path, encoding="utf-8") as f:
            rows += [dict(json.loads(line), worker=worker) for line in f]
    files = collections.defaultdict(lambda: [0.0, 0.0, 0])
    for r in rows:
        t = files[r["id"].split("::")[0]]
        t[0] += r["cpu"]
        t[1] += r["wall"]
        t[2] += 1
    print("  cpu s   wall s  tests  file")
    for name, (cpu, wall, k) in sorted(files.items(), key=lambda kv: -kv[1][0]):
        print(f"{cpu:7.1f} {wall:8.1f} {k:6d}  {name}")
    print(f"{sum(v[0] for v in files.values()):7.1f} {sum(v[1] for v in files.values()):8.1f}"
          f" {len(rows):6d}  all")
    print("\n  cpu s   wall s  worker  test")
    for r in sorted(rows, key=lambda r: -r["cpu"])[:n]:
        print(f"{r['cpu']:7.1f} {r['wall']:8.1f}  {r['worker']:6s}  {r['id']}")


if __name__ == "__main__":
    report(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 40)
