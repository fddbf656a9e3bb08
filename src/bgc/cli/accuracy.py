"""`bgc accuracy`: the command line of the work-precision study (bgc.studies.accuracy).

Registered only when asked for: the study's module is heavy, and warm runs of other commands
should not pay for it."""
from __future__ import annotations

import math
from pathlib import Path

import click
import numpy as np

from bgc.base.errors import ModelError
from bgc.base.outdirs import out_folder
from bgc.base.outfiles import check_folder
from bgc.cli.options import POSITIVE, RTOL, finite, model_inputs
from bgc.format.scene import parse_scene
from bgc.run.progress import Progress
from bgc.run.runner import check_start
from bgc.studies.accuracy import parse_methods, parse_tols, study
from bgc.studies.accuracy_report import cheapest, skipped_lines, write_all
from bgc.studies.runs import C_METHODS, FD_JACOBIAN, METHODS, c_available, prepare
from bgc.studies.sweep import client_for

_DEFAULT_METHODS = ",".join(METHODS + C_METHODS)


def register(main_group):
    """Add the `accuracy` command to a click group."""

    @main_group.command("accuracy")
    @click.argument("scene", type=click.Path(dir_okay=False))
    @click.option("--out", "out_dir", type=click.Path(), default=None,
                  help="output folder (default: accuracy_<scene>)")
    @click.option("--methods", default=_DEFAULT_METHODS, show_default=True,
                  help="comma-separated scipy methods")
    @click.option("--tols", default="1e-3:1e-10", show_default=True,
                  help="rtol values: a decade range a:b or a comma list")
    @click.option("--atol-scale", type=POSITIVE, default=None,
                  help="atol = rtol x this (default: the scene's atol/rtol)")
    @click.option("--budget", type=POSITIVE, default=20.0, show_default=True,
                  help="seconds per (method, tolerance), repeats included")
    @click.option("--study-budget", type=POSITIVE, default=120.0, show_default=True,
                  help="seconds for all the measured runs together (the references not "
                       "counted); what is left when they are spent is skipped, and listed")
    @click.option("--sweep-budget", type=POSITIVE, default=None,
                  help="seconds one method's sweep over the tolerances may take before its "
                       "tighter tolerances are skipped (default: the study budget shared "
                       "among the sweeps)")
    @click.option("--repeats", type=click.IntRange(1, 1000), default=3, show_default=True)
    @click.option("--long-run", type=POSITIVE, default=1.0, show_default=True,
                  help="a run longer than this many seconds is not repeated")
    @click.option("--ref-rtol", type=RTOL, default=1e-12, show_default=True)
    @click.option("--ref-methods", default=None,
                  help="two methods for the reference (default: C-Radau checked with "
                       "C-Rodas4 if stiff, else C-DOP853; without a C compiler Radau,BDF if "
                       "stiff, else Radau,DOP853)")
    @click.option("--ref-budget", type=POSITIVE, default=300.0, show_default=True)
    @click.option("--jac-methods", default="Radau,BDF", show_default=True,
                  help="methods for the analytic-vs-FD Jacobian comparison ('' for none)")
    @click.option("--jac-tols", default="1e-4,1e-6,1e-8", show_default=True)
    @click.option("--t-end", type=finite(), default=None, help="stop the scene early (s)")
    @click.option("--breakpoints", "extra_bps", default="",
                  help="comma-separated instants where inputs jump, added to the scene's")
    @click.option("--workers", type=click.IntRange(1, 1024), default=None,
                  help="run the study's runs as Dask tasks on a local cluster of this many "
                       "worker processes (default: one after another, here)")
    @click.option("--scheduler", default=None,
                  help="run them on this running Dask scheduler instead")
    @click.option("-q", "--quiet", is_flag=True)
    def accuracy_cmd(scene, out_dir, methods, tols, atol_scale, budget, study_budget,
                     sweep_budget, repeats, long_run, ref_rtol, ref_methods, ref_budget,
                     jac_methods, jac_tols, t_end, extra_bps, workers, scheduler, quiet):
        """Work-precision study of SCENE.yaml: error against wall time and rhs calls.

        The default study is a first look that finishes in a few minutes: the references on
        the C backend where a compiler works, each method's sweep stopped once it has taken
        its share of --study-budget, long runs not repeated; the summary lists what was
        skipped and why."""
        say = Progress(quiet)
        ms = parse_methods(methods)
        if methods == _DEFAULT_METHODS and not c_available():
            ms = tuple(m for m in ms if m not in C_METHODS)
            say("no C compiler or C runtime: the C methods are left out")
        tl = parse_tols(tols)
        rms = parse_methods(ref_methods) if ref_methods else None
        if rms is not None and len(rms) != 2:
            raise ModelError(None, "--ref-methods: give two methods")
        jms = parse_methods(jac_methods, FD_JACOBIAN) if jac_methods.strip() else ()
        jtl = parse_tols(jac_tols, "--jac-tols") if jms else ()
        if not budget > 0 or repeats < 1 or not 0 < ref_rtol < 1:
            raise ModelError(None, "--budget and --ref-rtol must be positive, --repeats >= 1")
        say(f"compiling {scene}")
        try:
            bps = tuple(float(b) for b in extra_bps.split(",") if b.strip())
        except ValueError:
            raise ModelError(None, f"--breakpoints {extra_bps!r}: give numbers") from None
        if not all(math.isfinite(b) for b in bps):
            raise ModelError(None, f"--breakpoints {extra_bps!r}: give finite numbers")
        sc = parse_scene(scene)
        # '' is refused as an empty path (Path('') would be '.'), not taken as the default
        out = f"accuracy_{Path(sc.file).stem}" if out_dir is None else out_dir
        check_folder(out_folder(out, "--out", create=False), "--out")  # before the study
        out = Path(out)
        setup = prepare(sc, t_end=t_end, atol_scale=atol_scale, breakpoints=bps)
        inputs = model_inputs(scene, sc.model_path)  # the model has parsed: its imports

        check_start(setup.compiled, setup.module, sc, setup.p)  # nan or inf at t0: one line
        client = None
        if workers is not None or scheduler is not None:
            client = client_for(scheduler or "local", workers)
        try:
            with np.errstate(all="ignore"):  # (inherited by the forked runs)
                st = study(setup, ms, tl, budget, repeats, ref_rtol, rms, ref_budget, jms, jtl,
                           say, client, study_budget=study_budget, sweep_budget=sweep_budget,
                           long_run=long_run)
        finally:
            if client is not None:
                # lazy: Dask loads only for a study on workers
                from bgc.studies.sweep import close_client

                close_client(client)
        for f in write_all(st, out, inputs):
            say(f"wrote {f}")
        _summary(st)

    return accuracy_cmd


def _summary(st):
    """The study's last lines: what was skipped and why, the references' agreement and the
    cheapest runs."""
    a = st.agreement
    skipped = skipped_lines(st)
    if skipped:
        click.echo("skipped:\n" + "\n".join(f"  {line}" for line in skipped))
    click.echo(f"{st.setup.name}: reference agreement {a['err']:.2e}; "
               + "; ".join(f"error <= {t:.0e}: {r.method} rtol {r.rtol:.0e} {r.wall:.3g} s"
                           for t in (1e-3, 1e-6) if (r := cheapest(st.runs, t))))
