"""FMU export: a model (or a scene's specialised model) as an FMI 2.0 FMU for Model Exchange
and Co-Simulation.

The FMU holds modelDescription.xml, the C sources under ``sources/`` (the model printed by
the C backend's printer from bgc's lowering, the FMI glue ``bgc_fmi2.c``, bgc's C runtime and
the FMI 2.0 headers taken from the installed FMPy package) and a shared library for this
platform under ``binaries/<platform>/``.

The model functions of an FMU differ from the C backend's in one respect: the inputs are
values in the parameter vector (set through fmi2SetReal) instead of compiled default
expressions; an input nobody has set follows its default signal (:mod:`templates/c/fmu`).
The variables, their value references and the model structure are
:func:`bgc.backends.fmu.spec.build_spec`'s; the C model's parts are the C backend's
(:mod:`bgc.backends.c.parts`), printed from the lowered functions.
"""
from __future__ import annotations

import io
import os
import platform
import re
import shutil
import tempfile
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import sympy as sp

from bgc.backends.c import build as cbuild
from bgc.backends.c.events import c_events, event_parts
from bgc.backends.c.parts import UNIT_PARTS, PartContext, cut_parts
from bgc.backends.c.printer import (
    CPrinter,
    c_name,
    newton_loops,
    newton_protos,
    table_data,
    template_env,
)
from bgc.backends.fmu.spec import FmuSpec, build_spec, flat_names  # noqa: F401 (as export.*)
from bgc.backends.fmu.xmltext import clean_tree
from bgc.base import __version__
from bgc.base.errors import ModelError
from bgc.base.outfiles import check_output, write_output
from bgc.base.paths import templates_dir
from bgc.core.equations import T
from bgc.format.units import UnitError, parse_unit

KINDS = ("me", "cs", "both")
FMI_HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")
GLUE_DIR = "c/fmu"
_STRUCTURED = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\[[0-9]+(,[0-9]+)*\])?"
                         r"(\.[A-Za-z_][A-Za-z0-9_]*(\[[0-9]+(,[0-9]+)*\])?)*")
_METHODS = {"Rodas4": 0, "Radau": 1}  # BGC_RODAS4, BGC_RADAU5; other methods run Radau5


# ---------------------------------------------------------------------------------------------
# modelDescription.xml


def _g(v: float) -> str:
    return repr(float(v))


#: FMI 2.0's BaseUnit attributes for bgc's base dimensions (bgc.format.units.BASE's order)
_FMI_BASE = ("m", "kg", "s", "A", "K", "mol", "cd")


def base_unit(unit: str) -> dict | None:
    """The attributes of a unit's ``<BaseUnit>`` (FMI 2.0, 2.2.2): the SI exponents (only
    those not 0) and ``factor`` (1 unit = factor * base units); None where FMI cannot say it
    (an exponent that is not a whole number, or a unit string bgc does not read)."""
    try:
        scale, d = parse_unit(unit)
    except UnitError:
        return None
    if any(int(x) != x for x in d):
        return None
    attrs = {name: str(int(x)) for name, x in zip(_FMI_BASE, d) if x}
    if scale != 1.0:
        attrs["factor"] = _g(scale)
    return attrs


def model_description(compiled, spec: FmuSpec, scene=None, kind: str = "both",
                      sources: tuple[str, ...] = ()) -> bytes:
    desc = compiled.model.description or ""
    naming = "structured" if all(_STRUCTURED.fullmatch(v.name) or (
        v.name.startswith("der(") and _STRUCTURED.fullmatch(v.name[4:-1]))
        for v in spec.variables) else "flat"
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "2.0", "modelName": compiled.model.name + (
            f" (scene {scene.name})" if scene is not None else ""),
        "guid": spec.guid, "description": desc, "generationTool": f"bgc {__version__}",
        "variableNamingConvention": naming,
        "numberOfEventIndicators": str(len(compiled.equations.events))})
    caps = {"modelIdentifier": spec.model_identifier,
            "needsExecutionTool": "false", "canNotUseMemoryManagementFunctions": "true",
            "canGetAndSetFMUstate": "true", "canSerializeFMUstate": "false",
            "providesDirectionalDerivative": "true"}
    for tag, extra in (("ModelExchange", {"completedIntegratorStepNotNeeded": "true"}),
                       ("CoSimulation", {"canHandleVariableCommunicationStepSize": "true",
                                         "canInterpolateInputs": "false",
                                         "maxOutputDerivativeOrder": "0",
                                         "canRunAsynchronuously": "false"})):
        if (tag == "ModelExchange" and kind == "cs") or (tag == "CoSimulation" and kind == "me"):
            continue
        el = ET.SubElement(root, tag, {**caps, **extra})
        sf = ET.SubElement(el, "SourceFiles")
        for f in sources:
            ET.SubElement(sf, "File", {"name": f})
    units = sorted({v.unit for v in spec.variables if v.unit})
    if units:
        ud = ET.SubElement(root, "UnitDefinitions")
        for u in units:
            base = base_unit(u)
            unit = ET.SubElement(ud, "Unit", {"name": u})
            if base is not None:
                ET.SubElement(unit, "BaseUnit", base)
    cats = ET.SubElement(root, "LogCategories")
    for cat, what in (("logStatusError", "errors: bad calls, failed evaluations"),
                      ("logStatusDiscard", "communication steps the integrator could not end"),
                      ("logAll", "everything")):
        ET.SubElement(cats, "Category", {"name": cat, "description": what})
    de = {}
    if scene is not None:
        de = {"startTime": _g(scene.t_span[0]), "stopTime": _g(scene.t_span[1]),
              "tolerance": _g(scene.rtol)}
        if scene.dt:
            de["stepSize"] = _g(scene.dt)
    else:
        de = {"startTime": "0.0", "tolerance": "1e-06"}
    ET.SubElement(root, "DefaultExperiment", de)
    mv = ET.SubElement(root, "ModelVariables")
    for v in spec.variables:
        a = {"name": v.name, "valueReference": str(v.vr)}
        if v.description:
            a["description"] = v.description
        a["causality"] = v.causality
        a["variability"] = v.variability
        if v.initial:
            a["initial"] = v.initial
        sv = ET.SubElement(mv, "ScalarVariable", a)
        ra = {}
        if v.unit:
            ra["unit"] = v.unit
        if v.derivative is not None:
            ra["derivative"] = str(v.derivative)
        if v.start is not None:
            ra["start"] = _g(v.start)
        ET.SubElement(sv, "Real", ra)
    ms = ET.SubElement(root, "ModelStructure")
    n = spec.n
    idx_y = [2 * n + spec.np + spec.nu + k + 1 for k in range(spec.nout)]
    if spec.nout:
        outs = ET.SubElement(ms, "Outputs")
        for k, i in enumerate(idx_y):
            ET.SubElement(outs, "Unknown", {"index": str(i), "dependencies": " ".join(
                map(str, spec.output_deps[k]))})
    if n:
        ders = ET.SubElement(ms, "Derivatives")
        for i in range(n):
            ET.SubElement(ders, "Unknown", {"index": str(n + i + 1), "dependencies": " ".join(
                map(str, spec.state_deps[i]))})
    if spec.initial_deps:
        iu = ET.SubElement(ms, "InitialUnknowns")
        for i, deps in spec.initial_deps:
            ET.SubElement(iu, "Unknown", {"index": str(i),
                                          "dependencies": " ".join(map(str, deps))})
    ET.indent(root, space="  ")

    clean_tree(root)  # the one door: only characters XML 1.0 can hold
    buf = io.BytesIO()
    ET.ElementTree(root).write(buf, encoding="UTF-8", xml_declaration=True)
    return buf.getvalue() + b"\n"


# ---------------------------------------------------------------------------------------------
# C sources


def render_sources(compiled, spec: FmuSpec, scene=None, kind: str = "both") -> dict[str, str]:
    """The FMU's generated C files (name -> text): bgc_fmu_model.c, the parts and the
    configuration header."""
    low = compiled.lowered
    eq = compiled.equations
    # numeric solves (Newton loops, derivative causality's linear solves): the C backend's
    # code in the parts, failures returned as codes (fmi2Error); Newton cold-started
    printer = CPrinter()
    ctx = PartContext.inputs_as_params(low)  # the inputs are values in the parameter vector
    fns = {name: cut_parts(name, fn, printer, ctx) for name, fn in
           (("rhs", low.rhs), ("jac", low.jac), ("outputs", low.outs), ("init", low.init))
           + ((("cons", low.cons),) if getattr(low, "cons", None) is not None else ())}
    # closed loops: each constraint component's source, for fmi2ExitInitializationMode's check
    cons_names = [name.split(".q")[0] for name in getattr(eq, "constraint_states", ())] \
        if "cons" in fns else []
    # events: the guards are the indicators (ME); the C runtime locates them in a step (CS)
    events = c_events(eq, lambda name, fn: cut_parts(name, fn, printer, ctx))
    syms = ctx.param_syms + ctx.state_syms
    cnames = [c_name(str(s)) for s in syms]
    if not all(nm.isidentifier() and nm.isascii() for nm in cnames) or \
            len(set(cnames)) != len(syms):
        raise AssertionError("two model identifiers map to one C name")
    n_par = sum(len(pv.symbols) for pv in eq.params)
    nd = len(low.derived)
    assert n_par == spec.np and len(ctx.param_syms) - n_par - nd == spec.nu
    index = {s: k for k, s in enumerate(ctx.param_syms)}
    defaults = [d for iv in eq.inputs for d in iv.default]
    used = set()
    for iv in eq.inputs:
        if getattr(iv, "table", None) is None:
            for d in iv.default:
                used |= sp.sympify(d).free_symbols
    default_params = [(c_name(str(s)), index[s]) for s in ctx.param_syms[:n_par + nd]
                      if s in used]
    # a table input's default is its table at t (the C backend's model_tables.c, its data
    # compiled into the unit)
    default_codes, k_tab = [], 0
    for iv in eq.inputs:
        if getattr(iv, "table", None) is not None:
            default_codes += [f"bgcf_table_{k_tab}(t)"] * len(iv.default)
            k_tab += 1
        else:
            default_codes += [printer.doprint(d) for d in iv.default]
    assert len(default_codes) == len(defaults)
    dused = set()
    for ln in low.derived:
        dused |= ln.expr.free_symbols
    derived_params = [(c_name(str(s)), k) for k, s in enumerate(ctx.param_syms[:n_par])
                      if s in dused]
    derived_lines = [(c_name(str(ln.target)), printer.doprint(ln.expr), n_par + j)
                     for j, ln in enumerate(low.derived)]
    has_t = int(fns["rhs"].uses_t or fns["jac"].uses_t or T in used or bool(ctx.tables))
    all_parts = [p for f in fns.values() for p in f.parts] + event_parts(events)
    units = [all_parts[i:i + UNIT_PARTS] for i in range(0, len(all_parts), UNIT_PARTS)]
    env = template_env()
    m = compiled.model
    common = dict(name=eq.name, version=__version__, source=Path(m.file).name,
                  source_hash=m.source_hash, description=m.description,
                  notes=list(compiled.notes) + list(eq.loops))
    files = {}
    for k, unit in enumerate(units):
        files[f"model_part{k}.c"] = env.get_template("c/part.c.j2").render(
            parts=unit, unit=k, newton=newton_protos(ctx), ntables=0, **common)
    if ctx.tables:  # the table inputs' data and interpolation, as the C backend's
        files["model_tables.c"] = env.get_template("c/tables.c.j2").render(
            tables=table_data(ctx), **common)
    if ctx.newton:  # the C backend's Newton loops; cold-started (no per-instance workspace)
        files["model_newton.c"] = env.get_template("c/newton.c.j2").render(
            loops=newton_loops(ctx, printer), **common)
    method, rtol, atol, max_step, breaks = 1, 1e-6, 1e-9, 0.0, []
    if scene is not None:
        method = _METHODS.get(scene.method, 1)
        rtol, atol = scene.rtol, scene.atol
        max_step = scene.max_step if scene.max_step not in (None, float("inf")) else 0.0
        breaks = sorted(b for b in scene.breakpoints if scene.t_span[0] < b < scene.t_span[1])
    tmpl = env.from_string((templates_dir() / GLUE_DIR / "fmu_model.c.j2").read_text("utf-8"))
    files["bgc_fmu_model.c"] = tmpl.render(
        fns=fns, all_parts=all_parts, n=spec.n, np=n_par, nd=nd, nu=spec.nu, nout=spec.nout,
        np_all=n_par + nd + 2 * spec.nu, jac_keys=low.jac_keys, has_t=has_t,
        default_params=default_params, default_codes=default_codes,
        derived_params=derived_params, derived_lines=derived_lines,
        param_start=[_g(v) for v in spec.param_start], param_tunable=list(spec.param_tunable),
        input_start=[_g(v) for v in spec.input_start], breaks=[_g(b) for b in breaks],
        guid=spec.guid, model_identifier=spec.model_identifier, method=method,
        rtol=_g(rtol), atol=_g(atol), max_step=_g(max_step), events=events,
        cons_names=cons_names,
        ntables=len(ctx.tables), **common)
    cfg = ["/* bgc FMU configuration (generated) */", "#ifndef BGC_FMU_CONFIG_H",
           "#define BGC_FMU_CONFIG_H"]
    if kind == "cs":
        cfg.append("#define BGCF_NO_ME 1")
    if kind == "me":
        cfg.append("#define BGCF_NO_CS 1")
    cfg += ["#endif", ""]
    files["bgc_fmu_config.h"] = "\n".join(cfg)
    return files


def fmi_headers_dir() -> Path:
    """The folder of the FMI 2.0 headers shipped by the installed FMPy package."""
    try:
        import fmpy
    except ImportError:
        raise ModelError(None, "bgc export --fmu needs the FMI 2.0 headers, which bgc takes "
                               "from the FMPy package: pip install fmpy") from None
    base = Path(fmpy.__file__).parent
    for d in [base / "c-code"] + sorted(p.parent for p in base.rglob("fmi2Functions.h")):
        if all((d / h).is_file() for h in FMI_HEADERS):
            return d
    raise ModelError(None, f"the FMPy package at {base} ships no FMI 2.0 headers")


def platform_dir() -> str:
    bits = "64" if platform.architecture()[0] == "64bit" else "32"
    system = {"Linux": "linux", "Darwin": "darwin", "Windows": "win"}.get(platform.system(),
                                                                       platform.system().lower())
    return f"{system}{bits}"


def _lib_suffix() -> str:
    return {"Darwin": ".dylib", "Windows": ".dll"}.get(platform.system(), ".so")


def write_sources(compiled, spec, scene, kind, dest: Path) -> list[str]:
    """All C sources (generated, glue, runtime, FMI headers) into dest; the .c file names."""
    files = render_sources(compiled, spec, scene, kind)
    for name, text in files.items():
        (dest / name).write_text(text, encoding="utf-8")
    glue = templates_dir() / GLUE_DIR
    for f in ("bgc_fmi2.c", "bgc_fmu_model.h"):
        shutil.copyfile(glue / f, dest / f)
    for f in cbuild.runtime_sources() + cbuild.runtime_headers():
        shutil.copyfile(f, dest / f.name)
    hd = fmi_headers_dir()
    for h in FMI_HEADERS:
        shutil.copyfile(hd / h, dest / h)
    return sorted(p.name for p in dest.glob("*.c"))


def build_binary(src: Path, cfiles: list[str], out: Path, cache=None, coord=None) -> None:
    """Build the FMU's shared library ``out`` with the C backend's build
    (bgc.backends.c.build: its flags, and the runtime's objects from the compile cache when
    ``cache`` is given): the FMU's own units with ``-fvisibility=hidden`` (only the fmi2
    functions are exported). A compiler that refuses the sources is one located error at
    ``coord``."""
    rt_names = {f.name for f in cbuild.runtime_sources()}
    own = [f for f in cfiles if f not in rt_names]  # the runtime's: compiled once, cached
    lib = cbuild.build_library(src, own, cache=cache, extra=("-fvisibility=hidden",),
                               lib_name=out.name + ".build", coord=coord)
    os.replace(lib, out)


def _zip(entries) -> bytes:
    """The FMU's bytes: a zip of (name, data), with fixed dates and modes (reproducible)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, data in entries:
            zi = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
            zi.compress_type = zipfile.ZIP_DEFLATED
            zi.external_attr = 0o644 << 16
            zf.writestr(zi, data)
    return buf.getvalue()


def package_fmu(compiled, out, scene=None, kind: str = "both", progress=None,
                cache=None, inputs=None) -> Path:
    """The FMU of a compiled model (specialised to ``scene`` when given), written to ``out``
    through the checked writer (bgc.base.outfiles: never over an input of the run, given as
    ``inputs``, a link or anything but a regular file; atomic): its description, C sources
    and built binary in one zip (the C runtime's objects from ``cache``, a
    bgc.base.store.Cache, when given)."""
    check_output(out, inputs, "--fmu")  # before anything is built
    say = progress or (lambda msg: None)
    if kind not in KINDS:
        raise ModelError(None, f"unknown FMU kind {kind!r}: one of {', '.join(KINDS)}")
    fmi_headers_dir()  # fail early without FMPy's headers
    spec = build_spec(compiled, scene, kind)
    work = Path(tempfile.mkdtemp(prefix="bgc-fmu-"))
    try:
        src = work / "sources"
        src.mkdir()
        say("writing the C sources")
        cfiles = write_sources(compiled, spec, scene, kind, src)
        xml = model_description(compiled, spec, scene, kind, tuple(cfiles))
        libname = spec.model_identifier + _lib_suffix()
        say(f"building {libname}")
        lib = work / libname
        build_binary(src, cfiles, lib, cache, compiled.model.coord)
        entries = [("modelDescription.xml", xml)]
        for f in sorted(src.iterdir()):
            entries.append((f"sources/{f.name}", f.read_bytes()))
        entries.append((f"binaries/{platform_dir()}/{libname}", lib.read_bytes()))
        write_output(out, _zip(entries), inputs, "--fmu")  # checked, atomic
    finally:
        shutil.rmtree(work, ignore_errors=True)
    say(f"wrote {out}: {spec.n} states, {spec.np} parameters, {spec.nu} inputs, "
        f"{spec.nout} outputs")
    return Path(out)
