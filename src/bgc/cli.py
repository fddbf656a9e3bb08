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
              "(default: generated/<name>.py beside the models folder, or ./<name>.py)")
@click.option("--scene", type=click.Path(dir_okay=False), help="specialise for this scene")
@click.option("-q", "--quiet", is_flag=True)
def compile_cmd(model, output, scene, quiet):
    """Compile MODEL.yaml into a Python module."""
    from .compiler import compile_model, write_atomic
    from .parse import parse_file

    prog = _Progress(quiet)
    prog("parsing")
    if scene:
        from .scene import apply_scene, parse_scene

        sc = parse_scene(scene)
        m = apply_scene(parse_file(model), sc)
    else:
        m = parse_file(model)
    c = compile_model(m, prog)
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
    """Parse MODEL.yaml, assign causality and list bonds, states and warnings."""
    from .causality import assign_causality
    from .graph import build_graph
    from .parse import parse_file

    m = parse_file(model)
    bg = build_graph(m)
    caus = assign_causality(bg)
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
    n_states = sum(bg.bonds_of(el.id)[0].n for el in bg.elements if el.type in ("I", "C"))
    n_states += sum(int(np.prod(st.shape)) if st.shape else 1 for st in bg.states)
    out.write(f"\nstates ({n_states} scalars):\n")
    for s in states:
        out.write(f"  {s}\n")
    all_integral = not caus.derivative
    out.write(f"\ncausality: {'all storage elements integral' if all_integral else 'derivative'}\n")
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
@click.option("--method", default=None, help="override the scene's solver method")
@click.option("--rtol", type=float, default=None)
@click.option("-q", "--quiet", is_flag=True)
def simulate_cmd(scene, out, plot_dir, method, rtol, quiet):
    """Compile the scene's model and simulate the scene."""
    from .runner import run_scene

    prog = _Progress(quiet)
    res = run_scene(scene, progress=prog, method=method, rtol=rtol)
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
               f"{res.method} rtol={res.rtol:g}: {st['nfev']} rhs calls, {st['njev']} Jacobians, "
               f"{st.get('nlu', 0)} LU; compile {res.compile_time:.2f} s, "
               f"integrate {res.run_time:.2f} s")


def _register_accuracy():
    from .accuracy import register

    register(main)


_register_accuracy()


if __name__ == "__main__":  # pragma: no cover
    main()
