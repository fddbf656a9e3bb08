"""gcc's optimisation level for the C backend's model units: build time against run time
(issue 27, the cold path).

Takes a built C entry of the compile cache (a folder with model*.c, module.py and
libmodel.so: what `bgc simulate SCENE --backend c` leaves under $BGC_CACHE_DIR/c/..), compiles
its model units at each level (one unit at a time, so the times add up to the CPU work; the
build runs them in parallel), links each variant with the runtime's objects at the default
flags, and runs the wrapper's simulate with it: Radau, its scene's span, best of 3.

    python bench/bench_cflags.py ENTRY_DIR --t-end 10 --levels=-O0,-O1,-O2

Prints one markdown table (CPU-bound, noisy on a shared machine: compare within the run).
"""
from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from bgc.backends.c import build as cbuild  # noqa: E402
from bgc.backends.load import load_module  # noqa: E402


def _children_cpu() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("entry")
    ap.add_argument("--t-end", type=float, default=10.0)
    ap.add_argument("--levels", default="-O0,-O1,-O2")
    ap.add_argument("--method", default="Radau")
    a = ap.parse_args()
    entry = Path(a.entry)
    units = sorted(p.name for p in entry.glob("model*.c"))
    cc = list(cbuild.compiler())
    inc = str(cbuild.runtime_sources()[0].parent)
    rt_dir = Path(tempfile.mkdtemp(prefix="bgc-cflags-rt-"))
    rt_objs = cbuild._runtime_objects(None, 2, rt_dir, None)
    rows = []
    for level in a.levels.split(","):
        work = Path(tempfile.mkdtemp(prefix="bgc-cflags-"))
        fl = [level] + [f for f in cbuild.flags() if not f.startswith("-O")]
        build = 0.0
        for u in units:  # the compilers' CPU seconds (user + system), not the wall's
            t0 = _children_cpu()
            subprocess.run(cc + fl + ["-I", inc, "-c", str(entry / u), "-o",
                                      str(work / (u[:-2] + ".o"))], check=True)
            build += _children_cpu() - t0
        subprocess.run(cc + fl + ["-shared", "-o", str(work / cbuild.LIB_NAME)]
                       + [str(work / (u[:-2] + ".o")) for u in units]
                       + [str(o) for o in rt_objs] + ["-lm"], check=True)
        # (the entry is this machine's own cache: a wrapper from an older runtime loads too)
        mod = load_module((entry / "module.py").read_text(), f"cflags{level[2:]}",
                          wrapper=True)
        mod._bind(str(work / cbuild.LIB_NAME))
        best = float("inf")
        for _ in range(3):
            t0 = time.perf_counter()
            r = mod.simulate((0.0, a.t_end), dt=a.t_end / 1000, method=a.method)
            best = min(best, time.perf_counter() - t0)
        rows.append((level, build, best, r.stats["nfev"]))
        print(rows[-1], flush=True)
        shutil.rmtree(work, ignore_errors=True)
    shutil.rmtree(rt_dir, ignore_errors=True)
    print(f"\n{len(units)} units, {sum((entry / u).stat().st_size for u in units)} bytes of C; "
          f"load average {os.getloadavg()[0]:.1f}\n")
    print("| level | model units' build [s, CPU sum] | run [s] | rhs calls |\n|---|---|---|---|")
    for level, b, r, nf in rows:
        print(f"| {level} | {b:.2f} | {r:.3f} | {nf} |")


if __name__ == "__main__":
    main()
