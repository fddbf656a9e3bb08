"""The `bgc` commands on a model file: compile, check, graph, equations, export (FMU). Each is a
click command that bgc.cli.commands adds to the `bgc` group; what they run is imported inside
them, so that listing the commands stays light."""
from __future__ import annotations

import io
from pathlib import Path

import click

from bgc.base import BACKENDS
from bgc.base.collector import gc_paused
from bgc.base.errors import ModelError
from bgc.base.outfiles import check_output, write_output
from bgc.base.reach import run_inputs
from bgc.cli.exits import fail
from bgc.cli.options import model_inputs
from bgc.run.progress import Progress


@click.command("compile")
@click.argument("model", type=click.Path())  # bgc.base.safeio refuses folders, FIFOs, devices (located)
@click.option("-o", "--output", type=click.Path(), help="module to write "
              "(default: generated/<name>.py beside the models folder, or ./<name>.py; with "
              "--scene: ./<name>_<scene>.py)")
@click.option("--scene", type=click.Path(dir_okay=False),
              help="specialise for this scene (its signals, effects, parameters, outputs)")
@click.option("--target", type=click.Choice(BACKENDS), default="numpy", show_default=True,
              help="numpy: one Python module; c: C sources, a wrapper module and the built "
                   "library in the folder -o")
@click.option("--no-cache", is_flag=True, help="do not use the compile cache (C runtime objects)")
@click.option("--strict-causality", is_flag=True,
              help="refuse derivative causality (every storage element independent) instead of "
                   "eliminating the dependent storage elements")
@click.option("-q", "--quiet", is_flag=True)
def compile_cmd(model, output, scene, target, no_cache, quiet, strict_causality):
    """Compile MODEL.yaml into a Python module (or, --target c, C sources and a library)."""
    with gc_paused():  # (the imports below allocate much and free little: see gc_paused)
        # lazy: what this command runs; `bgc --help` and the other commands never load it
        from bgc.backends import load as backends
        from bgc.backends.c import build as cbuild
        from bgc.format.scene import parse_scene
        from bgc.run import cache as cache_mod
        from bgc.run.driver import compile_source
        from bgc.run.runner import check_module_start

    prog = Progress(quiet)
    sc = None
    if scene is not None:  # '' too: the scene file's message, not a module for no scene
        prog("parsing")
        sc = parse_scene(scene)
    # the scene's module is the one `bgc simulate` runs: bgc.run.driver's one scene compile
    # (without the linearisation's B, C, D: `bgc linearize SCENE` compiles its own)
    c = compile_source(model, sc, prog, strict_causality, linear=False)
    if sc is not None and output is None:
        output = Path(f"{c.model.name}_{sc.name}.py")
    if target == "c":
        if output is None:
            raise ModelError(None, "--target c writes a folder: give it with -o OUTDIR")
        cbuild.identity()  # a clear message without a compiler

        path = backends.write_c(c, output, None if no_cache else cache_mod.Cache(), prog,
                                run_inputs(model, scene))
        prog(f"wrote {output}/ (C sources, {path.name}, {cbuild.LIB_NAME}): "
             f"{len(c.equations.states)} states, {len(c.equations.jacobian)} Jacobian entries")
        return
    if output is None:
        output = _default_output(Path(model), c.model.name)
    ins = model_inputs(model, scene, sc.model_path if sc is not None else None)

    check_module_start(c)  # finite at X0 with the defaults, or a located error: nothing written
    write_output(output, c.source, ins, "-o")
    prog(f"wrote {output}: {len(c.equations.states)} states, "
         f"{len(c.equations.jacobian)} Jacobian entries")


def _default_output(model: Path, name: str) -> Path:
    parent = model.resolve().parent
    if parent.name == "models" and (parent.parent / "generated").is_dir():
        return parent.parent / "generated" / f"{name}.py"
    return Path(f"{name}.py")


@click.command("check")
@click.argument("model", type=click.Path())  # bgc.base.safeio refuses folders, FIFOs, devices (located)
@click.option("--strict-causality", is_flag=True,
              help="refuse derivative causality (every storage element independent) instead of "
                   "eliminating the dependent storage elements")
@click.option("--units", "show_units", is_flag=True,
              help="also list each bond's physical domain and the dimensions of its effort and flow")
def check_cmd(model, strict_causality, show_units):
    """Check MODEL.yaml completely (up to the equations) and list causality, states, warnings."""
    # lazy: what this command runs; `bgc --help` and the other commands never load it
    from bgc.format.parse import parse_file
    from bgc.run.driver import check_model

    chk = check_model(parse_file(model), strict_causality)  # as bgc.check() and compile check
    if chk.error is not None:
        raise chk.error
    m, bg, caus, eqs = chk.model, chk.graph, chk.causality, chk.equations
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
    for src in caus.constraints:
        n = bg.bonds_of(src)[0].n
        states.append(f"{src}.q" + (f" ({n})" if n > 1 else "") + " (constraint violation)")
    out.write(f"\nstates ({len(eqs.states)} scalars):\n")
    for s in states:
        out.write(f"  {s}\n")
    all_integral = not caus.derivative
    out.write(f"\ncausality: {'all storage elements integral' if all_integral else 'derivative'}\n")
    if caus.derivative:
        # lazy: the compile path, which a warm run never loads
        from bgc.core.causality import dependent_report

        out.write(dependent_report(bg, caus, eqs))
    if caus.constraints:
        # lazy: the compile path, which a warm run never loads
        from bgc.core.constraints import constraint_report

        out.write(constraint_report(bg, caus, eqs))
    for loop in eqs.loops:
        out.write(f"note: {loop}\n")
    for wmsg in eqs.warnings:  # what the equations leave standing of causality's warnings
        out.write(f"warning: {wmsg}\n")
    if show_units:
        # lazy: the compile path, which a warm run never loads
        from bgc.core.units import check_units

        out.write("\n" + check_units(bg).text())
    click.echo(out.getvalue(), nl=False)


@click.command("graph")
@click.argument("model", type=click.Path())  # bgc.base.safeio refuses folders, FIFOs, devices (located)
@click.option("-o", "--output", required=True, type=click.Path(),
              help="FILE.dot, FILE.svg or FILE.png")
def graph_cmd(model, output):
    """Draw the bond graph with causal strokes (DOT; SVG/PNG through Graphviz)."""
    # lazy: the compile path, which a warm run never loads
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
    ins = model_inputs(model)
    check_output(output, ins, "-o")  # before Graphviz runs
    data = dot if suffix == ".dot" else render_image(dot, suffix[1:])
    write_output(output, data, ins, "-o")
    click.echo(f"wrote {output}", err=True)



@click.command("equations")
@click.argument("model", type=click.Path())  # bgc.base.safeio refuses folders, FIFOs, devices (located)
@click.option("--latex", is_flag=True, help="LaTeX (an aligned block) instead of plain text")
@click.option("--explicit", is_flag=True,
              help="substitute the causal assignments: dx/dt in states, parameters, inputs only")
def equations_cmd(model, latex, explicit):
    """The state equations of MODEL: the causal assignments, then dx/dt (sympy)."""
    # lazy: the compile path, which a warm run never loads
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



@click.command("export")
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
    # lazy: the compile path, which a warm run never loads
    from bgc.backends.c.build import CompilerMissing
    from bgc.run.fmu import export_fmu

    prog = Progress(quiet)
    try:
        export_fmu(model, fmu_out, scene_path=scene, kind=kind, progress=prog)
    except CompilerMissing as exc:
        fail(exc)
