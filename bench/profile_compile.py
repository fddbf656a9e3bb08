"""Where the symbolic compile's time goes, stage by stage, against model size (issue 27).

    python bench/profile_compile.py --ladder 1000,3000,10000 --links 48,143,476 [--profile P]
    python bench/profile_compile.py --src /tmp/before/src ...   # another checkout's bgc

Each size is generated (bench/bench_scale.py's RC ladder, bench/bench_compile.py's 3-D link
chain), parsed and compiled to the numpy module in this process, every stage timed in CPU
seconds (time.process_time); the growth exponent of each stage is the slope of log(time)
against log(states) between consecutive sizes. ``--profile PREFIX`` writes a cProfile of every
size (PREFIX.ladder1000, ...), its call counts the deterministic measure of the work. CPU-bound and noisy on a shared machine: compare within one run.
"""
from __future__ import annotations

import argparse
import cProfile
import math
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))
# --src DIR: compile with another checkout's sources (before/after side by side)
_src = sys.argv[sys.argv.index("--src") + 1] if "--src" in sys.argv else str(ROOT / "src")
sys.path.insert(0, _src)

from bgc.format.parse import parse_file  # noqa: E402, F401  (first: bench_compile then finds it)
from bgc.run import driver  # noqa: E402

from bench_compile import link_chain  # noqa: E402
from bench_scale import ladder_yaml  # noqa: E402

assert Path(driver.__file__).is_relative_to(_src), driver.__file__

# bgc.base.limits bounds untrusted models at 20,000 flat items and 2 MB: the largest sizes
# here are beyond both, so this benchmark (only) lifts them
from bgc.base.limits import LIMITS  # noqa: E402

object.__setattr__(LIMITS, "flat_elements", 10 ** 7)
object.__setattr__(LIMITS, "model_bytes", 10 ** 9)


# the driver's stage clock in CPU seconds (the machine is shared: wall time is not the work)
driver.time = type("CpuClock", (), {"perf_counter": staticmethod(time.process_time)})


def stages(path: Path) -> tuple[int, dict]:
    """One `bgc compile` of ``path`` as the measured checkout's driver runs it
    (``driver.compile_file``: the parse, then stages 2-7), its stage times in CPU seconds."""
    t0 = time.process_time()
    c = driver.compile_file(path)
    times = dict(c.times)
    times["total cpu"] = time.process_time() - t0
    return len(c.equations.states), times


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ladder", default="300,1000")
    ap.add_argument("--links", default="15,48")
    ap.add_argument("--profile", default=None)
    ap.add_argument("--src", default=None, help="the src folder of bgc to measure")
    a = ap.parse_args()
    d = Path(tempfile.mkdtemp(prefix="bgc-prof-"))
    for fam, sizes, make in (("ladder", a.ladder, ladder_yaml),
                             ("links", a.links, lambda n: yaml.safe_dump(link_chain(n),
                                                                         sort_keys=False))):
        rows = []
        ns = [int(s) for s in sizes.split(",") if s]
        for k, n in enumerate(ns):
            p = d / f"{fam}{n}.yaml"
            p.write_text(make(n))
            if a.profile:
                pr = cProfile.Profile()
                pr.enable()
            states, t = stages(p)
            if a.profile:
                pr.disable()
                pr.dump_stats(f"{a.profile}.{fam}{n}")
            rows.append((states, t))
            print(f"{fam} n={n} states={states} " + " ".join(
                f"{k}={v:.3f}" for k, v in t.items()), flush=True)
        for (n1, t1), (n2, t2) in zip(rows, rows[1:]):
            print(f"  exponents {n1}->{n2}: " + " ".join(
                f"{k}={math.log(max(t2[k], 1e-6) / max(t1[k], 1e-6)) / math.log(n2 / n1):.2f}"
                for k in t1), flush=True)


if __name__ == "__main__":
    main()
