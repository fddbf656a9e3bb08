"""Whole-process CPU of `bgc compile` (numpy target, empty compile cache), issue 27.

    python bench/bench_compile_process.py [--repeats 5] [--model models/3r2s.yaml] \
        [--before /tmp/before/src]

Each run is a fresh `python -m bgc compile MODEL -o OUT` with its own empty BGC_CACHE_DIR; its
CPU (user + sys) is read from resource.getrusage(RUSAGE_CHILDREN) around the subprocess.
Beside it, in the same rounds (interleaved), the floors it stands on: a bare interpreter, and
one that imports what a compile needs (sympy, networkx, jinja2, symengine, numpy, yaml, click)
without compiling anything. Reports the median of the rounds; a shared machine's load moves
seconds, so compare the columns of one run. ``--before SRC`` adds the same compile with another
checkout's bgc (its src folder), interleaved too. ``bgc --help`` (listing the commands, which
imports none of the libraries above) is measured beside it, for both.
"""
from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

LIBS = "import sympy, networkx, jinja2, symengine, numpy, yaml, click"


def cpu_of(cmd: list[str], env: dict) -> float:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(cmd, env=env, check=True, capture_output=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--model", default=str(ROOT / "models" / "3r2s.yaml"))
    ap.add_argument("--before", default=None, help="src folder of the bgc to compare with")
    a = ap.parse_args()
    base_env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    rows: dict[str, list[float]] = {"python -c pass": [], "import the libraries": [],
                                    "bgc --help": [], "bgc compile (cold cache)": []}
    if a.before:
        rows["bgc --help, --before's bgc"] = []
        rows["bgc compile, --before's bgc"] = []
    for _ in range(a.repeats):
        with tempfile.TemporaryDirectory() as d:
            cache = Path(d) / "cache"
            cache.mkdir(mode=0o700)
            env = {**base_env, "BGC_CACHE_DIR": str(cache)}
            rows["python -c pass"].append(cpu_of([sys.executable, "-c", "pass"], env))
            rows["import the libraries"].append(cpu_of([sys.executable, "-c", LIBS], env))
            rows["bgc --help"].append(cpu_of([sys.executable, "-m", "bgc", "--help"], env))
            if a.before:
                rows["bgc --help, --before's bgc"].append(cpu_of(
                    [sys.executable, "-m", "bgc", "--help"], {**env, "PYTHONPATH": a.before}))
            rows["bgc compile (cold cache)"].append(cpu_of(
                [sys.executable, "-m", "bgc", "compile", a.model, "-o", str(Path(d) / "m.py"),
                 "-q"], env))
            if a.before:
                rows["bgc compile, --before's bgc"].append(cpu_of(
                    [sys.executable, "-m", "bgc", "compile", a.model, "-o",
                     str(Path(d) / "b.py"), "-q"], {**env, "PYTHONPATH": a.before}))
    print(f"whole-process CPU (user + sys), median of {a.repeats}, {Path(a.model).name}:")
    for k, v in rows.items():
        print(f"  {k:30s} {statistics.median(v):6.3f} s   (min {min(v):.3f})")


if __name__ == "__main__":
    main()
