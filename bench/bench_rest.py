"""Issue 27, the numpy module's rest (branch numpyrest): a whole `bgc compile` process, cold
(an empty compile cache each run), this checkout against a clean copy of another (--before),
interleaved run by run; CPU (user + sys of the process) and the module's size.

    git -C /work/main worktree add --detach /tmp/numpyrest_before main
    python bench/bench_rest.py --before /tmp/numpyrest_before --repeats 3

Two cases: the 3R2S scene compile (`bgc compile models/3r2s.yaml --scene
models/scenes/3r2s_circle.yaml`: a scene's module without the linearisation's B, C, D) and the
1000-node ladder of bench/bench_scale.py (initial_state, input_jacobian and output_jacobian
vectorised). Results: bench/RESULTS_rest.md.
"""
from __future__ import annotations

import argparse
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from bench_scale import ladder_yaml  # noqa: E402


def one(root: Path, args: list[str], out: Path) -> float:
    """CPU seconds (user + sys) of one cold `bgc compile` from ``root``'s sources."""
    cache = Path(tempfile.mkdtemp(prefix="bgc_rest_cache_"))
    env = dict(os.environ, PYTHONPATH=str(root / "src"), BGC_CACHE_DIR=str(cache))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run([sys.executable, "-m", "bgc", "compile", *args, "-o", str(out), "-q"],
                   cwd=root, env=env, check=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    shutil.rmtree(cache, ignore_errors=True)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--before", required=True, help="a clean checkout to compare against")
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    sides = {"before": Path(a.before).resolve(), "after": HERE.parent}
    work = Path(tempfile.mkdtemp(prefix="bgc_rest_"))
    ladder = work / "ladder1000.yaml"
    ladder.write_text(ladder_yaml(1000))
    cases = {"3R2S scene": ["models/3r2s.yaml", "--scene", "models/scenes/3r2s_circle.yaml"],
             "ladder 1000": [str(ladder)]}
    for case, args in cases.items():
        cpu: dict = {s: [] for s in sides}
        for _ in range(a.repeats):
            for side, root in sides.items():  # interleaved: the load falls on both alike
                cpu[side].append(one(root, args, work / f"{side}.py"))
        size = {s: (work / f"{s}.py").stat().st_size for s in sides}
        med = {s: statistics.median(v) for s, v in cpu.items()}
        print(f"{case}: CPU before {med['before']:.2f} s {cpu['before']}, after "
              f"{med['after']:.2f} s {cpu['after']}: {med['before'] / med['after']:.2f}x; "
              f"module {size['before']} -> {size['after']} bytes")
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
