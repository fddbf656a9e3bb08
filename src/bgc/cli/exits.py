"""How the `bgc` command ends (README, "Errors"): the exit statuses and the one-line reports of
a user error and of an internal error."""
from __future__ import annotations

import os
import sys
import traceback

import click

from bgc.base.errors import ModelError, oneline

#: Exit statuses (README, "Errors"): 0 ok; 1 the simulation failed (numerically, or was
#: stopped); 2 a model, scene or usage error; 3 an internal error of bgc.
EXIT_FAILED_RUN, EXIT_USER, EXIT_INTERNAL = 1, 2, 3


def fail(exc: ModelError, status: int = EXIT_USER):
    click.echo(f"error: {exc}" if exc.coord is None else str(exc), err=True)
    sys.exit(status)


def debug_on() -> bool:
    return os.environ.get("BGC_DEBUG", "") not in ("", "0")


def internal_error(exc: BaseException):
    """An exception bgc did not expect: one line saying so (the traceback with BGC_DEBUG=1)."""
    if debug_on():
        traceback.print_exc()
    what = oneline(f"{type(exc).__name__}: {exc}", 300)
    click.echo(f"bgc: internal error ({what}); this is a bug in bgc, please report it with the "
               "command and its input files (BGC_DEBUG=1 shows the traceback)", err=True)
    sys.exit(EXIT_INTERNAL)
