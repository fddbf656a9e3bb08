"""The C target's printing stages in CPU seconds (issue 27, the cold path's back half): print C
(the re-rolling pass, the parts, the units) and the wrapper, for bench_scale's RC ladders.

Each checkout given (``--src``, a folder holding bgc's ``src``: a clean copy of main beside a
branch) compiles the ladder in a fresh process, as `bgc simulate --backend c` does (the scene
to the IR, the collector paused as the driver pauses it), then times
``bgc.backends.load.c_files`` once in that process's CPU time (the stages it reports, with the
collector's full passes counted), so a loaded machine's waiting is not counted. The checkouts
alternate, ``--rounds`` times.

    python bench/bench_cstages.py --sizes 1000,3000 --src /tmp/before,. --rounds 2

Prints one markdown table.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

from bench_scale import ladder_yaml, scene_yaml  # noqa: E402

CHILD = r"""
import gc, json, sys, time
from bgc.format.scene import parse_scene
from bgc.run import driver
import bgc.backends.load as load
c = driver.compile_source(scene=parse_scene(sys.argv[1]), target="c")
full = [0, 0.0]
def watch(phase, info, t=[0.0]):
    if info["generation"] == 2:
        if phase == "start":
            t[0] = time.process_time()
        else:
            full[0] += 1
            full[1] += time.process_time() - t[0]
gc.callbacks.append(watch)
load.time.perf_counter = time.process_time  # the stages in CPU seconds
times = []
t0 = time.process_time()
load.c_files(c, times)
print(json.dumps({"total": time.process_time() - t0, **dict(times), "full passes": full[0],
                  "their CPU": full[1]}))
"""


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", default="1000,3000")
    ap.add_argument("--src", default=".", help="checkouts, comma-separated")
    ap.add_argument("--rounds", type=int, default=1)
    a = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="bgc-cstages-"))
    rows = []
    load0 = os.getloadavg()[0]
    for n in (int(s) for s in a.sizes.split(",") if s):
        (work / f"ladder{n}.yaml").write_text(ladder_yaml(n))
        scene = work / f"ladder{n}_scene.yaml"
        scene.write_text(scene_yaml(f"ladder{n}.yaml"))
        for r in range(a.rounds):
            for src in a.src.split(","):
                env = {**os.environ, "PYTHONPATH": str(Path(src).resolve() / "src"),
                       "BGC_CACHE_DIR": str(work / "cache")}
                out = subprocess.run([sys.executable, "-c", CHILD, str(scene)], env=env,
                                     capture_output=True, text=True, check=True)
                got = json.loads(out.stdout.strip().splitlines()[-1])
                rows.append((n, r + 1, src, got))
                print(rows[-1], flush=True)
    print(f"\nload average {load0:.1f} at the start, {os.getloadavg()[0]:.1f} at the end on "
          f"{os.cpu_count()} cores; CPU seconds of one process\n")
    print("| nodes | round | checkout | print C | wrapper | both | collector's full passes "
          "(CPU) |\n|---|---|---|---|---|---|---|")
    for n, r, src, g in rows:
        print(f"| {n} | {r} | {src} | {g['print C']:.2f} | {g['wrapper']:.2f} | "
              f"{g['total']:.2f} | {g['full passes']} ({g['their CPU']:.2f}) |")


if __name__ == "__main__":
    main()
