"""A user's first work-precision study (issue 21, item 11): the default
`bgc accuracy models/scenes/3r2s_figure8.yaml`, as a whole command in a fresh process with an
empty compile cache, timed from start to exit; the goal is a few minutes on 2 cores.

    python bench/bench_first_study.py                    # the default study, limit 1800 s
    python bench/bench_first_study.py --limit 600 --scene models/scenes/msd_step.yaml
    python bench/bench_first_study.py --extra "--repeats 1"   # options added to the command

Prints the command, its exit status, its wall time and the tail of its summary (what was
skipped and why). A benchmark, not a test: the time depends on the machine and its load.
"""
from __future__ import annotations

import argparse
import os
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run(scene: str, extra: str, limit: float) -> dict:
    with tempfile.TemporaryDirectory(prefix="bgc-first-study-") as tmp:
        env = dict(os.environ, BGC_CACHE_DIR=str(Path(tmp) / "cache"), MPLBACKEND="Agg",
                   PYTHONPATH=str(ROOT / "src"))
        cmd = [sys.executable, "-m", "bgc.cli", "accuracy", scene, "--out",
               str(Path(tmp) / "acc"), *shlex.split(extra)]
        t0 = time.perf_counter()
        try:
            r = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True,
                               timeout=limit)
            status, out = r.returncode, r.stdout + r.stderr
        except subprocess.TimeoutExpired as exc:
            status = "timeout"
            out = (exc.stdout or b"").decode(errors="replace") if isinstance(
                exc.stdout, bytes) else (exc.stdout or "")
        wall = time.perf_counter() - t0
    return {"command": shlex.join(["bgc", *cmd[3:]]), "status": status, "wall": wall,
            "tail": "\n".join(out.strip().splitlines()[-15:]), "out": out}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="models/scenes/3r2s_figure8.yaml")
    ap.add_argument("--extra", default="", help="options added to the command")
    ap.add_argument("--limit", type=float, default=1800.0, help="seconds before it is stopped")
    ap.add_argument("--log", default=None, help="write the command's whole output here")
    a = ap.parse_args(argv)
    load0 = os.getloadavg()
    res = run(a.scene, a.extra, a.limit)
    load1 = os.getloadavg()
    if a.log:
        Path(a.log).write_text(res["out"])
    print(f"{res['command']}\nexit {res['status']} after {res['wall']:.0f} s "
          f"({os.cpu_count()} cores; load average {load0[0]:.1f} before, {load1[0]:.1f} "
          f"after, {load1[1]:.1f} over 5 min)\n{res['tail']}")
    return 0 if res["status"] == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
