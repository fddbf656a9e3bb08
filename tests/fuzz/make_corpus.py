"""Generate the hostile corpus of issue 10: models, scenes and command lines, each with the
outcome the issue asks for (not what bgc does today).

    python -m tests.fuzz.make_corpus                 # tests/fuzz/corpus (committed)
    python -m tests.fuzz.make_corpus --private DIR   # another set: other strings, other seed

Every case is one or more data files under ``<corpus>/<category>/`` (a case with several
files has a folder of its own) plus an entry in ``<corpus>/expected.yaml``: the command line
(argv, run in a fresh folder holding the case's files under the names given in ``files``),
setup actions done at test time (FIFOs, device nodes, symlinks, sparse or huge files: nothing
big is committed), and the expectation:

* ``ok``: compiles (or simulates), the module is the template's, loads, rhs(X0) is finite;
* ``error``: exit 2, one line ``file:line:col: message`` matching ``message`` (a
  case-insensitive regular expression) at ``line`` (the line of the offending element);
* ``any``: either of the two (where both answers are right, e.g. a lone surrogate in a
  description may be escaped or refused), with the same guarantees (no traceback, nothing
  written on error, bounded time and memory).

The first lines of each primary file repeat its case id and expectation as YAML comments.
"""
from __future__ import annotations

import argparse
import random
import shutil
from pathlib import Path

import yaml

HERE = Path(__file__).resolve().parent

# ---------------------------------------------------------------------------------------------
# YAML helpers


def dq(s: str) -> str:
    """A YAML double-quoted scalar holding exactly s (every odd character as an escape)."""
    out = []
    for ch in s:
        o = ord(ch)
        if ch == "\\":
            out.append("\\\\")
        elif ch == '"':
            out.append('\\"')
        elif ch == "\n":
            out.append("\\n")
        elif ch == "\t":
            out.append("\\t")
        elif ch == "\r":
            out.append("\\r")
        elif ch == "\0":
            out.append("\\0")
        elif o < 0x20 or o == 0x7F or 0x80 <= o < 0xA0:
            out.append(f"\\x{o:02X}")
        elif 0xD800 <= o <= 0xDFFF or o in (0x2028, 0x2029, 0xFEFF) or o > 0x7E:
            out.append(f"\\u{o:04X}" if o <= 0xFFFF else f"\\U{o:08X}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


class Doc:
    """A YAML file as keyed lines, so a case can replace one line and know its number."""

    def __init__(self, pairs):
        self.pairs = list(pairs)

    def make(self, header: list[str], **changes):
        """(text, {key: line}) with changes: key -> new line, list of lines, or None."""
        lines, where = list(header), {}
        for key, line in self.pairs:
            new = changes.pop(key, line) if key in changes else line
            if new is None:
                continue
            if isinstance(new, list):
                where[key] = len(lines) + 1
                lines.extend(new)
            else:
                where[key] = len(lines) + 1
                lines.append(new)
        extra = changes.pop("_after", None)
        if changes:
            raise KeyError(f"unknown keys {sorted(changes)}")
        if extra:
            where["_after"] = len(lines) + 1
            lines.extend(extra)
        return "\n".join(lines) + "\n", where


MSD = Doc([
    ("bgc", "bgc: 1"),
    ("name", "name: msd"),
    ("desc", "description: mass-spring-damper under a force step"),
    ("params", "parameters:"),
    ("p_m", "  m: {value: 2.0, unit: kg, min: 0, description: moving mass}"),
    ("p_k", "  k: {value: 200.0, unit: N/m, description: spring stiffness}"),
    ("p_c", "  c: {value: 4.0, unit: N*s/m, description: viscous damping}"),
    ("p_F0", "  F0: {value: 10.0, unit: N, description: force amplitude}"),
    ("inputs", "inputs:"),
    ("i_F", '  F: {default: "F0", unit: N}'),
    ("elements", "elements:"),
    ("e_force", '  force: {type: Se, effort: "F"}'),
    ("e_mass", '  mass: {type: I, inertia: "m"}'),
    ("e_spring", '  spring: {type: C, stiffness: "k"}'),
    ("e_damper", '  damper: {type: R, resistance: "c", effects: [damping]}'),
    ("e_v", '  v: {type: "1"}'),
    ("bonds", "bonds:"),
    ("b1", "  - [force, v]"),
    ("b2", "  - [v, mass]"),
    ("b3", "  - [v, spring]"),
    ("b4", "  - [v, damper]"),
    ("states", "states:"),
    ("s_W", '  W: {initial: 0, derivative: "power(damper)", unit: J, '
            'description: dissipated energy}'),
    ("outputs", "outputs:"),
    ("o_pos", '  position: "q(spring)"'),
    ("o_vel", '  velocity: "f(mass)"'),
])

COMP = Doc([
    ("bgc", "bgc: 1"),
    ("name", "name: chain"),
    ("desc", "description: a mass on a spring-damper component"),
    ("components", "components:"),
    ("c_sd", "  sd:"),
    ("c_desc", "    description: spring and damper in parallel"),
    ("c_params", "    parameters:"),
    ("c_k", "      k: {value: 100.0, unit: N/m, description: stiffness}"),
    ("c_c", "      c: {value: 1.0, unit: N*s/m, description: damping}"),
    ("c_ports", "    ports: {a: j}"),
    ("c_elements", "    elements:"),
    ("c_j", '      j: {type: "1"}'),
    ("c_s", '      s: {type: C, stiffness: "k"}'),
    ("c_d", '      d: {type: R, resistance: "c", effects: [damping]}'),
    ("c_bonds", "    bonds: [[j, s], [j, d]]"),
    ("params", "parameters:"),
    ("p_m", "  m: {value: 1.0, unit: kg}"),
    ("elements", "elements:"),
    ("e_mass", '  mass: {type: I, inertia: "m", initial: 0.5}'),
    ("e_v", '  v: {type: "1"}'),
    ("e_link", "  link: {type: sd, c: 2.0}"),
    ("bonds", "bonds:"),
    ("b1", "  - [v, mass]"),
    ("b2", "  - [v, link.a]"),
    ("outputs", "outputs:"),
    ("o_vel", '  velocity: "f(mass)"'),
])

SCENE = Doc([
    ("bgc_scene", "bgc_scene: 1"),
    ("name", "name: step"),
    ("desc", "description: the force step at t = 0.5 s on a heavier mass"),
    ("model", "model: model.yaml"),
    ("duration", "duration: 1.0"),
    ("parameters", "parameters: {m: 3.0}"),
    ("inputs", 'inputs: {F: "where(t < 0.5, 0, F0)"}'),
    ("outputs", "outputs: [position, velocity]"),
    ("solver", "solver: {method: Radau, rtol: 1.0e-6, atol: 1.0e-9, dt: 0.01}"),
    ("effects", "effects: {damping: on}"),
    ("breakpoints", "breakpoints: [0.5]"),
])


# ---------------------------------------------------------------------------------------------
# the case list


class Corpus:
    def __init__(self, root: Path):
        self.root = root
        self.cases: list[dict] = []
        self.ids: set[str] = set()

    def header(self, cid: str, expect: str, note: str = "") -> list[str]:
        h = [f"# fuzz case {cid}: expect {expect}"]
        if note:
            h.append("# " + " ".join(note.split())[:200])
        return h

    def write(self, rel: str, text) -> str:
        p = self.root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(text, bytes):
            p.write_bytes(text)
        else:
            with open(p, "w", encoding="utf-8", newline="\n") as fh:
                fh.write(text)
        return rel

    def add(self, category: str, name: str, *, argv, expect, files=None, setup=(),
            outputs=(), message=None, line=None, located=True, exit=(2,), check="auto",
            usage=False, twin=None, note="", env=None):
        cid = f"{category}/{name}"
        assert cid not in self.ids, cid
        assert expect in ("ok", "error", "any")
        self.ids.add(cid)
        files = dict(files or {})
        if check == "auto":
            check = (["check", argv[1]] if argv[0] == "compile" and "--scene" not in argv
                     else None)
        c = {"id": cid, "category": category, "argv": list(argv), "expect": expect,
             "files": files, "setup": list(setup), "outputs": list(outputs)}
        if message is not None:
            c["message"] = message
        if line is not None:
            c["line"] = line
        if not located:
            c["located"] = False
        if tuple(exit) != (2,):
            c["exit"] = list(exit)
        if check is not None:
            c["check"] = list(check)
        if usage:
            c["usage"] = True
        if twin:
            c["twin"] = twin
        if note:
            c["note"] = note
        if env:
            c["env"] = dict(env)
        self.cases.append(c)

    # --- shortcuts ----------------------------------------------------------------------

    def model_case(self, category, cname, doc: Doc, *, expect, key=None, message=None,
                   note="", line=None, extra_files=None, setup=(), fname="model.yaml",
                   twin=None, **changes):
        """One model file (doc with changes) compiled with -o out.py, then checked."""
        name = cname
        text, where = doc.make(self.header(f"{category}/{name}", expect, note), **changes)
        rel = self.write(f"{category}/{name}.yaml", text)
        if line is None and key is not None and expect != "ok":
            line = where[key]
        elif isinstance(line, tuple):  # the lines of these keys
            line = [where[k] for k in line]
        files = {fname: rel}
        files.update(extra_files or {})
        self.add(category, name, argv=["compile", fname, "-o", "out.py", "-q"], expect=expect,
                 files=files, outputs=["out.py"], message=message,
                 line=line if expect != "ok" else None, setup=setup, twin=twin, note=note)
        return rel

    def scene_case(self, category, cname, *, expect, key=None, message=None, note="",
                   simulate=False, model_changes=None, scene_name="scene.yaml", line=None,
                   argv=None, out_files=None, setup=(), exit=(2,), located=True, **changes):
        """A scene for the msd model: compile --scene (or simulate)."""
        name = cname
        cid = f"{category}/{name}"
        text, where = SCENE.make(self.header(cid, expect, note), **changes)
        mtext, _ = MSD.make(["# the model of " + cid], **(model_changes or {}))
        srel = self.write(f"{category}/{name}/scene.yaml", text)
        mrel = self.write(f"{category}/{name}/model.yaml", mtext)
        if line is None and key is not None and expect != "ok":
            line = where[key]
        elif isinstance(line, tuple):  # the lines of these keys
            line = [where[k] for k in line]
        if argv is None:
            if simulate:
                argv = ["simulate", scene_name, "--out", "r.npz", "-q"]
                out_files = ["r.npz"] if out_files is None else out_files
            else:
                argv = ["compile", "model.yaml", "--scene", scene_name, "-o", "out.py", "-q"]
                out_files = ["out.py"] if out_files is None else out_files
        self.add(category, name, argv=argv, expect=expect,
                 files={scene_name: srel, "model.yaml": mrel}, outputs=out_files or [],
                 message=message, line=line if expect != "ok" else None, setup=setup,
                 note=note, exit=exit, located=located)


# ---------------------------------------------------------------------------------------------
# hostile material

PWN = 'open("canary.txt", "w").write("pwned")'


def text_payloads(rng: random.Random, private: bool) -> list[tuple[str, str, str]]:
    """(name, text, expectation) for free text: ok where any sane escaping must keep the
    text; any where refusing odd characters is as right as escaping them."""
    if not private:
        return [
            ("triple_dq", f'x"""\nimport os; {PWN}\n"""', "ok"),
            ("triple_sq", f"x'''\n{PWN}\n'''", "ok"),
            ("dq_expr", '"""+__import__("os").system("touch pwned")+"""', "ok"),
            ("backslash_N", "\\N{BULLET} and \\N", "ok"),
            ("trailing_backslash", "ends in a backslash \\", "ok"),
            ("escaped_quote", 'a \\""" b', "ok"),
            ("nul", "nul\0byte", "any"),
            ("lone_surrogate", "lone \ud800 surrogate", "any"),
            ("cr_break", f'x"""\r{PWN}\r"""', "any"),
            ("line_sep", "para\u2028graph\u2029 next\x85 line", "any"),
            ("jinja", "{{ 7*7 }} {% raw %} {# c #} ${HOME} $(touch pwned)", "ok"),
            ("def_rhs", '"""\ndef rhs(t, x, p=None, u=None):\n    return x\n"""', "ok"),
            ("coding", "\n# -*- coding: rot13 -*-\n", "ok"),
        ]
    pl = [
        ("tq_exec", f'"""\nexec("{PWN}")\n#', "ok"),
        ("tq_sys", '"""; import sys; sys.exit(0); """', "ok"),
        ("bs_u", "\\u0022\\u0022\\u0022 \\x", "ok"),
        ("bs_only", "\\", "ok"),
        ("nul2", "\0\0", "any"),
        ("surr_low", "\udcff", "any"),
        ("esc", "\x1b[2J\x07", "any"),
        ("vt", "a\x0bb\x0cc", "any"),
        ("tq_comment", '"""  # \n' + PWN + "  # ", "ok"),
        ("braces", "{0} %s %(x)s", "ok"),
    ]
    rng.shuffle(pl)
    return pl


def name_payloads(private: bool) -> list[tuple[str, str]]:
    if not private:
        return [("trailing_nl", "{base}\n"), ("tq", '{base}"""'), ("space", "{base} x"),
                ("nonascii", "{base}\u00e9"), ("nul", "{base}\0"), ("cr", "{base}\r"),
                ("dunder", "__class__")]
    return [("lead_nl", "\n{base}"), ("tab", "{base}\t"), ("semicolon", "{base};import os"),
            ("surr", "{base}\ud800"), ("keyword", "lambda")]


NUMBERS = [  # (name, YAML spelling, expectation, message pattern)
    ("inf", ".inf", "error", "finite|inf"),
    ("neg_inf", "-.inf", "error", "finite|inf"),
    ("nan", ".nan", "error", "finite|nan|number"),
    ("NaN", ".NaN", "error", "finite|nan|number"),
    ("e309", "1e309", "error", "finite|inf|large|range"),
    ("neg_e309", "-1.0e+309", "error", "finite|inf|large|range"),
    ("str_e999", '"1e999"', "error", "finite|inf|large|range|number"),
    ("digits400", "1" + "0" * 400, "error", "finite|large|range|number|digits"),
    ("neg_digits400", "-9" * 1 + "9" * 399, "error", "finite|large|range|number|digits"),
    ("sexagesimal", "1:30", "any", None),
]
PRIVATE_NUMBERS = [
    ("pinf", "+.INF", "error", "finite|inf"),
    ("Nan2", ".NAN", "error", "finite|nan|number"),
    ("e400", "2.5e400", "error", "finite|inf|large|range"),
    ("digits500", "7" * 500, "error", "finite|large|range|number|digits"),
    ("sexa3", "190:20:30", "any", None),
    ("tagged_nan", "!!float nan", "error", "finite|nan|number|tag"),
]


# ---------------------------------------------------------------------------------------------


def build(root: Path, private: bool = False, seed: int = 0) -> Corpus:
    rng = random.Random(seed)
    C = Corpus(root)
    texts = text_payloads(rng, private)
    names = name_payloads(private)
    numbers = PRIVATE_NUMBERS if private else NUMBERS

    # ---- 1. code execution through free text ------------------------------------------
    fields = {
        "desc": ("desc", lambda s: f"description: {dq(s)}"),
        "param_unit": ("p_m", lambda s: f"  m: {{value: 2.0, unit: {dq(s)}, min: 0}}"),
        "param_desc": ("p_k", lambda s: f"  k: {{value: 200.0, description: {dq(s)}}}"),
        "input_unit": ("i_F", lambda s: f'  F: {{default: "F0", unit: {dq(s)}}}'),
        "input_desc": ("i_F", lambda s: f'  F: {{default: "F0", description: {dq(s)}}}'),
        "state_unit": ("s_W", lambda s: f'  W: {{initial: 0, derivative: "power(damper)", '
                                        f"unit: {dq(s)}}}"),
        "state_desc": ("s_W", lambda s: f'  W: {{initial: 0, derivative: "power(damper)", '
                                        f"description: {dq(s)}}}"),
        "elem_desc": ("e_mass", lambda s: f'  mass: {{type: I, inertia: "m", '
                                          f"description: {dq(s)}}}"),
    }
    comp_fields = {
        "comp_param_unit": ("c_k", lambda s: f"      k: {{value: 100.0, unit: {dq(s)}}}"),
        "comp_param_desc": ("c_k", lambda s: f"      k: {{value: 100.0, description: {dq(s)}}}"),
        "comp_desc": ("c_desc", lambda s: f"    description: {dq(s)}"),
        "instance_desc": ("e_link", lambda s: f"  link: {{type: sd, c: 2.0, "
                                              f"description: {dq(s)}}}"),
    }
    field_items = list(fields.items()) + list(comp_fields.items())
    if private:
        field_items = field_items[::2]
    for fname, (key, fmt) in field_items:
        doc = COMP if fname in comp_fields else MSD
        for pname, s, exp in texts:
            # a unit is parsed (issue 26): hostile text there is refused (located) or escaped
            C.model_case("text", f"{fname}_{pname}", doc,
                         expect="any" if fname.endswith("_unit") else exp, key=key,
                         note=f"free text in {fname}: must reach the module only escaped",
                         **{key: fmt(s)})
    # file names: the model's (the Source: line) and a scene's without name:
    fnames = [(p, s, e) for p, s, e in texts if "\0" not in s and "/" not in s]
    for pname, s, exp in fnames[: (6 if private else 99)]:
        try:
            s.encode("utf-8")
            fexp = exp
        except UnicodeEncodeError:
            s = s.encode("utf-8", "surrogatepass").decode("utf-8", "ignore") + "\udcff"
            fexp = "any"
        fn = f"m{s}.yaml"
        C.model_case("text", f"filename_{pname}", MSD, expect=fexp, fname=fn,
                     note="the model's file name reaches the module's Source: line")
        C.scene_case("text", f"scene_filename_{pname}", expect="any",
                     scene_name=f"s{s}.yaml", name=None,
                     note="a scene without name: is named by its file name: escaped or refused")
    # text in the scene, compiled and (for a few) simulated: bgc imports the module itself
    for pname, s, exp in texts[:4]:
        C.scene_case("text", f"scene_desc_{pname}", expect=exp, desc=f"description: {dq(s)}",
                     note="scene description")
        C.scene_case("text", f"scene_nameless_sim_{pname}", expect="any", simulate=True,
                     name=None, scene_name=f"s{s.splitlines()[0] if s.strip() else 'x'}.yaml"
                     .replace("/", "_").replace("\0", "_"),
                     note="bgc simulate imports the module it generated: nothing may run")
    for pname, s, exp in texts[:2]:
        C.scene_case("text", f"plot_title_{pname}", expect=exp, simulate=True,
                     argv=["simulate", "scene.yaml", "--out", "r.npz", "--plot", "figs", "-q"],
                     out_files=["r.npz", "figs/"],
                     _after=["plots:", f"  - {{kind: time, outputs: [position], title: {dq(s)}, "
                                       f"labels: [{dq(s)}]}}"],
                     note="plot titles reach matplotlib only")
    C.scene_case("text", "plot_title_mathtext", expect="any", simulate=True,
                 argv=["simulate", "scene.yaml", "--out", "r.npz", "--plot", "figs", "-q"],
                 out_files=["r.npz", "figs/"],
                 _after=["plots:", '  - {kind: time, outputs: [position], title: "$\\\\frac{$"}'],
                 note="broken mathtext in a title")
    # plots whose outputs have the wrong shape for their kind (scalars on a 3-D path)
    for kind in ("path3d", "loci"):
        C.scene_case("semantic", f"plot_shape_{kind}", expect="error", simulate=True,
                     key="_after", out_files=[],
                     argv=["simulate", "scene.yaml", "--out", "r.npz", "--plot", "figs", "-q"],
                     _after=["plots:", f"  - {{kind: {kind}, outputs: [position, velocity]}}"],
                     message=f"{kind}|shape|vector|3|size|matri",
                     note="a plot's outputs must have the shape its kind draws")
        C.cases[-1]["line"] = [C.cases[-1]["line"], C.cases[-1]["line"] + 1]
    # explain imports both modules inside bgc
    for pname, s, exp in texts[:2]:
        C.scene_case("text", f"explain_{pname}", expect="any",
                     model_changes={"desc": f"description: {dq(s)}"},
                     argv=["explain", "scene.yaml", "--rounds", "1", "-q"], out_files=[],
                     note="bgc explain imports the modules it generates")

    # names: a full match, no trailing newline; refused with a located message
    name_fields = {
        "model": (MSD, "name", lambda n: f"name: {dq(n)}", "msd"),
        "element": (MSD, "e_v", lambda n: f'  {dq(n)}: {{type: "1"}}', "v"),
        "param": (MSD, "p_c", lambda n: f"  {dq(n)}: 4.0", "c"),
        "input": (MSD, "i_F", lambda n: f'  {dq(n)}: "F0"', "F"),
        "state": (MSD, "s_W", lambda n: f'  {dq(n)}: {{derivative: "power(damper)"}}', "W"),
        "output": (MSD, "o_vel", lambda n: f'  {dq(n)}: "f(mass)"', "velocity"),
        "effect": (MSD, "e_damper",
                   lambda n: f'  damper: {{type: R, resistance: "c", effects: [{dq(n)}]}}',
                   "damping"),
        "bond_name": (MSD, "b4", lambda n: f"  - {{from: v, to: damper, name: {dq(n)}}}", "bd"),
        "component": (COMP, "c_sd", lambda n: f"  {dq(n)}:", "sd"),
        "port": (COMP, "c_ports", lambda n: f"    ports: {{{dq(n)}: j}}", "a"),
    }
    for fname, (doc, key, fmt, base) in name_fields.items():
        for pname, pat in names:
            n = pat.format(base=base)
            C.model_case("names", f"{fname}_{pname}", doc, expect="error", key=key,
                         message="name|invalid|character|identifier", **{key: fmt(n)},
                         note="a name must match in full: refused, located")
    scene_names = {
        "scene_name": ("name", lambda n: f"name: {dq(n)}", "step"),
        "scene_effect": ("effects", lambda n: f"effects: {{{dq(n)}: on}}", "damping"),
        "scene_output": ("outputs", lambda n: f"outputs: [{dq(n)}]", "position"),
        "scene_param": ("parameters", lambda n: f"parameters: {{{dq(n)}: 3.0}}", "m"),
        "scene_input": ("inputs", lambda n: f"inputs: {{{dq(n)}: \"F0\"}}", "F"),
    }
    for fname, (key, fmt, base) in scene_names.items():
        for pname, pat in names[:4]:
            C.scene_case("names", f"{fname}_{pname}", expect="error", key=key,
                         message="name|invalid|character|identifier", **{key: fmt(pat.format(
                             base=base))})

    # ---- 2. YAML number spellings in every numeric slot --------------------------------
    slots = {
        "param_value": (MSD, "p_m", lambda v: f"  m: {{value: {v}, unit: kg}}"),
        "param_plain": (MSD, "p_k", lambda v: f"  k: {v}"),
        "param_min": (MSD, "p_m", lambda v: f"  m: {{value: 2.0, min: {v}}}"),
        "matrix_entry": (MSD, "p_k", lambda v: f"  k: [[{v}]]"),
        "initial": (MSD, "e_mass", lambda v: f'  mass: {{type: I, inertia: "m", initial: {v}}}'),
        "state_initial": (MSD, "s_W", lambda v: f'  W: {{initial: {v}, '
                                                f'derivative: "power(damper)"}}'),
        "input_default": (MSD, "i_F", lambda v: f"  F: {{default: {v}}}"),
        "law": (MSD, "e_damper", lambda v: f"  damper: {{type: R, resistance: {v}}}"),
        "instance_arg": (COMP, "e_link", lambda v: f"  link: {{type: sd, c: {v}}}"),
        "bond_n": (MSD, "b4", lambda v: f"  - {{from: v, to: damper, n: {v}}}"),
        "version": (MSD, "bgc", lambda v: f"bgc: {v}"),
    }
    for sname, (doc, key, fmt) in slots.items():
        for nname, spelling, exp, msg in numbers:
            e, m = exp, msg
            if nname.startswith("neg") and m:
                m += "|positive|negative|below|min"
            if sname == "param_min" and nname in ("neg_inf", "inf"):
                e, m = "any", None  # an infinite bound is arguably no bound
            if sname in ("bond_n", "version"):
                e, m = "error", None  # not a cardinality / version either way
            C.model_case("numbers", f"{sname}_{nname}", doc, expect=e, key=key, message=m,
                         note=f"YAML spelling {spelling[:20]} in {sname}",
                         **{key: fmt(spelling)})
    scene_slots = {
        "duration": ("duration", lambda v: f"duration: {v}"),
        "t_span_end": ("duration", lambda v: f"t_span: [0, {v}]"),
        "rtol": ("solver", lambda v: f"solver: {{rtol: {v}}}"),
        "atol": ("solver", lambda v: f"solver: {{atol: {v}}}"),
        "dt": ("solver", lambda v: f"solver: {{dt: {v}}}"),
        "breakpoint": ("breakpoints", lambda v: f"breakpoints: [{v}]"),
        "scene_param": ("parameters", lambda v: f"parameters: {{m: {v}}}"),
    }
    for sname, (key, fmt) in scene_slots.items():
        for nname, spelling, exp, msg in numbers[: (6 if private else 8)]:
            e, line = exp, None
            if nname.startswith("neg") and msg:
                msg += "|positive|negative|below|after|before"
            if sname in ("duration", "t_span_end"):  # the scene's start, or the entry
                _, w = SCENE.make(C.header("x", e, "y"), **{key: fmt(spelling)})
                line = [w["bgc_scene"], w[key]]
            C.scene_case("numbers", f"scene_{sname}_{nname}", expect=e, key=key, message=msg,
                         **{key: fmt(spelling)}, line=line,
                         note=f"{spelling[:20]} in the scene's {sname}")

    # ---- 3. expressions: whitelist, size and value ------------------------------------
    bad_syntax = [
        ("import", '__import__("os").system("touch pwned")'),
        ("lambda", "(lambda: k)()"),
        ("comprehension", "[k for k in [1]]"),
        ("ifexp", "k if m else c"),
        ("attribute", "k.__class__"),
        ("string", "'abc'"),
        ("fstring", 'f"{k}"'),
        ("kwarg", "sin(x=k)"),
        ("starred", "max(*[k, m])"),
        ("walrus", "(z := k)"),
        ("semicolon", "k; import os"),
        ("newline", "k\nimport os"),
        ("open", 'open("canary.txt", "w")'),
        ("np_attr", "np.sin(k)"),
        ("boolop", "k and m"),
        ("compare_eq", "k == m"),
        ("floordiv", "k // m"),
        ("slice", "k[::2]"),
        ("dict", "{k: m}"),
        ("ellipsis", "..."),
        ("caret", "k ^ 2"),
        ("signum", "signum(k)"),
        ("arity", "sin(k, m)"),
        ("unknown_name", "kk"),
        ("call_param", "k(1)"),
        ("bytes", "b'k'"),
        ("await", "await k"),
        ("yield", "(yield k)"),
    ]
    if private:
        bad_syntax = [("getattr", 'getattr(k, "real")'), ("globals", "globals()"),
                      ("bitnot", "~k"), ("matmul_scalar_str", "k @ 'x'"),
                      ("lshift", "k << 2"), ("set", "{k}"), ("ternary_chain", "k<m<c"),
                      ("percent", "k % m"), ("not", "not k"), ("is", "k is m")]
    for xname, text in bad_syntax:
        hint = {"caret": r"\*\*", "signum": r"\bsign\b"}.get(xname, "spring")
        _, w = MSD.make(C.header("x", "error", "y"))
        C.model_case("expr", f"syntax_{xname}", MSD, expect="error", key="e_spring",
                     message=hint, line=[w["e_spring"], w["e_spring"] + 1] if "\n" in text
                     else None, e_spring=f"  spring: {{type: C, stiffness: {dq(text)}}}",
                     note="an expression outside the whitelist: located, naming the element")
    bad_values = [  # (name, law text of the spring, expectation, message)
        ("float_inf", "1e999", "error", "finite|inf|large"),
        ("pow_huge", "10**400", "error", "large|finite|10"),
        ("pow_tower", "9**9**9", "error", "large|finite|10"),
        ("exp_1000", "exp(1000)", "error", "finite|inf|large|overflow"),
        ("div_zero", "k/0", "error", "zero|finite|infinite|divis"),
        ("zero_over_zero", "0/0", "error", "zero|finite|nan|divis|undefined"),
        ("log_zero", "k*log(0)", "error", "finite|inf|log|zero"),
        ("sqrt_neg", "sqrt(-1)", "error", "complex|real|imag|sqrt"),
        ("acos_2", "k*acos(2)", "error", "complex|real|imag|acos"),
        ("log_neg", "k + log(-1)", "error", "complex|real|imag|log"),
        ("exp3", "exp(exp(exp(100)))", "error", "finite|inf|large|overflow|bound|limit"),
        ("where_exp3", "where(exp(exp(exp(100))) > 1, k, m)", "any", None),
        ("eye_1000", "k*det(eye(1000) @ eye(1000))", "error", "size|large|limit|matrix|1000"),
        ("zeros_huge", "k + norm(zeros(100000))", "error", "size|large|limit|100000"),
        ("deep_parens", "(" * 500 + "k" + ")" * 500, "error", "deep|nest|level|long|limit"),
        ("huge_power_sym", "(k + m)**100000", "any", None),
        ("tiny", "1e-400 + k", "ok", None),
    ]
    if private:
        bad_values = [("sinh_big", "sinh(1e5)", "error", "finite|inf|large|overflow"),
                      ("neg_sqrt_param", "k*sqrt(-k)", "any", None),
                      ("inv_singular", "k*det(inv(zeros(3, 3)))", "error",
                       "singular|finite|inv|zero|invert"),
                      ("pow_neg", "0**-1 + k", "error", "zero|finite|infinite|divis"),
                      ("exp_exp", "exp(exp(10))", "error", "finite|inf|large|overflow")]
    for xname, text, exp, msg in bad_values:
        C.model_case("expr", f"value_{xname}", MSD, expect=exp, key="e_spring", message=msg,
                     e_spring=f"  spring: {{type: C, stiffness: {dq(text)}}}",
                     note="a constant that is not finite and real, or too much work")
    # derived parameters with bad values (the parameter's line)
    for xname, text, exp, msg in [("sqrt_neg", "sqrt(-1)", "error", "complex|real|imag"),
                                  ("inf", "1e308*10", "error", "finite|inf|large"),
                                  ("self", "F0b + 1", "error", "F0b|itself|cycle|circular"),
                                  ("nan", "0*1e999", "error", "finite|nan|inf")]:
        C.model_case("expr", f"derived_{xname}", MSD, expect=exp, key="p_F0", message=msg,
                     p_F0=f"  F0b: {dq(text)}", i_F='  F: {default: "F0b"}')
    # a huge expression made at test time (the law's line)
    text, where = MSD.make(C.header("expr/huge_sum", "error"),
                           e_spring="  spring: {type: C, stiffness: !!str LAW}")
    head, tail = text.split("LAW")
    C.add("expr", "huge_sum", argv=["compile", "model.yaml", "-o", "out.py", "-q"],
          expect="error", setup=[{"kind": "repeat", "name": "model.yaml", "head": head,
                                  "item": "k+", "count": 400000, "tail": "k" + tail}],
          check=["check", "model.yaml"], message="long|large|size|limit|deep|nest",
          line=where["e_spring"], note="an 800 kB expression (made at test time)")

    # ---- 4. models that compile to broken modules or crash the printer -----------------
    sem = [
        ("zero_inertia", "e_mass", '  mass: {type: I, inertia: "0"}', "error",
         "zero|singular|infinite|inertia|mass"),
        ("zero_inertia_param", "p_m", "  m: 0", "any", None),
        ("c_own_effort", "e_spring", '  spring: {type: C, effort: "k*q(spring) + e(spring)"}',
         "error", "spring"),
        ("r_own_flow", "e_damper", '  damper: {type: R, flow: "f(damper)/2 + e(damper)"}',
         "error", "damper"),
        ("matrix_1x1_on_3bond", "b4", "  - {from: v, to: damper, n: 3}", "error", None),
        ("nonfinite_initial", "e_mass", '  mass: {type: I, inertia: "m", initial: "1/0"}',
         "error", "finite|zero|infinite|divis"),
        ("complex_initial", "e_mass", '  mass: {type: I, inertia: "m", initial: "sqrt(-2)"}',
         "error", "complex|real|imag"),
    ]
    # a zero inertia given as a parameter's value: the error may name the parameter or the
    # element whose law divides by it (bgc compile checks rhs at X0 with the defaults)
    lines = {"zero_inertia_param": ("p_m", "e_mass")}
    for sname, key, line, exp, msg in sem:
        ch = {key: line}
        if sname == "matrix_1x1_on_3bond":
            continue
        C.model_case("semantic", sname, MSD, expect=exp, key=key, message=msg,
                     line=lines.get(sname), **ch)
    three = Doc([
        ("bgc", "bgc: 1"), ("name", "name: three"),
        ("params", "parameters: {m: 1.0, Rm: [[4.0]]}"),
        ("elements", "elements:"),
        ("e_src", '  src: {type: Se, effort: "[1.0, 0.0, 0.0]"}'),
        ("e_j", '  j: {type: "1"}'),
        ("e_mass", '  mass: {type: I, inertia: "m"}'),
        ("e_damper", '  damper: {type: R, resistance: "Rm"}'),
        ("bonds", "bonds:"),
        ("b1", "  - {from: src, to: j, n: 3}"), ("b2", "  - {from: j, to: mass, n: 3}"),
        ("b3", "  - {from: j, to: damper, n: 3}"),
        ("outputs", 'outputs: {v: "f(mass)"}'),
    ])
    _, tw = three.make(["#", "#"])
    C.model_case("semantic", "matrix_1x1_on_3bond", three, expect="error", key="e_damper",
                 line=[tw["e_damper"], tw["params"], tw["b3"]],
                 message="1x1|1 x 1|1\u00d71|shape|3x3|3 x 3|dimension|size|cardinality",
                 note="a 1x1 matrix law on a 3-bond: refused, not a broken module")
    C.model_case("semantic", "scalar_on_3bond", three, expect="ok",
                 e_damper='  damper: {type: R, resistance: "4.0"}',
                 note="the same with a scalar resistance: valid (r times the identity)")
    # the module's own locals and imports as model names: refused, or harmless (same rhs)
    locals_ = ["x0", "P", "X0", "N_STATES", "PARAM_DEFAULTS", "SimulationError", "q_spring",
               "p_mass", "e_b3", "f_b2", "u_F", "rtol", "dt", "np_", "J", "dx", "scipy",
               "self", "SimResult", "METHODS", "np", "rhs", "numpy", "simulate"]
    if private:
        locals_ = ["x0", "method", "t_span", "JAC_SPARSITY", "STATE_NAMES", "p_spring"]
    for nm in locals_:
        twin_text, _ = MSD.make([f"# the clean twin of semantic/shadow_{nm}"],
                                p_k="  kk: {value: 200.0, unit: N/m}",
                                e_spring='  spring: {type: C, stiffness: "kk"}')
        twin = C.write(f"semantic/shadow_{nm}.twin.yaml", twin_text)
        _, w = MSD.make(C.header("x", "any", "y"))
        C.model_case("semantic", f"shadow_{nm}", MSD, expect="any", key="p_k",
                     message=None, line=[w["p_k"], w["e_spring"]], twin="twin.yaml", extra_files={"twin.yaml": twin},
                     p_k=f"  {nm}: {{value: 200.0, unit: N/m}}",
                     e_spring=f'  spring: {{type: C, stiffness: "{nm}"}}',
                     note="a parameter named like a local of the module: refused, or the same "
                          "rhs as the clean twin")
    # issue 10's modelling bugs
    C.model_case("semantic", "auto_bond_name_vs_param", MSD, expect="ok",
                 p_F0="  b1: 10.0", i_F='  F: {default: "b1"}',
                 note="bonds named b1.. automatically must not collide with a parameter b1")
    mtf = Doc([
        ("bgc", "bgc: 1"), ("name", "name: planar"),
        ("params", "parameters: {m: 1.0, k: 10.0, a: 0.6, b: 0.8}"),
        ("elements", "elements:"),
        ("e_src", '  drive: {type: Se, effort: "1.0"}'),
        ("e_j", '  j: {type: "1"}'),
        ("e_mass", '  mass: {type: I, inertia: "m"}'),
        ("e_tf", '  tf: {type: MTF, modulus: [[a], [b]]}'),
        ("e_j2", '  j2: {type: "1"}'),
        ("e_spring", '  spring: {type: C, stiffness: "k*eye(2)"}'),
        ("bonds", "bonds:"),
        ("b1", "  - [drive, j]"), ("b2", "  - [j, mass]"), ("b3", "  - [j, tf]"),
        ("b4", "  - {from: tf, to: j2, n: 2}"), ("b5", "  - {from: j2, to: spring, n: 2}"),
        ("outputs", 'outputs: {v: "f(mass)"}'),
    ])
    C.model_case("semantic", "mtf_scalar_to_2vector", mtf, expect="ok",
                 note="an MTF from a scalar bond to a 2-vector multibond (a 2x1 modulus)")

    # ---- 5. resource exhaustion --------------------------------------------------------
    R = "resources"
    base_text, _ = MSD.make(["# a valid model"])
    base_rel = C.write(f"{R}/base_model.yaml", base_text)

    def res_case(name, setup, expect="error", message=None, line=None, argv=None, files=None,
                 located=True, note=""):
        C.add(R, name, argv=argv or ["compile", "model.yaml", "-o", "out.py", "-q"],
              expect=expect, files=files or {}, setup=setup,
              outputs=["out.py"] if expect != "error" else [], message=message, line=line,
              located=located, note=note,
              check=["check", (argv or ["", "model.yaml"])[1]] if (argv or ["compile"])[0]
              == "compile" else None)

    nonreg = "regular|not a file|fifo|device|special|directory|size|large"
    res_case("model_fifo", [{"kind": "fifo", "name": "model.yaml"}], message=nonreg, line=1,
             note="a FIFO would block for ever")
    res_case("model_dev_zero", [{"kind": "symlink", "name": "model.yaml",
                                 "target": "/dev/zero"}], message=nonreg, line=1)
    res_case("model_dev_urandom", [{"kind": "symlink", "name": "model.yaml",
                                    "target": "/dev/urandom"}], message=nonreg, line=1)
    res_case("model_directory", [{"kind": "mkdir", "name": "model.yaml"}],
             message="regular|not a file|directory|read", line=1)
    C.cases[-1]["usage"] = True  # click's own check of the argument may answer first
    res_case("model_sparse_10g", [{"kind": "sparse", "name": "model.yaml", "size": 10 << 30}],
             message="size|large|MB|bytes|limit", line=1, note="10 GB, no room taken")
    res_case("model_6mb", [{"kind": "repeat", "name": "model.yaml", "head": base_text +
                            "# ", "item": "x" * 64, "count": 100000, "tail": "\n"}],
             message="size|large|MB|bytes|limit", line=1)
    res_case("model_symlink_loop", [{"kind": "symlink", "name": "model.yaml",
                                     "target": "loop.yaml"},
                                    {"kind": "symlink", "name": "loop.yaml",
                                     "target": "model.yaml"}],
             message="read|link|loop|exist|regular", line=1)
    res_case("model_missing", [], message="exist|read|no such|not found", line=1)
    res_case("model_binary", [{"kind": "repeat", "name": "model.yaml", "head": "",
                               "item": "\x01\x02", "count": 100}],
             message="character|YAML|binary|utf|decode|not allowed", line=1)
    C.write(f"{R}/latin1.yaml", base_text.replace("mass-spring", "mass-spr\u00efng")
            .encode("latin-1"))
    res_case("model_latin1", [], files={"model.yaml": f"{R}/latin1.yaml"},
             message="utf|decode|encoding|character|read", line=[1, 3, 4, 5])
    # imports: a binary fan-out (2^16 paths, 32 files), cycles, odd targets
    depth = 12 if private else 16
    fan = {}
    for lv in range(depth):
        for side in "ab":
            nxt = ("" if lv == depth - 1 else
                   f"imports:\n  - {{file: l{lv + 1}a.yaml}}\n  - {{file: l{lv + 1}b.yaml}}\n")
            body = (f"bgc: 1\nname: l{lv}{side}\n{nxt}components:\n  c{lv}{side}:\n"
                    "    parameters: {k: 1.0}\n    ports: {a: s}\n"
                    '    elements: {s: {type: C, stiffness: "k"}}\n    bonds: []\n'
                    "elements: {}\nbonds: []\n")
            fan[f"l{lv}{side}.yaml"] = C.write(f"{R}/fanout/l{lv}{side}.yaml", body)
    top = ("# fuzz case resources/import_fanout: expect ok\nbgc: 1\nname: fanout\n"
           "imports:\n  - {file: l0a.yaml}\n  - {file: l0b.yaml}\n"
           "parameters: {m: 1.0}\nelements:\n  mass: {type: I, inertia: \"m\"}\n"
           f"  v: {{type: \"1\"}}\n  leaf: {{type: c{depth - 1}a}}\n"
           "bonds:\n  - [v, mass]\n  - [v, leaf.a]\noutputs: {x: \"f(mass)\"}\n")
    fan["model.yaml"] = C.write(f"{R}/fanout/model.yaml", top)
    res_case("import_fanout", [], expect="ok", files=fan,
             note=f"each file imports the next level twice: 2^{depth} paths, {2 * depth} files")
    imp = ("bgc: 1\nname: imp\nimports:\n  - {file: TARGET}\nparameters: {m: 1.0}\n"
           'elements:\n  mass: {type: I, inertia: "m"}\n  s: {type: Se, effort: "1.0"}\n'
           "bonds:\n  - [s, mass]\n")
    import_targets = [
        ("self", "model.yaml", [], "cycle|itself|import"),
        ("fifo", "pipe.yaml", [{"kind": "fifo", "name": "pipe.yaml"}], nonreg),
        ("dev_zero", "zero.yaml", [{"kind": "symlink", "name": "zero.yaml",
                                    "target": "/dev/zero"}], nonreg),
        ("directory", "sub", [{"kind": "mkdir", "name": "sub"}], "regular|directory|exist|file"),
        ("nul_in_path", '"a\\0b.yaml"', [], "invalid|character|NUL|null|exist|path"),
        ("symlink_loop", "la.yaml", [{"kind": "symlink", "name": "la.yaml",
                                      "target": "lb.yaml"},
                                     {"kind": "symlink", "name": "lb.yaml",
                                      "target": "la.yaml"}], "link|loop|exist|read|regular"),
        ("etc_passwd", "/etc/passwd", [], "mapping|YAML|model|import|outside|absolute|"
                                          "regular|exist"),
        ("sparse", "big.yaml", [{"kind": "sparse", "name": "big.yaml", "size": 10 << 30}],
         "size|large|MB|bytes|limit"),
        ("long_path", "a" * 5000 + ".yaml", [], "long|exist|path|read|invalid"),
        ("missing", "nothere.yaml", [], "exist|not found|no such"),
    ]
    for iname, target, setup, msg in import_targets:
        if iname in ("fifo", "dev_zero"):
            msg += "|exist"  # refused before it is opened: the word may be "does not exist"
        rel = C.write(f"{R}/import_{iname}.yaml",
                      f"# fuzz case resources/import_{iname}: expect error\n" +
                      imp.replace("TARGET", target))
        res_case(f"import_{iname}", setup, files={"model.yaml": rel}, message=msg,
                 line=None if iname in ("self", "etc_passwd") else [1, 5])
    # components: 16 instances per level, 7 levels (16^7 leaves)
    lv, fanout = (5, 12) if private else (7, 16)
    comps = ["components:", "  c0:", "    parameters: {k: 1.0}", "    ports: {a: s}",
             '    elements: {s: {type: C, stiffness: "k"}}', "    bonds: []"]
    for i in range(1, lv + 1):
        comps += [f"  c{i}:", "    ports: {a: j}", "    elements:", '      j: {type: "0"}']
        comps += [f"      i{n}: {{type: c{i - 1}}}" for n in range(fanout)]
        comps += ["    bonds:"] + [f"      - [j, i{n}.a]" for n in range(fanout)]
    body = (["# fuzz case resources/component_explosion: expect error", "bgc: 1",
             "name: explode"] + comps + ["parameters: {m: 1.0}", "elements:",
                                         '  mass: {type: I, inertia: "m"}',
                                         '  v: {type: "1"}', f"  top: {{type: c{lv}}}",
                                         "bonds:", "  - [v, mass]", "  - [v, top.a]"])
    rel = C.write(f"{R}/component_explosion.yaml", "\n".join(body) + "\n")
    res_case("component_explosion", [], files={"model.yaml": rel},
             message="element|instance|limit|many|large|size",
             note=f"{fanout}^{lv} leaves: a cap on instantiated elements")
    # scenes: sizes and run lengths
    SC = "resources"
    C.scene_case(SC, "scene_dt_1e-9", expect="error", key="solver", simulate=True,
                 solver="solver: {method: Radau, dt: 1.0e-9}",
                 message="sample|dt|points|many|limit|large", note="7 GiB of output grid")
    C.scene_case(SC, "scene_max_step_1e-300", expect="error", key="solver", simulate=True,
                 solver="solver: {max_step: 1.0e-300}",
                 message="max_step|step|small|limit", note="would never end")
    C.scene_case(SC, "scene_t_span_1e309", expect="error", key="duration", simulate=True,
                 duration="t_span: [0, 1e309]", message="finite|inf|t_span|large|range")
    C.scene_case(SC, "scene_t_span_huge", expect="error", key="duration", simulate=True,
                 duration="t_span: [1.0e300, 1.0000000000000002e300]",
                 message="t_span|time|range|resolution|dt|sample|step|large|limit")
    C.scene_case(SC, "scene_fifo", expect="error", line=1, argv=["simulate", "pipe.yaml",
                 "--out", "r.npz", "-q"], out_files=[],
                 setup=[{"kind": "fifo", "name": "pipe.yaml"}], message=nonreg)
    C.scene_case(SC, "scene_dev_zero", expect="error", line=1, argv=["simulate", "z.yaml", "-q"],
                 out_files=[], setup=[{"kind": "symlink", "name": "z.yaml",
                                     "target": "/dev/zero"}], message=nonreg)
    C.scene_case(SC, "scene_6mb", expect="error", line=1,
                 argv=["simulate", "big.yaml", "-q"], out_files=[],
                 setup=[{"kind": "repeat", "name": "big.yaml",
                         "head": "bgc_scene: 1\nmodel: model.yaml\nduration: 1.0\n# ",
                         "item": "y" * 64, "count": 100000, "tail": "\n"}],
                 message="size|large|MB|bytes|limit")
    C.scene_case(SC, "scene_model_fifo", expect="error", key="model",
                 model="model: pipe.yaml", setup=[{"kind": "fifo", "name": "pipe.yaml"}],
                 argv=["simulate", "scene.yaml", "-q"], out_files=[], message=nonreg + "|exist")
    C.scene_case(SC, "scene_model_dev_zero", expect="error", key="model",
                 model="model: zero.yaml", setup=[{"kind": "symlink", "name": "zero.yaml",
                                                   "target": "/dev/zero"}],
                 argv=["simulate", "scene.yaml", "-q"], out_files=[], message=nonreg + "|exist")
    C.scene_case(SC, "scene_model_itself", expect="error",
                 model="model: scene.yaml", argv=["simulate", "scene.yaml", "-q"], out_files=[],
                 message="model|missing|key|bgc|scene")
    C.scene_case(SC, "scene_breakpoints_many", expect="error", simulate=True,
                 key="breakpoints", breakpoints="breakpoints: !!str BPS", setup=[],
                 message="breakpoint|many|limit|large|size|bytes")
    # rewrite that last one at test time: 200000 breakpoints
    last = C.cases[-1]
    stext = (root / last["files"]["scene.yaml"]).read_text()
    head, tail = stext.split("!!str BPS")
    last["setup"] = [{"kind": "repeat", "name": "scene.yaml", "head": head + "[",
                      "item": "0.5, ", "count": 100000, "tail": "0.5]" + tail}]
    last["line"] = [1, last["line"]]  # a size limit on the scene file may answer first

    # ---- 6. numerical failures during a run (simulate) ---------------------------------
    tanks = ("bgc: 1\nname: tanks\nparameters: {C1: 1.0, C2: 1.0, a: 1.0}\nelements:\n"
             '  tank1: {type: C, compliance: "C1", initial: 1.0}\n'
             '  tank2: {type: C, compliance: "C2", initial: 1.0}\n'
             '  n1: {type: "0"}\n  n2: {type: "0"}\n  pipe: {type: "1"}\n'
             '  orifice: {type: R, flow: "a*sign(e(orifice))*sqrt(abs(e(orifice)))"}\n'
             "bonds:\n  - [n1, tank1]\n  - [n1, pipe]\n  - [pipe, orifice]\n"
             "  - [pipe, n2]\n  - [n2, tank2]\n"
             'outputs: {level1: "q(tank1)", level2: "q(tank2)"}\n')
    trel = C.write("runtime/tanks.yaml", "# two tanks at the same level joined by an orifice: "
                   "the law's slope is infinite at zero pressure difference\n" + tanks)
    for meth in (["Radau", "BDF", "Rodas4", "RK45"] if not private else ["LSODA", "DOP853"]):
        exp = "error" if meth in ("Radau", "BDF", "Rodas4", "LSODA") else "any"
        cid = f"orifice_{meth}"
        srel = C.write(f"runtime/{cid}.yaml",
                       f"# fuzz case runtime/{cid}: expect {exp}\nbgc_scene: 1\nname: drain\n"
                       f"model: model.yaml\nduration: 1.0\nsolver: {{method: {meth}}}\n")
        C.add("runtime", cid, argv=["simulate", "scene.yaml", "--out", "r.npz", "-q"],
              expect=exp, files={"scene.yaml": srel, "model.yaml": trel}, outputs=["r.npz"],
              message="orifice" if exp == "error" else None, exit=(1, 2), located=False,
              check=None, note="a law with infinite slope at zero (the orifice at equal levels)"
                               ": one message naming the element, no numpy warning")
    C.scene_case("runtime", "blowup_exp", expect="error", simulate=True,
                 model_changes={"s_W": '  W: {initial: 0, derivative: "exp(exp(W))"}',
                                "o_vel": ['  velocity: "f(mass)"', '  work: "W"']},
                 outputs="outputs: [position, work]",
                 message=r"\bW\b|fail|finite|overflow", exit=(1, 2), located=False,
                 note="dW/dt = exp(exp(W)) from 0 reaches infinity at t = E1(1) = 0.219 s: "
                      "one message naming the state, no warning")
    C.scene_case("runtime", "sqrt_negative_state", expect="error", simulate=True,
                 model_changes={"e_damper": '  damper: {type: R, effort: "sqrt(f(damper) - 1)",'
                                            " effects: [damping]}"},
                 message="damper", exit=(1, 2), located=False,
                 note="sqrt of a negative value at X0: complex/NaN, a diagnostic naming it")

    # ---- 7. command lines: output paths and options ------------------------------------
    Cl = "cli"
    if private:
        _private_cli(C, base_rel)
        return _sample(C, rng)
    scene_text, _ = SCENE.make(["# a valid scene"])
    srel = C.write(f"{Cl}/scene.yaml", scene_text)
    mfiles = {"model.yaml": base_rel}
    sfiles = {"model.yaml": base_rel, "scene.yaml": srel}
    outerr = "output|write|path|file|name|directory|exist|permission|long|empty|device|regular"

    def cli(name, argv, files, expect="error", message=outerr, setup=(), outputs=(),
            usage=False, located=False, line=None, note=""):
        C.add(Cl, name, argv=argv, files=files, expect=expect, message=message,
              setup=setup, outputs=outputs, usage=usage, located=located, line=line,
              check=None, note=note)

    cli("o_empty", ["compile", "model.yaml", "-o", "", "-q"], mfiles)
    cli("o_300_chars", ["compile", "model.yaml", "-o", "a" * 300 + ".py", "-q"], mfiles)
    cli("o_proc", ["compile", "model.yaml", "-o", "/proc/x.py", "-q"], mfiles)
    cli("o_proc_subdir", ["compile", "model.yaml", "-o", "/proc/self/bgc_x/y.py", "-q"], mfiles)
    cli("o_model_itself", ["compile", "model.yaml", "-o", "model.yaml", "-q"], mfiles,
        message="input|model|overwrite|same|itself")
    cli("o_model_other_spelling", ["compile", "model.yaml", "-o", "./sub/../model.yaml", "-q"],
        mfiles, setup=[{"kind": "mkdir", "name": "sub"}],
        message="input|model|overwrite|same|itself")
    cli("o_symlink_to_model", ["compile", "model.yaml", "-o", "link.py", "-q"], mfiles,
        setup=[{"kind": "symlink", "name": "link.py", "target": "model.yaml"}],
        message="input|model|overwrite|same|itself|link|regular")
    cli("o_fifo", ["compile", "model.yaml", "-o", "pipe.py", "-q"], mfiles,
        setup=[{"kind": "fifo", "name": "pipe.py"}], message="regular|fifo|device|special")
    cli("o_device", ["compile", "model.yaml", "-o", "null.py", "-q"], mfiles,
        setup=[{"kind": "nulldev", "name": "null.py"}], message="regular|device|special|link")
    cli("o_directory", ["compile", "model.yaml", "-o", "sub", "-q"], mfiles,
        setup=[{"kind": "mkdir", "name": "sub"}], usage=True,
        message="directory|regular|sub")
    cli("o_subdir_new", ["compile", "model.yaml", "-o", "new/dir/out.py", "-q"], mfiles,
        expect="any", outputs=["new/", "new/dir/out.py"])
    cli("graph_missing_folder", ["graph", "model.yaml", "-o", "out/g.svg"], mfiles,
        expect="any", outputs=["out/", "out/g.svg"])
    cli("graph_missing_folder_dot", ["graph", "model.yaml", "-o", "out/g.dot"], mfiles,
        expect="any", outputs=["out/", "out/g.dot"])
    cli("graph_model_itself", ["graph", "model.yaml", "-o", "model.yaml"], mfiles,
        message="input|model|overwrite|same|itself|format|\\.yaml")
    cli("graph_bad_suffix", ["graph", "model.yaml", "-o", "g.txt"], mfiles,
        message="format|suffix|\\.txt|dot")
    cli("graph_fifo", ["graph", "model.yaml", "-o", "g.dot"], mfiles,
        setup=[{"kind": "fifo", "name": "g.dot"}], message="regular|fifo|device|special")
    cli("sim_out_device", ["simulate", "scene.yaml", "--out", "null.npz", "-q"], sfiles,
        setup=[{"kind": "nulldev", "name": "null.npz"}], message="regular|device|special|link")
    cli("sim_out_fifo", ["simulate", "scene.yaml", "--out", "pipe.npz", "-q"], sfiles,
        setup=[{"kind": "fifo", "name": "pipe.npz"}], message="regular|fifo|device|special")
    cli("sim_out_scene", ["simulate", "scene.yaml", "--out", "scene.yaml", "-q"], sfiles,
        message="input|scene|overwrite|same|itself")
    cli("sim_out_model", ["simulate", "scene.yaml", "--out", "model.yaml", "-q"], sfiles,
        message="input|model|overwrite|same|itself")
    cli("sim_out_symlink_model", ["simulate", "scene.yaml", "--out", "r.npz", "-q"], sfiles,
        setup=[{"kind": "symlink", "name": "r.npz", "target": "model.yaml"}],
        message="input|model|overwrite|same|itself|link|regular")
    cli("sim_out_empty", ["simulate", "scene.yaml", "--out", "", "-q"], sfiles, expect="any")
    cli("sim_plot_is_file", ["simulate", "scene.yaml", "--plot", "model.yaml", "-q"], sfiles,
        message="plot|directory|folder|exist|file|model", usage=True)
    cli("sim_rtol_inf", ["simulate", "scene.yaml", "--rtol", "inf", "-q"], sfiles,
        message="rtol", usage=True)
    cli("sim_rtol_nan", ["simulate", "scene.yaml", "--rtol", "nan", "-q"], sfiles,
        message="rtol", usage=True)
    cli("sim_rtol_huge", ["simulate", "scene.yaml", "--rtol", "1e300", "-q"], sfiles,
        message="rtol", usage=True)
    cli("sim_max_wall_inf", ["simulate", "scene.yaml", "--max-wall", "inf", "-q"], sfiles,
        expect="any", outputs=[], usage=True, message="max.wall|finite")
    cli("sim_max_wall_nan", ["simulate", "scene.yaml", "--max-wall", "nan", "-q"], sfiles,
        message="max.wall", usage=True)
    cli("sim_method_unknown", ["simulate", "scene.yaml", "--method", "Euler", "-q"], sfiles,
        message="method|Euler", usage=True)
    cli("compile_scene_other_model", ["compile", "other.yaml", "--scene", "scene.yaml", "-o",
                                      "out.py", "-q"],
        {"other.yaml": base_rel, "scene.yaml": srel, "model.yaml": base_rel},
        message="scene is for|model|other", located=True)
    cli("explain_rounds_0", ["explain", "scene.yaml", "--rounds", "0"], sfiles,
        message="rounds", usage=True)
    cli("sim_scene_missing", ["simulate", "nothere.yaml", "-q"], sfiles,
        message="exist|read|no such|not found", located=False)
    cli("compile_default_out_ok", ["compile", "model.yaml", "-q"], mfiles, expect="ok",
        message=None, outputs=["msd.py"])
    cli("compile_ok_sanity", ["compile", "model.yaml", "-o", "out.py", "-q"], mfiles,
        expect="ok", message=None, outputs=["out.py"])
    cli("simulate_ok_sanity", ["simulate", "scene.yaml", "--out", "r.npz", "-q"], sfiles,
        expect="ok", message=None, outputs=["r.npz"])
    import sys

    sys.path.insert(0, str(HERE))
    from cases_issue21 import add_issue21_cases

    add_issue21_cases(C, base_rel, MSD, SCENE, dq)
    # every ok case expects the umask's permissions: 0644 under umask 022
    C.cases = [c for c in C.cases if c is not None]
    return C


def _private_cli(C: Corpus, base_rel: str) -> None:
    """Command lines of the private set: other paths and values than the committed ones."""
    scene_text, _ = SCENE.make(["# a valid scene"])
    srel = C.write("cli/scene.yaml", scene_text)
    mf, sf = {"model.yaml": base_rel}, {"model.yaml": base_rel, "scene.yaml": srel}
    outerr = "output|write|path|file|name|directory|exist|permission|long|empty|device|regular"
    for name, argv, files, setup, msg, usage in [
        ("o_256", ["compile", "model.yaml", "-o", "b" * 256, "-q"], mf, [], outerr, False),
        ("o_sys", ["compile", "model.yaml", "-o", "/sys/bgc.py", "-q"], mf, [], outerr, False),
        ("o_dotdot_model", ["compile", "model.yaml", "-o", "d/../model.yaml", "-q"], mf,
         [{"kind": "mkdir", "name": "d"}], "input|model|overwrite|same|itself", False),
        ("o_hardlink_like", ["compile", "model.yaml", "-o", "./model.yaml", "-q"], mf, [],
         "input|model|overwrite|same|itself", False),
        ("graph_dev", ["graph", "model.yaml", "-o", "n.dot"], mf,
         [{"kind": "nulldev", "name": "n.dot"}], "regular|device|special|link", False),
        ("sim_out_dir_scene", ["simulate", "scene.yaml", "--out", "./scene.yaml", "-q"], sf, [],
         "input|scene|overwrite|same|itself", False),
        ("sim_rtol_neg_inf", ["simulate", "scene.yaml", "--rtol", "-inf", "-q"], sf, [], "rtol",
         True),
        ("sim_rtol_zero", ["simulate", "scene.yaml", "--rtol", "0", "-q"], sf, [], "rtol", True),
        ("sim_out_link_dev", ["simulate", "scene.yaml", "--out", "z.npz", "-q"], sf,
         [{"kind": "symlink", "name": "z.npz", "target": "/dev/null"}],
         "regular|device|special|link", False),
    ]:
        C.add("cli", name, argv=argv, files=files, expect="error", message=msg, setup=setup,
              usage=usage, located=False, check=None)


def _sample(C: Corpus, rng: random.Random, caps=None) -> Corpus:
    """About a hundred cases, drawn per category; files no case uses are removed."""
    caps = caps or {"text": 20, "names": 15, "numbers": 20, "expr": 12, "semantic": 8,
                    "resources": 10, "runtime": 4, "cli": 9}
    keep = []
    for cat, cap in caps.items():
        cs = [c for c in C.cases if c["category"] == cat]
        keep += rng.sample(cs, min(cap, len(cs)))
    order = {id(c): i for i, c in enumerate(C.cases)}
    C.cases = sorted(keep, key=lambda c: order[id(c)])
    used = {v for c in C.cases for v in c["files"].values()}
    for p in sorted(C.root.rglob("*"), reverse=True):
        rel = p.relative_to(C.root).as_posix()
        if p.is_file() and rel not in used:
            p.unlink()
        elif p.is_dir() and not any(p.iterdir()):
            p.rmdir()
    return C


def write_manifest(C: Corpus, root: Path, private: bool) -> None:
    head = ("# The expected outcome of every case in this folder (generated by "
            "tests/fuzz/make_corpus.py;\n# regenerate, do not edit). Fields: "
            "tests/fuzz/harness.py (class Case).\n")
    data = {"private": private, "cases": C.cases}
    text = yaml.safe_dump(data, sort_keys=False, allow_unicode=False, width=100,
                          default_flow_style=None)
    (root / "expected.yaml").write_text(head + text, encoding="utf-8")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=str(HERE / "corpus"))
    ap.add_argument("--private", default=None,
                    help="write the other (uncommitted) set here: other strings, other seed")
    ap.add_argument("--seed", type=int, default=None)
    a = ap.parse_args(argv)
    private = a.private is not None
    root = Path(a.private if private else a.out)
    if root.exists():
        shutil.rmtree(root)
    root.mkdir(parents=True)
    C = build(root, private=private, seed=a.seed if a.seed is not None else (7 if private else 0))
    write_manifest(C, root, private)
    cats: dict[str, int] = {}
    for c in C.cases:
        cats[c["category"]] = cats.get(c["category"], 0) + 1
    print(f"{len(C.cases)} cases in {root}: " + ", ".join(f"{k} {v}" for k, v in cats.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
