"""The `bgc` command: its click group (user errors one located line, exit 2; bgc.cli.exits),
the commands of bgc.cli.model_cmds, scene_cmds and housekeeping added to it, and the heavy
commands (`accuracy`, `sweep`: bgc.cli.accuracy, bgc.cli.sweep) registered only when asked
for."""
from __future__ import annotations

import errno
import sys
import traceback

import click

from bgc.base import __version__
from bgc.base.errors import ModelError, SimulationFailed, oneline
from bgc.cli import housekeeping, library, model_cmds, scene_cmds
from bgc.cli.exits import (  # noqa: F401 (EXIT_*: the statuses, as bgc.cli.commands.*)
    EXIT_FAILED_RUN,
    EXIT_INTERNAL,
    EXIT_USER,
    debug_on,
    fail,
    internal_error,
)


class _Group(click.Group):
    """Catches user errors; registers the commands that live in heavy modules (`bgc accuracy`,
    `bgc sweep`) only when asked for, so a warm `bgc simulate` never imports them."""

    listing = False  # True while --help lists the commands: the heavy ones by their summary

    def get_command(self, ctx, name):
        if name in _LAZY and name not in self.commands:
            if self.listing:  # a stand-in that only says what the command does
                return click.Command(name, help=_LAZY[name][1])
            _LAZY[name][0]()
        return super().get_command(ctx, name)

    def list_commands(self, ctx):
        if self.listing:
            return sorted(set(self.commands) | set(_LAZY))
        for name, (register, _) in _LAZY.items():
            if name not in self.commands:
                register()
        return super().list_commands(ctx)

    def format_commands(self, ctx, formatter):
        """``bgc --help`` lists `accuracy` and `sweep` by their summary (:data:`_LAZY`),
        without importing their modules."""
        self.listing = True
        try:
            super().format_commands(ctx, formatter)
        finally:
            self.listing = False

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True,
             **extra):
        """A usage error is one line too (click prints three): ``error: ...``, exit 2."""
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, False, **extra)
        try:
            rv = super().main(args, prog_name, complete_var, False, **extra)
        except click.UsageError as exc:
            hint = f" (see '{exc.ctx.command_path} --help')" if exc.ctx is not None else ""
            click.echo(f"error: {oneline(exc.format_message(), 400)}{hint}", err=True)
            sys.exit(exc.exit_code)
        except click.ClickException as exc:
            click.echo(f"error: {oneline(exc.format_message(), 400)}", err=True)
            sys.exit(exc.exit_code)
        except click.Abort:
            click.echo("error: aborted", err=True)
            sys.exit(1)
        sys.exit(rv if isinstance(rv, int) else 0)

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except (click.exceptions.ClickException, click.exceptions.Exit, click.Abort):
            raise  # usage errors: click prints them (exit 2)
        except SimulationFailed as exc:
            if debug_on():
                traceback.print_exc()
            fail(exc, EXIT_FAILED_RUN)
        except ModelError as exc:
            if debug_on():
                traceback.print_exc()
            fail(exc)
        except RecursionError:
            click.echo("error: the model is nested too deeply", err=True)
            sys.exit(EXIT_USER)
        except MemoryError:
            click.echo("error: out of memory (the model or scene asks for more than this "
                       "machine has)", err=True)
            sys.exit(EXIT_USER)
        except OSError as exc:  # a file named on the command line that cannot be used
            if exc.errno == errno.EPIPE:
                raise  # stdout closed early (bgc check ... | head): click exits quietly
            if debug_on():
                traceback.print_exc()

            where = f" {exc.filename!r}" if exc.filename is not None else ""
            click.echo(f"error:{oneline(where, 240)} {exc.strerror or exc}", err=True)
            sys.exit(EXIT_USER)
        except Exception as exc:  # noqa: BLE001 - the catch-all: exit 3, one line
            internal_error(exc)


@click.group(cls=_Group)
@click.version_option(__version__, prog_name="bgc")
def main():
    """bgc: compile bond graphs (YAML) into standalone numpy simulation modules."""


for _cmd in (model_cmds.compile_cmd, model_cmds.check_cmd, model_cmds.graph_cmd,
             scene_cmds.simulate_cmd, scene_cmds.explain_cmd, scene_cmds.linearize_cmd,
             model_cmds.equations_cmd, housekeeping.examples_cmd, housekeeping.cache_cmd,
             model_cmds.export_cmd, library.library_cmd):
    main.add_command(_cmd)


def _register_accuracy():
    """`bgc accuracy` lives in a heavy module: registered only when asked for (warm runs of
    other commands never import it)."""
    # lazy: the compile path, which a warm run never loads
    from bgc.cli.accuracy import register

    register(main)
    main.commands["accuracy"].epilog = f"\b\nExample:\n  {_EXAMPLES['accuracy']}\n\n{_DOCS}"


_DOCS = "Docs: docs/model-format.md (the format), docs/api.md (Python), README.md."
_EXAMPLES = {
    "compile": "bgc compile models/msd.yaml -o msd.py",
    "check": "bgc check models/3r2s.yaml",
    "graph": "bgc graph models/msd.yaml -o msd.svg",
    "simulate": "bgc simulate models/scenes/msd_step.yaml --out r.npz --plot figs/",
    "explain": "bgc explain models/scenes/motor_load_motion_cold.yaml",
    "accuracy": "bgc accuracy models/scenes/msd_step.yaml --out acc/",
    "linearize": "bgc linearize models/quarter_car.yaml --out lin/ --bode zr:body_height",
    "equations": "bgc equations models/msd.yaml --latex",
    "examples": "bgc examples my_models/",
    "library": "bgc library rigid_rod",
    "sweep": "bgc sweep models/scenes/msd_sweep.yaml --out sweep.zarr --workers 2",
}
main.epilog = "\b\nExample:\n  bgc simulate models/scenes/msd_step.yaml --plot figs/\n\n" + _DOCS
for _name, _cmd in main.commands.items():
    if _name in _EXAMPLES:
        _cmd.epilog = f"\b\nExample:\n  {_EXAMPLES[_name]}\n\n{_DOCS}"


def _register_sweep():
    """`bgc sweep` (Dask, xarray, Zarr) is registered only when asked for, like accuracy."""
    # lazy: the compile path, which a warm run never loads
    from bgc.cli.sweep import register

    register(main)
    if "sweep" in _EXAMPLES:
        main.commands["sweep"].epilog = f"\b\nExample:\n  {_EXAMPLES['sweep']}\n\n{_DOCS}"


#: the commands registered on first use: (register, the summary `bgc --help` lists; the
#: first sentence of the command's own help, which tests/test_cli.py compares)
_LAZY = {"accuracy": (_register_accuracy, ("Work-precision study of SCENE.yaml: error against "
                                           "wall time and rhs calls.")),
         "sweep": (_register_sweep, ("Run SCENE's sweep: batched simulations on Dask, results "
                                     "in a Zarr store."))}


if __name__ == "__main__":  # pragma: no cover
    main()
