"""`bgc sweep`: the command line of parameter sweeps (bgc.studies.sweep: Dask, xarray, Zarr).

Registered only when asked for, like `bgc accuracy`."""
from __future__ import annotations

import click

from bgc.base.outdirs import out_folder
from bgc.base.outfiles import check_folder
from bgc.cli.options import POSITIVE
from bgc.run.progress import Progress
from bgc.studies.sweep import client_for, close_client, prepare, run_sweep
from bgc.studies.sweep_folder import check_store
from bgc.studies.sweep_plot import plot_sweep
from bgc.studies.sweep_spec import MAX_SAMPLES
from bgc.studies.sweep_store import open_results


def register(main_group):
    """Add the `sweep` command to a click group."""

    @main_group.command("sweep")
    @click.argument("scene", type=click.Path(dir_okay=False))
    @click.option("--out", required=True, type=click.Path(file_okay=False),
                  help="results store RESULTS.zarr (rerun with the same --out to resume)")
    @click.option("--scheduler", default="local", show_default=True,
                  help="'local' (a new local cluster) or a running Dask scheduler's address")
    @click.option("--workers", type=click.IntRange(1, 1024), default=2, show_default=True,
                  help="worker processes of the local cluster")
    @click.option("--chunk", type=click.IntRange(1, MAX_SAMPLES), default=16, show_default=True,
                  help="instances per task (one vectorised simulate call)")
    @click.option("--plot", "plot_dir", type=click.Path(file_okay=False), default=None,
                  help="write overview PNGs here")
    @click.option("--restart", is_flag=True,
                  help="discard the results in a store bgc made (marked by its .bgc-output "
                       "file) for another sweep; nothing else in it, and no other folder, is "
                       "ever removed")
    @click.option("--max-wall", type=POSITIVE, default=None,
                  help="seconds per simulate call before it is stopped (recorded as failed)")
    @click.option("--backend", type=click.Choice(("c", "numpy")), default=None,
                  help="c (the C step loop: each instance its own step size) or numpy; "
                       "default: the scene's solver backend, else c where a C compiler is "
                       "available and the model is one the C backend prints, else numpy")
    @click.option("-q", "--quiet", is_flag=True)
    def sweep_cmd(scene, out, scheduler, workers, chunk, plot_dir, restart, max_wall, backend,
                  quiet):
        """Run SCENE's sweep: batched simulations on Dask, results in a Zarr store."""
        say = Progress(quiet)


        check_store(out)  # a folder bgc did not make: refused before anything runs
        if plot_dir is not None:  # '' too: refused as an empty path
            check_folder(out_folder(plot_dir, "--plot", create=False), "--plot")
        say(f"compiling {scene}")
        prep = prepare(scene, say, backend)
        prep.max_wall = max_wall
        say(f"{prep.n} instances in chunks of {chunk} ({prep.backend} backend); starting "
            + ("a local cluster" if scheduler in ("", "local") else f"client of {scheduler}"))
        client = client_for(scheduler, workers)
        try:
            rep = run_sweep(prep, out, client, chunk, restart, quiet)
        finally:
            close_client(client)
        if plot_dir is not None:
            for f in plot_sweep(prep, open_results(out), plot_dir):
                say(f"wrote {f}")
        click.echo(f"{prep.scene_name}: {rep.n} instances, {rep.chunks} chunks ({rep.computed} "
                   f"computed, {rep.skipped} already done), {rep.failed} failed "
                   f"({prep.backend} backend); "
                   f"{rep.wall:.1f} s; results in {rep.out}")

    return sweep_cmd
