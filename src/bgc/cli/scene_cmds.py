"""The `bgc` commands on a scene (or a model): simulate, explain, linearize. Click commands that
bgc.cli.commands adds to the `bgc` group; what they run is imported inside them."""
from __future__ import annotations

import io
from pathlib import Path

import click
import numpy as np

from bgc.base import BACKENDS
from bgc.base.errors import ModelError
from bgc.cli.options import POSITIVE, model_inputs
from bgc.format.scene import METHODS as SOLVER_METHODS
from bgc.run.progress import Progress


@click.command("simulate")
@click.argument("scene", type=click.Path())  # (as MODEL: bgc.base.safeio)
@click.option("--out", type=click.Path(), help="results .npz (t and outputs)")
@click.option("--plot", "plot_dir", type=click.Path(), help="write PNG plots here")
@click.option("--method", type=click.Choice(SOLVER_METHODS), default=None,
              help="override the scene's solver method (Rodas4: the generated module's own)")
@click.option("--rtol", type=float, default=None,
              help="relative tolerance, finite, within the limit of tolerances (1e-14..1)")
@click.option("--atol", type=POSITIVE, default=None,
              help="absolute tolerance (default: the scene's solver atol)")
@click.option("--max-wall", type=POSITIVE, default=None,
              help="stop with an error once the integration has taken this many seconds")
@click.option("--backend", type=click.Choice(BACKENDS), default=None,
              help="numpy module, or C (the step loop in a compiled library); default: the "
                   "scene's solver backend, else numpy")
@click.option("--no-cache", is_flag=True, help="compile afresh, without the compile cache")
@click.option("--strict-causality", is_flag=True,
              help="refuse derivative causality (every storage element independent) instead of "
                   "eliminating the dependent storage elements")
@click.option("-q", "--quiet", is_flag=True)
def simulate_cmd(scene, out, plot_dir, method, rtol, atol, max_wall, backend, no_cache,
                 strict_causality, quiet):
    """Compile the scene's model (or take it from the compile cache) and simulate the scene."""
    from bgc.base.outfiles import check_folder, check_output, write_output
    from bgc.format.scene import check_rtol, parse_scene
    from bgc.run.runner import run_scene

    if rtol is not None:  # finite, within the limits (bgc.base.limits): one line, exit 2
        check_rtol(rtol, None, "--rtol")
    prog = Progress(quiet)
    sc = parse_scene(scene)
    if out:  # refused before the run, not after it (the imports are known after it)
        check_output(out, model_inputs(scene, sc.model_path, follow=False), "--out")
    if plot_dir is not None:
        check_folder(plot_dir, "--plot")
    res = run_scene(sc, progress=prog, method=method, rtol=rtol, max_wall=max_wall,
                    atol=atol, backend=backend, use_cache=not no_cache,
                    strict_causality=strict_causality)
    ins = model_inputs(scene, sc.model_path)
    figures = None
    if plot_dir is not None:  # every figure drawn before anything is written
        from bgc.run.plots import render_plots, write_plots

        figures = render_plots(res.scene, res.t, res.y,
                               getattr(res.module, "OUTPUT_UNITS", None))
    if out:
        from bgc.run.event_log import event_arrays  # a hybrid model's event log

        buf = io.BytesIO()
        np.savez_compressed(buf, t=res.t, **res.y, **event_arrays(res.events, res.x.shape[0]))
        write_output(out, buf.getvalue(), ins, "--out")
        prog(f"wrote {out}")
    if plot_dir is not None:
        for p in write_plots(res.scene, res.t, res.y, plot_dir, ins, figures):
            prog(f"wrote {p}")
    if not no_cache:  # a later run of the same scene and options replays it (bgc.run.record)
        from bgc.run.record import keep, options_text

        keep(scene, options_text(method, rtol, atol, max_wall, backend, strict_causality), res)
    from bgc.run.progress import summary_line

    click.echo(summary_line(res.scene.name, res.t, res.method, res.rtol, res.atol, res.backend,
                            res.stats, res.compile_time, res.run_time))


@click.command("explain")
@click.argument("scene", type=click.Path())  # (as MODEL: bgc.base.safeio)
@click.option("--rounds", type=click.IntRange(1, 100), default=7, show_default=True,
              help="interleaved timing rounds of the rhs (the median is shown)")
@click.option("-q", "--quiet", is_flag=True)
def explain_cmd(scene, rounds, quiet):
    """Full model against SCENE's specialisation: states, operations, cost of one rhs call."""
    from bgc.run.runner import explain_scene

    prog = Progress(quiet)
    ex = explain_scene(scene, progress=prog)
    prog("timing the rhs")
    kept, removed = ex.states
    (ofull, ospec), (cfull, cspec) = ex.ops(), ex.rhs_cost(rounds)
    sc = ex.scene
    out = io.StringIO()
    out.write(f"scene {sc.name}: model {ex.full.model.name} ({sc.model_path})\n")
    if ex.same:
        out.write("the scene changes nothing: its module is the full model\n")
    w = 24

    def row(label, a, b, fmt="{}"):
        ratio = f"{b / a:.2f}" if a else "-"
        out.write(f"  {label:<{w}} {fmt.format(a):>10} {fmt.format(b):>10} {ratio:>7}\n")

    out.write(f"  {'':<{w}} {'full':>10} {'scene':>10} {'ratio':>7}\n")
    row("states", len(ex.full_module.STATE_NAMES), len(kept))
    row("outputs", len(ex.full_module.OUTPUT_NAMES), len(ex.module.OUTPUT_NAMES))
    row("rhs operations", ofull["rhs"], ospec["rhs"])
    row("jacobian operations", ofull["jacobian"], ospec["jacobian"])
    row("Jacobian nonzeros", len(ex.full.equations.jacobian), len(ex.special.equations.jacobian))
    row("rhs call [us]", cfull * 1e6, cspec * 1e6, "{:.1f}")
    out.write(f"  compile: full {ex.compile_time[0]:.2f} s, scene {ex.compile_time[1]:.2f} s\n")
    out.write(f"\nstates kept ({len(kept)}): {', '.join(kept) or 'none'}\n")
    out.write(f"states removed ({len(removed)}): {', '.join(removed) or 'none'}\n")
    if ex.special.notes:
        out.write("\nwhat the scene changed (as in the module's header):\n")
        for note in ex.special.notes:
            out.write(f"  - {note}\n")
    out.write(f"\n(operations after CSE, counted in the generated code; rhs cost: median of "
              f"{rounds} interleaved rounds at the initial state, default parameters)\n")
    click.echo(out.getvalue(), nl=False)


def _load_target(path, prog):
    """A scene file (its specialised module, parameters and span) or a model file."""
    from bgc.linear import load_target

    return load_target(path, prog)


@click.command("linearize", epilog="Example: bgc linearize models/quarter_car.yaml --at "
              "equilibrium --out lin/ --bode zr:body_height   (docs/api.md)")
@click.argument("target", metavar="SCENE_OR_MODEL", type=click.Path())
@click.option("--at", "at", default="equilibrium", show_default=True,
              help="'equilibrium' (inputs held at their t0 values), or a TIME: the state a "
                   "run from the initial state reaches then")
@click.option("--out", type=click.Path(file_okay=False),
              help="write NAME_linear.npz (A, B, C, D, names, eigenvalues) and Bode PNGs here")
@click.option("--bode", multiple=True, metavar="IN:OUT",
              help="a Bode plot of input IN to output OUT (names as in INPUT_LABELS, "
                   "OUTPUT_LABELS); repeatable; needs --out")
@click.option("-q", "--quiet", is_flag=True)
def linearize_cmd(target, at, out, bode, quiet):
    """Linearise SCENE_OR_MODEL: eigenvalues with natural frequencies and damping ratios and
    the states that dominate each mode; matrices and Bode plots with --out."""
    from bgc.linear import bode_plot, modes, operating_point

    prog = Progress(quiet)
    mod, p, t0, sc = _load_target(target, prog)
    pairs = []
    for spec in bode:
        i_name, sep, o_name = spec.partition(":")
        if not sep or i_name not in mod.INPUT_LABELS or o_name not in mod.OUTPUT_LABELS:
            raise ModelError(None, f"--bode {spec!r}: give IN:OUT with IN one of "
                                   f"{', '.join(mod.INPUT_LABELS) or '(no inputs)'} and OUT "
                                   f"one of {', '.join(mod.OUTPUT_LABELS)}")
        pairs.append((i_name, o_name))
    from bgc.base.errors import Coord
    from bgc.cli import guards

    coord = sc.coord if sc is not None and getattr(sc, "coord", None) else Coord(str(target), 1, 1)
    with np.errstate(all="ignore"):
        try:
            t, x, where = operating_point(mod, at, p, None, t0, prog, " after Newton): "
                                          "linearise at a time instead (--at TIME)")
        except (np.linalg.LinAlgError, ValueError, FloatingPointError) as exc:
            raise ModelError(coord, f"no operating point found: the search failed ({exc}); is "
                                    "the right-hand side finite near the initial state?") from None
    lin = guards.linearization(mod, t, x, p, coord, where)
    ms = modes(lin[0], mod.STATE_NAMES)
    buf = io.StringIO()
    buf.write(f"linearised at {where}: {mod.N_STATES} states, {len(mod.INPUT_LABELS)} inputs, "
              f"{len(mod.OUTPUT_LABELS)} outputs\n")
    buf.write(f"{'eigenvalue [1/s]':>30}  {'wn [rad/s]':>11}  {'f [Hz]':>10}  {'damping':>8}"
              "  dominant states\n")
    for md in ms:
        lam = md.eigenvalue
        ev = f"{lam.real:.4g}" + (f" +/- {lam.imag:.4g}j" if lam.imag > 0 else "")
        dom = ", ".join(f"{nm} ({w:.2f})" for nm, w in md.states)
        zeta = "-" if md.wn == 0 else f"{md.zeta:.3f}"  # a zero eigenvalue has none
        buf.write(f"{ev:>30}  {md.wn:11.4g}  {md.hz:10.4g}  {zeta:>8}  {dom}\n")
    click.echo(buf.getvalue(), nl=False)
    if pairs and not out:
        raise ModelError(None, "--bode needs --out DIR for its plots")
    if out:
        d = Path(out)
        d.mkdir(parents=True, exist_ok=True)
        name = getattr(mod, "__name__", "model").removeprefix("bgc_generated_")
        npz = d / f"{name}_linear.npz"
        data = io.BytesIO()
        np.savez(data, A=lin[0], B=lin[1], C=lin[2], D=lin[3], t=t, x=x,
                 states=np.array(mod.STATE_NAMES), inputs=np.array(mod.INPUT_LABELS, dtype=str),
                 outputs=np.array(mod.OUTPUT_LABELS),
                 eigenvalues=np.linalg.eigvals(lin[0]))
        tmp = npz.with_name(f".{npz.name}.tmp")
        tmp.write_bytes(data.getvalue())
        tmp.replace(npz)
        prog(f"wrote {npz}")
        iu, ou = dict(getattr(mod, "INPUT_UNITS", {})), dict(getattr(mod, "OUTPUT_UNITS", {}))
        for i_name, o_name in pairs:
            png = d / f"bode_{i_name}_{o_name}.png".replace("[", "_").replace("]", "")
            tmp = png.with_name(f".{png.stem}.tmp.png")
            bode_plot(tmp, lin, mod.INPUT_LABELS.index(i_name), mod.OUTPUT_LABELS.index(o_name),
                      i_name, o_name, iu.get(i_name.split("[")[0], ""),
                      ou.get(o_name.split("[")[0], ""))
            tmp.replace(png)
            prog(f"wrote {png}")
