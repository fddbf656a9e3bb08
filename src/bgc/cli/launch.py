"""The `bgc` command's front door: a warm `bgc simulate` replays its run record (bgc.run.record)
before click, PyYAML or bgc's parser is imported; everything else is bgc.cli.commands."""
from __future__ import annotations

import os
import sys

from bgc.base.collector import gc_paused


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
    with gc_paused():  # (importing allocates much and frees little: see gc_paused)
        # lazy: a warm `bgc simulate` replays its record before click and the CLI load
        from bgc.cli.commands import main as cli_main

    cli_main(args=args)


def run() -> None:
    """The process entry point (the ``bgc`` script, ``python -m bgc``): :func:`main`, then
    the process ends without the interpreter's teardown (:func:`exit_now`)."""
    exit_now(main)


def exit_now(main) -> None:
    """Run ``main`` (a whole command) as the process, then end the process without the
    interpreter's teardown: a cold compile leaves millions of objects (sympy's caches among
    them) that the final collection walks and frees one by one, 0.5-1.5 s after a 1000-node
    ladder's results were written. What the teardown does that matters is done first: the
    other threads joined (a pool's queued work finished), the ``atexit`` handlers run
    (temporary folders, logging), the standard streams flushed; the exit status is
    ``sys.exit``'s. Only for the process entry points (``python -m bgc``, the ``bgc`` script):
    callers inside a host process use ``main`` and its ``SystemExit``."""
    import atexit
    import threading

    try:
        main()
        code = 0
    except SystemExit as exc:
        code = exc.code
    if code is None:
        code = 0
    elif not isinstance(code, int):  # as the interpreter does: the text, status 1
        print(code, file=sys.stderr)
        code = 1
    shutdown = getattr(threading, "_shutdown", None)
    if shutdown is None:  # pragma: no cover - an interpreter without it: the normal teardown
        sys.exit(code)
    shutdown()
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError, AttributeError):  # closed early (| head), or replaced
            pass
    os._exit(code & 0xFF)
