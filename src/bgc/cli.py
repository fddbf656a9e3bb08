"""Command line: a thin layer over the pipeline. User errors: one located line, exit 2."""
from __future__ import annotations

import io
import sys
import time
from pathlib import Path

import click
import numpy as np

from . import __version__
from .errors import ModelError
from .scene import METHODS as SOLVER_METHODS


class _Progress:
    def __init__(self, quiet: bool):
        self.quiet = quiet
        self.t0 = time.perf_counter()

    def __call__(self, msg: str) -> None:
        if not self.quiet:
            click.echo(f"[{time.perf_counter() - self.t0:6.2f} s] {msg}", err=True)


def _fail(exc: ModelError):
    click.echo(f"error: {exc}" if exc.coord is None else str(exc), err=True)
    sys.exit(2)


class _Group(click.Group):
    """Catches user errors; registers `bgc accuracy` (a heavy module) only when asked for."""

    def get_command(self, ctx, name):
        if name == "accuracy" and "accuracy" not in self.commands:
            _register_accuracy()
        return super().get_command(ctx, name)

    def list_commands(self, ctx):
        if "accuracy" not in self.commands:
            _register_accuracy()
        return super().list_commands(ctx)

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except ModelError as exc:
            _fail(exc)
        except RecursionError:
            click.echo("error: the model is nested too deeply", err=True)
            sys.exit(2)


@click.group(cls=_Group)
@click.version_option(__version__, prog_name="bgc")
def main():
    """bgc: compile bond graphs (YAML) into standalone numpy simulation modules."""


@main.command("compile")
@click.argument("model", type=click.Path(dir_okay=False))
@click.option("-o", "--output", type=click.Path(dir_okay=False), help="module to write "
              "(default: generated/<name>.py beside the models folder, or ./<name>.py; with "
              "--scene: ./<name>_<scene>.py)")
@click.option("--scene", type=click.Path(dir_okay=False),
              help="specialise for this scene (its signals, effects, parameters, outputs)")
@click.option("--target", type=click.Choice(("numpy", "c")), default="numpy", show_default=True,
              help="numpy: one Python module; c: C sources, a wrapper module and the built "
                   "library in the folder -o")
@click.option("--no-cache", is_flag=True, help="do not use the compile cache (C runtime objects)")
@click.option("-q", "--quiet", is_flag=True)
def compile_cmd(model, output, scene, target, no_cache, quiet):
    """Compile MODEL.yaml into a Python module (or, --target c, C sources and a library)."""
    from .compiler import compile_model, write_atomic
    from .parse import parse_file

    prog = _Progress(quiet)
    prog("parsing")
    if scene:
        from .graph import build_graph
        from .scene import apply_scene, check_outputs, parse_scene, plan_for

        sc = parse_scene(scene)
        if Path(sc.model_path).resolve() != Path(model).resolve():
            raise ModelError(sc.model_coord, f"the scene is for {sc.model_path}, not {model}")
        m = apply_scene(parse_file(model), sc)
        c = compile_model(m, prog, plan_for(sc, build_graph(m).params))
        check_outputs(sc, [o[0] for o in c.equations.outputs])
        if output is None:
            output = Path(f"{c.model.name}_{sc.name}.py")
    else:
        c = compile_model(parse_file(model), prog)
    if target == "c":
        from . import backends, cache as cache_mod, cbuild

        if output is None:
            raise ModelError(None, "--target c writes a folder: give it with -o OUTDIR")
        cbuild.identity()  # a clear message without a compiler
        path = backends.write_c(c, output, None if no_cache else cache_mod.Cache(), prog)
        prog(f"wrote {output}/ (C sources, {path.name}, {cbuild.LIB_NAME}): "
             f"{len(c.equations.states)} states, {len(c.equations.jacobian)} Jacobian entries")
        return
    if output is None:
        output = _default_output(Path(model), c.model.name)
    write_atomic(output, c.source)
    prog(f"wrote {output}: {len(c.equations.states)} states, "
         f"{len(c.equations.jacobian)} Jacobian entries")


def _default_output(model: Path, name: str) -> Path:
    parent = model.resolve().parent
    if parent.name == "models" and (parent.parent / "generated").is_dir():
        return parent.parent / "generated" / f"{name}.py"
    return Path(f"{name}.py")


@main.command("check")
@click.argument("model", type=click.Path(dir_okay=False))
def check_cmd(model):
    """Check MODEL.yaml completely (up to the equations) and list causality, states, warnings."""
    from .causality import assign_causality
    from .equations import derive
    from .graph import build_graph
    from .parse import parse_file

    m = parse_file(model)
    bg = build_graph(m)
    caus = assign_causality(bg)
    eqs = derive(bg, caus)  # every expression built and checked, as `bgc compile` would
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
        if el.type in ("I", "C"):
            n = bg.bonds_of(el.id)[0].n
            states.append(f"{el.id}.{'p' if el.type == 'I' else 'q'}" + (f" ({n})" if n > 1 else ""))
    for st in bg.states:
        states.append(f"{st.id}" + (f" {list(st.shape)}" if st.shape else ""))
    out.write(f"\nstates ({len(eqs.states)} scalars):\n")
    for s in states:
        out.write(f"  {s}\n")
    all_integral = not caus.derivative
    out.write(f"\ncausality: {'all storage elements integral' if all_integral else 'derivative'}\n")
    for loop in eqs.loops:
        out.write(f"note: {loop}\n")
    for wmsg in caus.warnings:
        out.write(f"warning: {wmsg}\n")
    click.echo(out.getvalue(), nl=False)


@main.command("graph")
@click.argument("model", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="FILE.dot, FILE.svg or FILE.png")
def graph_cmd(model, output):
    """Draw the bond graph with causal strokes (DOT; SVG/PNG through Graphviz)."""
    from .causality import assign_causality
    from .compiler import write_atomic
    from .draw import render_image, to_dot
    from .graph import build_graph
    from .parse import parse_file

    bg = build_graph(parse_file(model))
    caus = assign_causality(bg, allow_derivative=True)
    dot = to_dot(bg, caus)
    suffix = Path(output).suffix.lower()
    if suffix == ".dot":
        write_atomic(output, dot)
    elif suffix in (".svg", ".png"):
        data = render_image(dot, suffix[1:])
        tmp = Path(output).with_name(f".{Path(output).name}.tmp")
        tmp.write_bytes(data)
        tmp.replace(output)
    else:
        raise ModelError(None, f"unknown drawing format {suffix!r}: use .dot, .svg or .png")
    click.echo(f"wrote {output}", err=True)


@main.command("simulate")
@click.argument("scene", type=click.Path(dir_okay=False))
@click.option("--out", type=click.Path(dir_okay=False), help="results .npz (t and outputs)")
@click.option("--plot", "plot_dir", type=click.Path(file_okay=False), help="write PNG plots here")
@click.option("--method", type=click.Choice(SOLVER_METHODS), default=None,
              help="override the scene's solver method (Rodas4: the generated module's own)")
@click.option("--rtol", type=click.FloatRange(min=0.0, min_open=True), default=None)
@click.option("--atol", type=click.FloatRange(min=0.0, min_open=True), default=None,
              help="absolute tolerance (default: the scene's solver atol)")
@click.option("--max-wall", type=click.FloatRange(min=0.0, min_open=True), default=None,
              help="stop with an error once the integration has taken this many seconds")
@click.option("--backend", type=click.Choice(("numpy", "c")), default=None,
              help="numpy module, or C (the step loop in a compiled library); default: the "
                   "scene's solver backend, else numpy")
@click.option("--no-cache", is_flag=True, help="compile afresh, without the compile cache")
@click.option("-q", "--quiet", is_flag=True)
def simulate_cmd(scene, out, plot_dir, method, rtol, atol, max_wall, backend, no_cache, quiet):
    """Compile the scene's model (or take it from the compile cache) and simulate the scene."""
    from .runner import run_scene

    prog = _Progress(quiet)
    res = run_scene(scene, progress=prog, method=method, rtol=rtol, max_wall=max_wall,
                    atol=atol, backend=backend, use_cache=not no_cache)
    if out:
        buf = io.BytesIO()
        np.savez_compressed(buf, t=res.t, **res.y)
        tmp = Path(out).with_name(f".{Path(out).name}.tmp")
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        tmp.write_bytes(buf.getvalue())
        tmp.replace(out)
        prog(f"wrote {out}")
    if plot_dir:
        from .plots import write_plots

        for p in write_plots(res.scene, res.t, res.y, plot_dir):
            prog(f"wrote {p}")
    st = res.stats
    click.echo(f"{res.scene.name}: t = {res.t[0]:g}..{res.t[-1]:g} s, {len(res.t)} points, "
               f"{res.method} rtol={res.rtol:g} atol={res.atol:g} ({res.backend} backend): "
               f"{st['nfev']} rhs calls, {st['njev']} Jacobians, "
               f"{st.get('nlu', 0)} LU; compile {res.compile_time:.2f} s, "
               f"integrate {res.run_time:.2f} s")


@main.command("explain")
@click.argument("scene", type=click.Path(dir_okay=False))
@click.option("--rounds", type=click.IntRange(1, 100), default=7, show_default=True,
              help="interleaved timing rounds of the rhs (the median is shown)")
@click.option("-q", "--quiet", is_flag=True)
def explain_cmd(scene, rounds, quiet):
    """Full model against SCENE's specialisation: states, operations, cost of one rhs call."""
    from .runner import explain_scene

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


@main.group("cache")
def cache_cmd():
    """The compile cache ($BGC_CACHE_DIR, else ~/.cache/bgc)."""


@cache_cmd.command("info")
def cache_info_cmd():
    """Where the cache is, how many entries per target, how many bytes."""
    from .cache import Cache

    info = Cache().info()
    ents = ", ".join(f"{k} {v}" for k, v in info["entries"].items()) or "empty"
    click.echo(f"{info['path']}: {ents}; {info['bytes'] / 1e6:.1f} MB")


@cache_cmd.command("clear")
def cache_clear_cmd():
    """Remove every cache entry."""
    from .cache import Cache

    c = Cache()
    n = c.clear()
    click.echo(f"{c.path}: removed {n} entries")


@main.command("export")
@click.argument("model", type=click.Path(dir_okay=False))
@click.option("--scene", type=click.Path(dir_okay=False),
              help="export the scene's specialised model (its signals, parameters, solver)")
@click.option("--fmu", "fmu_out", required=True, type=click.Path(dir_okay=False),
              help="the FMU to write (FMI 2.0)")
@click.option("--kind", type=click.Choice(("me", "cs", "both")), default="both",
              show_default=True, help="Model Exchange, Co-Simulation or both")
@click.option("-q", "--quiet", is_flag=True)
def export_cmd(model, scene, fmu_out, kind, quiet):
    """Export MODEL.yaml (or SCENE's specialised model) as an FMI 2.0 FMU."""
    from .cbuild import CompilerMissing
    from .fmu import export_fmu

    prog = _Progress(quiet)
    try:
        export_fmu(model, fmu_out, scene_path=scene, kind=kind, progress=prog)
    except CompilerMissing as exc:
        _fail(exc)


def _register_accuracy():
    from .accuracy import register

    register(main)


if __name__ == "__main__":  # pragma: no cover
    main()
