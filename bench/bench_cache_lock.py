"""What the compile cache's per-entry lock saves (bgc.base.store): K copies of one cold
`bgc simulate SCENE` started together on an empty cache, with the lock and without it (the
store's fcntl switched off in those processes, as on a system without fcntl), side by side in
one run.

For each backend and mode: how many of the K processes compiled (their summary's "deriving
equations"), the CPU seconds of all K together (user + system, from each child's rusage),
and the wall time until the last one ended; then the CPU ratio without/with the lock.

    python bench/bench_cache_lock.py                          # msd_step, numpy and c, K = 2
    python bench/bench_cache_lock.py --scene models/scenes/dc_motor_load_step.yaml -k 3

CPU-bound and noisy on a shared machine: compare the ratios within one run.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# a child: `bgc ARGS` with the store's lock on or off
_CHILD = r"""
import sys
from bgc.base import store
if sys.argv[1] == "off":
    store._fcntl = lambda: None
from bgc.cli.commands import main
main(sys.argv[2:])
"""


def one(scene: str, backend: str, mode: str, k: int) -> dict:
    """K children started together on a fresh cache: (compiles, CPU seconds, wall seconds)."""
    import subprocess

    with tempfile.TemporaryDirectory(prefix="bgc-lockbench-") as d:
        env = {**os.environ, "BGC_CACHE_DIR": str(Path(d) / "cache")}
        logs = [Path(d) / f"{i}.err" for i in range(k)]
        t0 = time.perf_counter()
        procs = []
        for i in range(k):
            with open(logs[i], "w") as err:
                procs.append(subprocess.Popen(
                    [sys.executable, "-c", _CHILD, mode, "simulate", scene, "--backend",
                     backend, "--out", str(Path(d) / f"{i}.npz")], env=env, stderr=err,
                    stdout=subprocess.DEVNULL))
        cpu = 0.0
        for p in procs:
            _, status, ru = os.wait4(p.pid, 0)
            p.returncode = os.waitstatus_to_exitcode(status)
            if p.returncode != 0:
                raise SystemExit(f"a child failed:\n{logs[procs.index(p)].read_text()}")
            cpu += ru.ru_utime + ru.ru_stime
        wall = time.perf_counter() - t0
        compiles = sum("deriving equations" in f.read_text() for f in logs)
    return {"compiles": compiles, "cpu": cpu, "wall": wall}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default=str(ROOT / "models" / "scenes" / "msd_step.yaml"))
    ap.add_argument("--backends", default="numpy,c")
    ap.add_argument("-k", type=int, default=2, help="processes started together")
    a = ap.parse_args(argv)
    print(f"{a.k} x `bgc simulate {Path(a.scene).name}` started together on an empty cache")
    print("| backend | lock | compiles | CPU s (all) | wall s | CPU without / with |")
    print("|---|---|---|---|---|---|")
    for backend in a.backends.split(","):
        got = {mode: one(a.scene, backend, mode, a.k) for mode in ("on", "off")}
        ratio = got["off"]["cpu"] / got["on"]["cpu"]
        for mode in ("on", "off"):
            g = got[mode]
            print(f"| {backend} | {mode} | {g['compiles']} of {a.k} | {g['cpu']:.1f} | "
                  f"{g['wall']:.1f} | {f'{ratio:.2f}' if mode == 'on' else ''} |")


if __name__ == "__main__":
    main()
