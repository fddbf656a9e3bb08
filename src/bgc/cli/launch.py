"""The `bgc` command's front door: a warm `bgc simulate` replays its run record (bgc.run.record)
before click, PyYAML or bgc's parser is imported; everything else is bgc.cli.commands."""
from __future__ import annotations

import sys


def main(argv: list[str] | None = None) -> None:
    args = sys.argv[1:] if argv is None else list(argv)
    if args[:1] == ["simulate"]:
        # lazy: only `bgc simulate` has a record to replay (numpy; every other command skips it)
        from bgc.run.record import replay

        try:
            status = replay(args[1:])
        except KeyboardInterrupt:
            print("error: aborted", file=sys.stderr)
            sys.exit(1)
        if status is not None:
            sys.exit(status)
    # lazy: a warm `bgc simulate` replays its record before click and the CLI load
    from bgc.cli.commands import main as cli_main

    cli_main(args=args)
