"""What a run tells its user while it works and when it ends: one progress printer for every
command (``[  1.23 s] message`` on stderr) and the lines `bgc simulate` prints, the full way
and a record's replay alike. Standard library only: a warm run's replay uses it."""
from __future__ import annotations

import sys
import time


class Progress:
    """Progress lines on stderr, ``[  1.23 s] message``, unless quiet (every command's)."""

    def __init__(self, quiet: bool = False, t0: float | None = None):
        self.quiet = quiet
        self.t0 = time.perf_counter() if t0 is None else t0

    def __call__(self, msg: str) -> None:
        if not self.quiet:
            print(f"[{time.perf_counter() - self.t0:6.2f} s] {msg}", file=sys.stderr, flush=True)


def simulating_line(name: str, method: str, backend: str, rtol: float, atol: float,
                    why: str = "") -> str:
    why = f"; {why}" if why else ""
    return f"simulating {name} with {method} ({backend}{why}), rtol {rtol:g}, atol {atol:g}"


def summary_line(name: str, t, method: str, rtol: float, atol: float, backend: str,
                 stats: dict, compile_time: float, run_time: float, why: str = "") -> str:
    """The one line a run ends with; why: how the backend was chosen, when no one named it."""
    why = f"; {why}" if why else ""
    return (f"{name}: t = {t[0]:g}..{t[-1]:g} s, {len(t)} points, {method} rtol={rtol:g} "
            f"atol={atol:g} ({backend} backend{why}): {stats['nfev']} rhs calls, "
            f"{stats['njev']} Jacobians, {stats.get('nlu', 0)} LU"
            + (f", {stats['nevents']} events" if "nevents" in stats else "")
            + f"; compile {compile_time:.2f} s, "
            f"integrate {run_time:.2f} s")
