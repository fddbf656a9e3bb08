"""The `bgc` command's front door: a warm `bgc simulate` replays its run record (bgc.record)
before click, PyYAML or bgc's parser is imported; everything else is bgc.cli."""
from __future__ import annotations

import sys
import time


class Progress:
    """Progress lines on stderr, ``[  1.23 s] message``, unless quiet (every command's)."""

    def __init__(self, quiet: bool, t0: float | None = None):
        self.quiet = quiet
        self.t0 = time.perf_counter() if t0 is None else t0

    def __call__(self, msg: str) -> None:
        if not self.quiet:
            print(f"[{time.perf_counter() - self.t0:6.2f} s] {msg}", file=sys.stderr, flush=True)


def main(argv: list[str] | None = None) -> None:
    args = sys.argv[1:] if argv is None else list(argv)
    if args[:1] == ["simulate"]:
        from .record import replay

        try:
            status = replay(args[1:])
        except KeyboardInterrupt:
            print("error: aborted", file=sys.stderr)
            sys.exit(1)
        if status is not None:
            sys.exit(status)
    from .cli import main as cli_main

    cli_main(args=args)
