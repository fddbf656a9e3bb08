"""The `bgc` commands on a scene (or a model): simulate, explain, linearize. Click commands that
bgc.cli.commands adds to the `bgc` group; what they run is imported inside them."""
from __future__ import annotations

import io
import os

import click

from bgc.base import BACKENDS
from bgc.base.errors import Coord, ModelError
from bgc.base.outfiles import check_folder, check_output, write_output
from bgc.cli.options import POSITIVE, LazyChoice, model_inputs
from bgc.run.progress import Progress, summary_line


def _solver_methods():
    # lazy: the scene format's module (YAML, the parser) only once --method is read
    from bgc.format.scene import METHODS

    return METHODS


@click.command("simulate")
@click.argument("scene", type=click.Path())  # (as MODEL: bgc.base.safeio)
@click.option("--t-end", type=float, default=None,
              help="end time in s (default: the scene's; a model alone runs 10 s)")
@click.option("--max-steps", type=int, default=None,
              help="the most steps the run may take (default: the scene's solver max_steps, "
                   "else 50000)")
@click.option("--out", type=click.Path(), help="results .npz (t and outputs)")
@click.option("--plot", "plot_dir", type=click.Path(), help="write PNG plots here")
@click.option("--method", type=LazyChoice(_solver_methods), default=None,
              help="override the scene's solver method (Rodas4: the generated module's own; "
                   "auto: DOP853, or Radau where a stiffness probe finds the model stiff)")
@click.option("--rtol", type=float, default=None,
              help="relative tolerance, finite, within the limit of tolerances (1e-14..1)")
@click.option("--atol", type=POSITIVE, default=None,
              help="absolute tolerance, in each state's unit (default: the scene's solver "
                   "atol; without one 1e-9, tightened by a second run where a state stays "
                   "small next to it, e.g. a microfarad's charge)")
@click.option("--max-wall", type=POSITIVE, default=None,
              help="stop with an error once the integration has taken this many seconds")
@click.option("--backend", type=click.Choice(BACKENDS), default=None,
              help="numpy module, or C (the step loop in a compiled library); default: the "
                   "scene's solver backend, else c where a C compiler works and the method's "
                   "step loop runs in C (Radau, Rodas4, DOP853), else numpy")
@click.option("--no-cache", is_flag=True, help="compile afresh, without the compile cache")
@click.option("--strict-causality", is_flag=True,
              help="refuse derivative causality (every storage element independent) instead of "
                   "eliminating the dependent storage elements")
@click.option("-q", "--quiet", is_flag=True)
def simulate_cmd(scene, t_end, max_steps, out, plot_dir, method, rtol, atol, max_wall, backend,
                 no_cache, strict_causality, quiet):
    """Compile the scene's model (or take it from the compile cache) and simulate the scene.
    SCENE may also be a model file: it runs with its defaults for 10 s (or --t-end)."""
    import numpy as np

    # lazy: what this command runs; `bgc --help` and the other commands never load it
    from bgc.format.scene import check_rtol
    from bgc.run.event_log import event_arrays
    from bgc.run.plots import render_plots, write_plots
    from bgc.run.record import keep, options_text
    from bgc.run.runner import run_scene

    if rtol is not None:  # finite, within the limits (bgc.base.limits): one line, exit 2
        check_rtol(rtol, None, "--rtol")
    prog = Progress(quiet)
    sc = _scene_or_model(scene, t_end, max_steps, prog)
    if out is not None:  # refused before the run (the imports are known after it); '' too
        check_output(out, model_inputs(scene, sc.model_path, follow=False), "--out")
    if plot_dir is not None:
        # lazy: the compile path, which a warm run never loads
        from bgc.base.outdirs import out_folder

        check_folder(out_folder(plot_dir, "--plot", create=False), "--plot")
    res = run_scene(sc, progress=prog, method=method, rtol=rtol, max_wall=max_wall,
                    atol=atol, backend=backend, use_cache=not no_cache,
                    strict_causality=strict_causality, max_steps=max_steps,
                    choose_backend=True)
    ins = model_inputs(scene, sc.model_path)
    figures = None
    if plot_dir is not None:  # every figure drawn before anything is written

        figures = render_plots(res.scene, res.t, res.y,
                               getattr(res.module, "OUTPUT_UNITS", None))
    if out is not None:
        buf = io.BytesIO()
        np.savez_compressed(buf, t=res.t, **res.y, **event_arrays(res.events, res.x.shape[0]))
        write_output(out, buf.getvalue(), ins, "--out")
        prog(f"wrote {out}")
    if plot_dir is not None:
        for p in write_plots(res.scene, res.t, res.y, plot_dir, ins, figures):
            prog(f"wrote {p}")
    if not no_cache:  # a later run of the same scene and options replays it (bgc.run.record)

        keep(scene, options_text(method, rtol, atol, max_wall, backend, strict_causality,
                                 t_end=t_end, max_steps=max_steps), res)

    click.echo(summary_line(res.scene.name, res.t, res.method, res.rtol, res.atol, res.backend,
                            res.stats, res.compile_time, res.run_time, res.backend_why))
    if os.environ.get("BGC_STAGE_TIMES"):  # where the compile went (bench/bench_scale.py)
        click.echo("stages: " + ", ".join(f"{s} {t:.2f} s" for s, t in res.stage_times),
                   err=True)


def _scene_or_model(path, t_end, max_steps, say):
    """The scene file at path, or a model file as the scene of its defaults (bgc simulate
    MODEL.yaml); --t-end and --max-steps checked (one located line each)."""
    # lazy: the scene format's module, for the commands that read a scene
    from bgc.format.scene import (
        MODEL_T_END,
        check_max_steps,
        is_model_file,
        model_scene,
        parse_scene,
        with_t_end,
    )

    if max_steps is not None:
        check_max_steps(max_steps, None, "--max-steps")
    if is_model_file(path):
        say(f"{path} is a model: simulating it with its defaults from 0 to "
            f"{MODEL_T_END if t_end is None else t_end:g} s (a scene file chooses more)")
        sc = model_scene(path)
    else:
        sc = parse_scene(path)
    return sc if t_end is None else with_t_end(sc, t_end)


@click.command("explain")
@click.argument("scene", type=click.Path())  # (as MODEL: bgc.base.safeio)
@click.option("--rounds", type=click.IntRange(1, 100), default=7, show_default=True,
              help="interleaved timing rounds of the rhs (the median is shown)")
@click.option("-q", "--quiet", is_flag=True)
def explain_cmd(scene, rounds, quiet):
    """Full model against SCENE's specialisation: states, operations, cost of one rhs call."""
    # lazy: what this command runs; `bgc --help` and the other commands never load it
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
    # lazy: the compile path, which a warm run never loads
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
@click.option("--freq-range", nargs=2, type=POSITIVE, default=None, metavar="FMIN FMAX",
              help="the Bode plots' frequencies in Hz (default: two decades around the modes' "
                   "natural frequencies, near-zero eigenvalues ignored)")
@click.option("--x0", "x0_items", multiple=True, metavar="NAME=VALUE",
              help="the start (the equilibrium's initial guess, or the run's start): a state "
                   "of the module's STATE_NAMES set to VALUE; repeatable (default: the "
                   "scene's `initial:` values, else the initial state)")
@click.option("-q", "--quiet", is_flag=True)
def linearize_cmd(target, at, out, bode, freq_range, x0_items, quiet):
    """Linearise SCENE_OR_MODEL: eigenvalues with natural frequencies and damping ratios and
    the states that dominate each mode; matrices and Bode plots with --out."""
    import numpy as np

    # lazy: the compile path, which a warm run never loads
    from bgc.format.scene import initial_state
    from bgc.linear import modes, on_manifold, operating_point, point_warnings, start_guess

    prog = Progress(quiet)
    mod, p, t0, sc = _load_target(target, prog)
    base = initial_state(sc, mod, p) if sc is not None and isinstance(sc.initial, dict) else None
    guess = start_guess(mod, p, x0_items, base)
    pairs = []
    for spec in bode:
        i_name, sep, o_name = spec.partition(":")
        if not sep or i_name not in mod.INPUT_LABELS or o_name not in mod.OUTPUT_LABELS:
            raise ModelError(None, f"--bode {spec!r}: give IN:OUT with IN one of "
                                   f"{', '.join(mod.INPUT_LABELS) or '(no inputs)'} and OUT "
                                   f"one of {', '.join(mod.OUTPUT_LABELS)}")
        pairs.append((i_name, o_name))
    if pairs and out is None:
        raise ModelError(None, "--bode needs --out DIR for its plots")
    plan = None
    if out is not None:  # refused before anything is computed ('' too: an empty path)
        # lazy: the compile path, which a warm run never loads
        from bgc.cli.outputs import check_linear

        plan = check_linear(out, mod, pairs, target, sc)
    # lazy: the compile path, which a warm run never loads
    from bgc.cli import guards

    coord = sc.coord if sc is not None and getattr(sc, "coord", None) else Coord(str(target), 1, 1)
    found = []
    with np.errstate(all="ignore"):
        try:
            t, x, where = operating_point(mod, at, p, None, t0, prog, " after Newton): "
                                          "linearise at a time instead (--at TIME)",
                                          x0=guess,
                                          on_equilibrium=found.append)
            settled = getattr(found[0], "settled", None) if found else None
            if found:
                _warn_free(found[0], prog)
            for msg in point_warnings(mod, t, x, p, None, guess, at == "equilibrium", settled):
                prog(f"warning: {msg}")
        except (np.linalg.LinAlgError, ValueError, FloatingPointError) as exc:
            raise ModelError(coord, f"no operating point found: the search failed ({exc}); is "
                                    "the right-hand side finite near the initial state?") from None
    if freq_range is not None and not freq_range[0] < freq_range[1]:
        raise ModelError(None, f"--freq-range {freq_range[0]:g} {freq_range[1]:g}: FMIN must "
                               "be below FMAX")
    lin = guards.linearization(mod, t, x, p, coord, where)
    _warn_unstable(lin[0], where, prog)
    red = on_manifold(mod, lin[0], lin[1], lin[2])
    ms = (modes(lin[0], mod.STATE_NAMES) if red is None
          else modes(red.A, mod.STATE_NAMES, basis=red.N))
    buf = io.StringIO()
    buf.write(f"linearised at {where}: {mod.N_STATES} states, {len(mod.INPUT_LABELS)} inputs, "
              f"{len(mod.OUTPUT_LABELS)} outputs\n")
    if red is not None:
        buf.write(f"{red.note}\n")
    buf.write(f"{'eigenvalue [1/s]':>30}  {'wn [rad/s]':>11}  {'f [Hz]':>10}  {'damping':>8}"
              "  dominant states\n")
    for md in ms:
        lam = md.eigenvalue
        ev = f"{lam.real:.4g}" + (f" +/- {lam.imag:.4g}j" if lam.imag > 0 else "")
        dom = ", ".join(f"{nm} ({w:.2f})" for nm, w in md.states)
        zeta = "-" if md.wn == 0 else f"{md.zeta:.3f}"  # a zero eigenvalue has none
        buf.write(f"{ev:>30}  {md.wn:11.4g}  {md.hz:10.4g}  {zeta:>8}  {dom}\n")
    click.echo(buf.getvalue(), nl=False)
    if plan is not None:
        # lazy: the compile path, which a warm run never loads
        from bgc.cli.outputs import write_linear

        plan["f_range"] = freq_range
        write_linear(plan, mod, lin, t, x, prog)


def _warn_free(info, say) -> None:
    """A warning when the equilibrium is not isolated: directions along which no stiffness
    holds the state (they keep the initial state's values, which the model's geometry may not
    agree with: a closing spring's deflection and the angles it ties together)."""
    free = [d for d in (info.free or []) if d]
    settled = getattr(info, "settled", None)
    if free and settled is not None:
        say(f"the equilibrium is not isolated ({len(free)} free direction(s)): reached by "
            f"letting the damped dynamics come to rest from the initial state ({settled:.3g} s), "
            "then Newton's minimum-norm steps, so the states the geometry ties together (a "
            "closing spring's deflection and the angles) stay consistent")
    elif free:
        names = ", ".join(sorted({nm for d in free for nm in d})[:6])
        say(f"warning: the equilibrium is not isolated: {len(free)} free direction(s) ("
            f"{names}) keep their initial values; check they agree with the model's geometry, "
            "or start from a consistent state (bgc.linearize(..., x0=...))")


def _warn_unstable(A, where, say) -> None:
    """A warning line when the linearisation has growing modes (an equilibrium that is not
    stable, or not an equilibrium the model can hold)."""
    # lazy: the compile path, which a warm run never loads
    from bgc.linear import unstable_modes

    grow = unstable_modes(A)
    if grow:
        lam = ", ".join(f"{v.real:+.3g}" + (f"+/-{v.imag:.3g}j" if v.imag > 0 else "")
                        for v in grow[:4])
        say(f"warning: {len(grow)} unstable mode(s) at {where} (eigenvalue {lam} 1/s): the "
            "state grows away from it; check that it is the equilibrium you meant (an initial "
            "guess: bgc.linearize(..., x0=...))")
