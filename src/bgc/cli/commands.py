"""Command line: a thin layer over the pipeline. User errors: one located line, exit 2."""
from __future__ import annotations

import errno
import io
import os
import sys
import traceback
from pathlib import Path

import click
import numpy as np

from bgc.base import __version__
from bgc.base.errors import ModelError, SimulationFailed
from bgc.cli.options import POSITIVE
from bgc.cli.options import model_inputs as _model_inputs
from bgc.format.scene import METHODS as SOLVER_METHODS
from bgc.run.progress import (
    Progress as _Progress,  # the replay (bgc.run.record) prints the same lines
)

#: Exit statuses (README, "Errors"): 0 ok; 1 the simulation failed (numerically, or was
#: stopped); 2 a model, scene or usage error; 3 an internal error of bgc.
EXIT_FAILED_RUN, EXIT_USER, EXIT_INTERNAL = 1, 2, 3


def _fail(exc: ModelError, status: int = EXIT_USER):
    click.echo(f"error: {exc}" if exc.coord is None else str(exc), err=True)
    sys.exit(status)


def _debug() -> bool:
    return os.environ.get("BGC_DEBUG", "") not in ("", "0")


def _internal(exc: BaseException):
    """An exception bgc did not expect: one line saying so (the traceback with BGC_DEBUG=1)."""
    from bgc.base.errors import oneline

    if _debug():
        traceback.print_exc()
    what = oneline(f"{type(exc).__name__}: {exc}", 300)
    click.echo(f"bgc: internal error ({what}); this is a bug in bgc, please report it with the "
               "command and its input files (BGC_DEBUG=1 shows the traceback)", err=True)
    sys.exit(EXIT_INTERNAL)


class _Group(click.Group):
    """Catches user errors; registers the commands that live in heavy modules (`bgc accuracy`,
    `bgc sweep`) only when asked for, so a warm `bgc simulate` never imports them."""

    def get_command(self, ctx, name):
        if name in _LAZY and name not in self.commands:
            _LAZY[name]()
        return super().get_command(ctx, name)

    def list_commands(self, ctx):
        for name, register in _LAZY.items():
            if name not in self.commands:
                register()
        return super().list_commands(ctx)

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True,
             **extra):
        """A usage error is one line too (click prints three): ``error: ...``, exit 2."""
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, False, **extra)
        try:
            rv = super().main(args, prog_name, complete_var, False, **extra)
        except click.UsageError as exc:
            from bgc.base.errors import oneline

            hint = f" (see '{exc.ctx.command_path} --help')" if exc.ctx is not None else ""
            click.echo(f"error: {oneline(exc.format_message(), 400)}{hint}", err=True)
            sys.exit(exc.exit_code)
        except click.ClickException as exc:
            from bgc.base.errors import oneline

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
            if _debug():
                traceback.print_exc()
            _fail(exc, EXIT_FAILED_RUN)
        except ModelError as exc:
            if _debug():
                traceback.print_exc()
            _fail(exc)
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
            if _debug():
                traceback.print_exc()
            from bgc.base.errors import oneline

            where = f" {exc.filename!r}" if exc.filename is not None else ""
            click.echo(f"error:{oneline(where, 240)} {exc.strerror or exc}", err=True)
            sys.exit(EXIT_USER)
        except Exception as exc:  # noqa: BLE001 - the catch-all: exit 3, one line
            _internal(exc)


@click.group(cls=_Group)
@click.version_option(__version__, prog_name="bgc")
def main():
    """bgc: compile bond graphs (YAML) into standalone numpy simulation modules."""


@main.command("compile")
@click.argument("model", type=click.Path())  # bgc.base.safeio refuses folders, FIFOs, devices (located)
@click.option("-o", "--output", type=click.Path(), help="module to write "
              "(default: generated/<name>.py beside the models folder, or ./<name>.py; with "
              "--scene: ./<name>_<scene>.py)")
@click.option("--scene", type=click.Path(dir_okay=False),
              help="specialise for this scene (its signals, effects, parameters, outputs)")
@click.option("--target", type=click.Choice(("numpy", "c")), default="numpy", show_default=True,
              help="numpy: one Python module; c: C sources, a wrapper module and the built "
                   "library in the folder -o")
@click.option("--no-cache", is_flag=True, help="do not use the compile cache (C runtime objects)")
@click.option("--strict-causality", is_flag=True,
              help="refuse derivative causality (every storage element independent) instead of "
                   "eliminating the dependent storage elements")
@click.option("-q", "--quiet", is_flag=True)
def compile_cmd(model, output, scene, target, no_cache, quiet, strict_causality):
    """Compile MODEL.yaml into a Python module (or, --target c, C sources and a library)."""
    from bgc.base.outfiles import write_output
    from bgc.format.parse import parse_file
    from bgc.run.driver import compile_model

    prog = _Progress(quiet)
    prog("parsing")
    if scene:
        from bgc.core.graph import build_graph
        from bgc.core.specialize import plan_for
        from bgc.format.scene import apply_scene, check_outputs, parse_scene

        sc = parse_scene(scene)
        if Path(sc.model_path).resolve() != Path(model).resolve():
            raise ModelError(sc.model_coord, f"the scene is for {sc.model_path}, not {model}")
        m = apply_scene(parse_file(model), sc)
        c = compile_model(m, prog, plan_for(sc, build_graph(m).params),
                          strict_causality=strict_causality)
        check_outputs(sc, [o[0] for o in c.equations.outputs])
        if output is None:
            output = Path(f"{c.model.name}_{sc.name}.py")
    else:
        c = compile_model(parse_file(model), prog, strict_causality=strict_causality)
    if target == "c":
        from bgc.backends import load as backends
        from bgc.backends.c import build as cbuild
        from bgc.run import cache as cache_mod

        if output is None:
            raise ModelError(None, "--target c writes a folder: give it with -o OUTDIR")
        cbuild.identity()  # a clear message without a compiler
        path = backends.write_c(c, output, None if no_cache else cache_mod.Cache(), prog)
        prog(f"wrote {output}/ (C sources, {path.name}, {cbuild.LIB_NAME}): "
             f"{len(c.equations.states)} states, {len(c.equations.jacobian)} Jacobian entries")
        return
    if output is None:
        output = _default_output(Path(model), c.model.name)
    ins = _model_inputs(model, scene, sc.model_path if scene else None)
    from bgc.run.runner import check_module_start

    check_module_start(c)  # finite at X0 with the defaults, or a located error: nothing written
    write_output(output, c.source, ins, "-o")
    prog(f"wrote {output}: {len(c.equations.states)} states, "
         f"{len(c.equations.jacobian)} Jacobian entries")


def _default_output(model: Path, name: str) -> Path:
    parent = model.resolve().parent
    if parent.name == "models" and (parent.parent / "generated").is_dir():
        return parent.parent / "generated" / f"{name}.py"
    return Path(f"{name}.py")


@main.command("check")
@click.argument("model", type=click.Path())  # bgc.base.safeio refuses folders, FIFOs, devices (located)
@click.option("--strict-causality", is_flag=True,
              help="refuse derivative causality (every storage element independent) instead of "
                   "eliminating the dependent storage elements")
def check_cmd(model, strict_causality):
    """Check MODEL.yaml completely (up to the equations) and list causality, states, warnings."""
    from bgc.core.causality import assign_causality
    from bgc.core.equations import derive
    from bgc.core.graph import build_graph
    from bgc.format.parse import parse_file

    m = parse_file(model)
    bg = build_graph(m)
    strict = strict_causality or m.strict_causality
    caus = assign_causality(bg, allow_derivative=not strict)
    if caus.derivative:
        from bgc.core.causality import fixed_r_culprit

        culprit = fixed_r_culprit(bg, caus)
        if culprit is not None:
            raise ModelError(culprit[0], culprit[1])
    eqs = derive(bg, caus, newton=not strict)  # everything built and checked, as in compile
    out = io.StringIO()
    out.write(f"model {m.name}: {len(bg.elements)} elements, {len(bg.bonds)} bonds\n\n")
    out.write("causality (the stroke is at the end that receives the effort):\n")
    w = max((len(b.id) for b in bg.bonds), default=4)
    for b in bg.bonds:
        setter = caus.effort_by[b.id]
        recv = b.dst if setter == b.src else b.src
        card = f" [n={b.n}]" if b.n > 1 else ""
        out.write(f"  {b.id:<{w}}  {b.src} -> {b.dst}{card}: effort set by {setter}, "
                  f"stroke at {recv}\n")
    out.write("\nelements:\n")
    for el in bg.elements:
        if el.type in ("I", "C", "R", "TF", "MTF", "GY", "MGY"):
            out.write(f"  {el.type:<3} {el.id}: {caus.form(bg, el)}\n")
    states = []
    for el in bg.elements:
        if el.type in ("I", "C") and el.id not in caus.derivative:
            n = bg.bonds_of(el.id)[0].n
            states.append(f"{el.id}.{'p' if el.type == 'I' else 'q'}" + (f" ({n})" if n > 1 else ""))
    for st in bg.states:
        states.append(f"{st.id}" + (f" {list(st.shape)}" if st.shape else ""))
    out.write(f"\nstates ({len(eqs.states)} scalars):\n")
    for s in states:
        out.write(f"  {s}\n")
    all_integral = not caus.derivative
    out.write(f"\ncausality: {'all storage elements integral' if all_integral else 'derivative'}\n")
    if caus.derivative:
        from bgc.core.causality import dependent_report

        out.write(dependent_report(bg, caus, eqs))
    for loop in eqs.loops:
        out.write(f"note: {loop}\n")
    for wmsg in eqs.warnings:  # what the equations leave standing of causality's warnings
        out.write(f"warning: {wmsg}\n")
    click.echo(out.getvalue(), nl=False)


@main.command("graph")
@click.argument("model", type=click.Path())  # bgc.base.safeio refuses folders, FIFOs, devices (located)
@click.option("-o", "--output", required=True, type=click.Path(),
              help="FILE.dot, FILE.svg or FILE.png")
def graph_cmd(model, output):
    """Draw the bond graph with causal strokes (DOT; SVG/PNG through Graphviz)."""
    from bgc.base.outfiles import check_output, write_output
    from bgc.core.causality import assign_causality
    from bgc.core.draw import render_image, to_dot
    from bgc.core.graph import build_graph
    from bgc.format.parse import parse_file

    bg = build_graph(parse_file(model))
    caus = assign_causality(bg, allow_derivative=True)
    dot = to_dot(bg, caus)
    suffix = Path(output).suffix.lower()
    if suffix not in (".dot", ".svg", ".png"):
        raise ModelError(None, f"-o {output!r}: unknown drawing format {suffix!r}: use .dot, "
                               ".svg or .png")
    ins = _model_inputs(model)
    check_output(output, ins, "-o")  # before Graphviz runs
    data = dot if suffix == ".dot" else render_image(dot, suffix[1:])
    write_output(output, data, ins, "-o")
    click.echo(f"wrote {output}", err=True)


@main.command("simulate")
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
@click.option("--backend", type=click.Choice(("numpy", "c")), default=None,
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
    prog = _Progress(quiet)
    sc = parse_scene(scene)
    if out:  # refused before the run, not after it (the imports are known after it)
        check_output(out, _model_inputs(scene, sc.model_path, follow=False), "--out")
    if plot_dir is not None:
        check_folder(plot_dir, "--plot")
    res = run_scene(sc, progress=prog, method=method, rtol=rtol, max_wall=max_wall,
                    atol=atol, backend=backend, use_cache=not no_cache,
                    strict_causality=strict_causality)
    ins = _model_inputs(scene, sc.model_path)
    figures = None
    if plot_dir is not None:  # every figure drawn before anything is written
        from bgc.run.plots import render_plots, write_plots

        figures = render_plots(res.scene, res.t, res.y,
                               getattr(res.module, "OUTPUT_UNITS", None))
    if out:
        buf = io.BytesIO()
        np.savez_compressed(buf, t=res.t, **res.y)
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


@main.command("explain")
@click.argument("scene", type=click.Path())  # (as MODEL: bgc.base.safeio)
@click.option("--rounds", type=click.IntRange(1, 100), default=7, show_default=True,
              help="interleaved timing rounds of the rhs (the median is shown)")
@click.option("-q", "--quiet", is_flag=True)
def explain_cmd(scene, rounds, quiet):
    """Full model against SCENE's specialisation: states, operations, cost of one rhs call."""
    from bgc.run.runner import explain_scene

    prog = _Progress(quiet)
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
    from bgc.backends.load import load_module
    from bgc.format.parse import parse_file
    from bgc.format.scene import parse_scene
    from bgc.run.driver import compile_model

    from bgc.base.limits import LIMITS
    from bgc.base.safeio import read_text_bounded

    head = read_text_bounded(path, None, "model or scene file", LIMITS.model_bytes)[:4096]
    if "bgc_scene" in head:
        from bgc.run.runner import compile_scene, runtime_params

        sc = parse_scene(path)
        _, mod = compile_scene(sc, prog)
        return mod, runtime_params(sc, mod), sc.t_span[0], sc
    from bgc.run.runner import check_module_start

    c = compile_model(parse_file(path), prog)
    check_module_start(c)  # a zero mass, a root of a negative parameter: located here
    return load_module(c.source, c.model.name), None, 0.0, None


@main.command("linearize", epilog="Example: bgc linearize models/quarter_car.yaml --at "
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
    from bgc.linear import bode_plot, modes

    prog = _Progress(quiet)
    from bgc.base.errors import Coord
    from bgc.cli import guards

    mod, p, t0, sc = _load_target(target, prog)
    coord = sc.coord if sc is not None and getattr(sc, "coord", None) else Coord(str(target), 1, 1)
    pairs = []
    for spec in bode:
        i_name, sep, o_name = spec.partition(":")
        if not sep or i_name not in mod.INPUT_LABELS or o_name not in mod.OUTPUT_LABELS:
            raise ModelError(None, f"--bode {spec!r}: give IN:OUT with IN one of "
                                   f"{', '.join(mod.INPUT_LABELS) or '(no inputs)'} and OUT "
                                   f"one of {', '.join(mod.OUTPUT_LABELS)}")
        pairs.append((i_name, o_name))
    if at == "equilibrium":
        t = t0
        prog("finding the equilibrium")
        x, info = guards.equilibrium(mod, p, t, coord)
        if not info.converged:
            raise ModelError(None, f"no equilibrium found (max |dx/dt| = {info.residual:.3g} "
                                   "after Newton): linearise at a time instead (--at TIME)")
        where = "the equilibrium"
    else:
        try:
            t = float(at)
        except ValueError:
            raise ModelError(None, f"--at {at!r}: 'equilibrium' or a time in seconds") from None
        if t != t0:
            prog(f"simulating to t = {t:g} s")
            try:
                res = mod.simulate((t0, t), t_eval=[t], p=p, rtol=1e-8, atol=1e-10)
            except mod.SimulationError as exc:
                raise ModelError(None, f"simulation to t = {t:g} failed: {exc}") from None
            x = res.x[..., -1]
        else:
            x = mod.initial_state(p)
        where = f"t = {t:g} s"
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


@main.command("equations")
@click.argument("model", type=click.Path())  # bgc.base.safeio refuses folders, FIFOs, devices (located)
@click.option("--latex", is_flag=True, help="LaTeX (an aligned block) instead of plain text")
@click.option("--explicit", is_flag=True,
              help="substitute the causal assignments: dx/dt in states, parameters, inputs only")
def equations_cmd(model, latex, explicit):
    """The state equations of MODEL: the causal assignments, then dx/dt (sympy)."""
    from bgc.api import equations

    eq = equations(model)
    if latex:
        click.echo(eq.latex(explicit=explicit))
        return
    if explicit:
        for s, e in zip(eq.states, eq.explicit()):
            click.echo(f"d{s}/dt = {e}")
        return
    for a in eq.assignments:
        click.echo(f"{a.lhs} = {a.rhs}")
    for s, d in zip(eq.states, eq.derivatives):
        click.echo(f"d{s}/dt = {d.rhs}")


@main.command("examples")
@click.argument("directory", type=click.Path(file_okay=False))
def examples_cmd(directory):
    """Copy the example models and scenes (and the format reference) into DIRECTORY; nothing
    that already exists there is overwritten (then nothing is copied)."""
    import shutil

    files = _example_files()
    dest = Path(directory)
    clash = [rel for rel in files if (dest / rel).exists()]
    if clash:
        raise ModelError(None, f"{dest}: {len(clash)} file(s) exist already (e.g. {clash[0]}); "
                               "nothing copied: choose an empty or new directory")
    for rel, src in files.items():
        (dest / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, dest / rel)
    click.echo(f"copied {len(files)} files to {dest} (try: bgc simulate "
               f"{dest / 'models' / 'scenes' / 'msd_step.yaml'} --plot figs/)")


def _example_files() -> dict:
    """relative path -> source file: the repository's models/ and docs/model-format.md in a
    source checkout, else the installed copies (bgc.examples, bgc.docs)."""
    from bgc.base.paths import package_dir

    here = package_dir()  # src/bgc in a checkout, site-packages/bgc when installed
    root = here.parent.parent
    if (root / "models" / "msd.yaml").is_file():
        models, docs = root / "models", root / "docs"
    else:  # installed wheel: bgc/examples and bgc/docs beside the package's modules
        models, docs = here / "examples", here / "docs"
    out = {}
    for f in sorted(models.glob("*.yaml")):
        out[f"models/{f.name}"] = f
    for f in sorted((models / "scenes").glob("*")):
        if f.suffix in (".yaml", ".csv"):
            out[f"models/scenes/{f.name}"] = f
    for name in ("model-format.md", "api.md"):
        if (docs / name).is_file():
            out[f"docs/{name}"] = docs / name
    return out
@main.group("cache")
def cache_cmd():
    """The compile cache ($BGC_CACHE_DIR, else ~/.cache/bgc)."""


@cache_cmd.command("info")
def cache_info_cmd():
    """Where the cache is, how many entries per target, how many bytes."""
    from bgc.run.cache import Cache

    info = Cache().info()
    ents = ", ".join(f"{k} {v}" for k, v in info["entries"].items()) or "empty"
    click.echo(f"{info['path']}: {ents}; {info['bytes'] / 1e6:.1f} MB")


@cache_cmd.command("clear")
def cache_clear_cmd():
    """Remove every cache entry."""
    from bgc.run.cache import Cache

    c = Cache()
    n = c.clear()
    click.echo(f"{c.path}: removed {n} entries")


@main.command("export")
@click.argument("model", type=click.Path())  # bgc.base.safeio refuses folders, FIFOs, devices (located)
@click.option("--scene", type=click.Path(dir_okay=False),
              help="export the scene's specialised model (its signals, parameters, solver)")
@click.option("--fmu", "fmu_out", required=True, type=click.Path(dir_okay=False),
              help="the FMU to write (FMI 2.0)")
@click.option("--kind", type=click.Choice(("me", "cs", "both")), default="both",
              show_default=True, help="Model Exchange, Co-Simulation or both")
@click.option("-q", "--quiet", is_flag=True)
def export_cmd(model, scene, fmu_out, kind, quiet):
    """Export MODEL.yaml (or SCENE's specialised model) as an FMI 2.0 FMU."""
    from bgc.backends.c.build import CompilerMissing
    from bgc.run.fmu import export_fmu

    prog = _Progress(quiet)
    try:
        export_fmu(model, fmu_out, scene_path=scene, kind=kind, progress=prog)
    except CompilerMissing as exc:
        _fail(exc)


def _register_accuracy():
    """`bgc accuracy` lives in a heavy module: registered only when asked for (warm runs of
    other commands never import it)."""
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
    "sweep": "bgc sweep models/scenes/msd_sweep.yaml --out sweep.zarr --workers 2",
}
main.epilog = "\b\nExample:\n  bgc simulate models/scenes/msd_step.yaml --plot figs/\n\n" + _DOCS
for _name, _cmd in main.commands.items():
    if _name in _EXAMPLES:
        _cmd.epilog = f"\b\nExample:\n  {_EXAMPLES[_name]}\n\n{_DOCS}"


def _register_sweep():
    """`bgc sweep` (Dask, xarray, Zarr) is registered only when asked for, like accuracy."""
    from bgc.cli.sweep import register

    register(main)
    if "sweep" in _EXAMPLES:
        main.commands["sweep"].epilog = f"\b\nExample:\n  {_EXAMPLES['sweep']}\n\n{_DOCS}"


_LAZY = {"accuracy": _register_accuracy, "sweep": _register_sweep}


if __name__ == "__main__":  # pragma: no cover
    main()
