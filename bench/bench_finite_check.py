"""What the runtime's finiteness check of every rhs and Jacobian result costs.

    python bench/bench_finite_check.py [--rounds 7]

Each generated module below is simulated side by side with its check on and off (off: the
module's ``_all_finite`` replaced by one that answers True, so everything else is the same
code), in interleaved rounds; the median wall time of each and their ratio are printed. The
check is one BLAS dot per call (the sum of squares), element by element only when that sum is
not finite. A shared machine is noisy: read the ratios, not the absolute times.
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

# (module in generated/, simulate keyword arguments): a small model with many cheap steps, and
# the 3R2S (101 states) over a short span
CASES = [
    ("msd", dict(t_span=(0.0, 5.0), method="RK45", dt=0.01)),
    ("msd", dict(t_span=(0.0, 5.0), method="Radau", dt=0.01)),
    ("van_der_pol", dict(t_span=(0.0, 20.0), method="Rodas4", dt=0.01)),
    ("mech3r2s", dict(t_span=(0.0, 0.02), method="Radau", dt=1e-3)),
]


def load(name):
    spec = importlib.util.spec_from_file_location(f"bench_{name}", ROOT / "generated" /
                                                  f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=7)
    args = ap.parse_args()
    print(f"{'case':<28} {'checked [s]':>12} {'unchecked [s]':>14} {'ratio':>7}  rhs calls")
    for name, kw in CASES:
        mod = load(name)
        checked = mod._all_finite
        kw = dict(kw)
        t_span = kw.pop("t_span")
        walls = {True: [], False: []}
        nfev = None
        for _ in range(args.rounds):
            for on in (True, False):
                mod._all_finite = checked if on else (lambda a: True)
                t0 = time.perf_counter()
                res = mod.simulate(t_span, **kw)
                walls[on].append(time.perf_counter() - t0)
                nfev = res.stats["nfev"]
        mod._all_finite = checked
        a, b = statistics.median(walls[True]), statistics.median(walls[False])
        print(f"{name + ' ' + kw['method']:<28} {a:12.4f} {b:14.4f} {a / b:7.3f}  {nfev}")
    print(f"numpy {np.__version__}")


if __name__ == "__main__":
    main()
