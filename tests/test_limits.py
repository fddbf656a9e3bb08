"""Untrusted input meets bounded work (issue 10): reading files, imports, instantiation, scenes,
names the generated module uses itself, message length, and the bugs found while modelling.

Every refusal is a located ModelError that names its limit; the hostile inputs here would hang,
exhaust memory or give a traceback without the limits (a FIFO blocks ``read`` for ever,
``/dev/zero`` never ends, 28 files importing the next twice are 2**27 parses, 16 instances on
each of 7 levels are 268 million elements).
"""
from __future__ import annotations

import ast
import builtins
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bgc.backends.load import load_module
from bgc.base.errors import Coord, ModelError
from bgc.base.limits import LIMITS
from bgc.base.safeio import read_text_bounded
from bgc.format import parse as parse_mod
from bgc.format import reader as reader_mod
from bgc.format.parse import RESERVED, parse_file, parse_text
from bgc.format.scene import parse_scene
from bgc.run.driver import compile_file, compile_model

ROOT = Path(__file__).resolve().parents[1]

MSD = """bgc: 1
name: msd
parameters: {m: 2.0, k: 200.0}
elements:
  force:  {type: Se, effort: "1"}
  mass:   {type: I, inertia: "m"}
  spring: {type: C, stiffness: "k"}
  v:      {type: "1"}
bonds:
  - [force, v]
  - [v, mass]
  - [v, spring]
"""


def refused(fn, *args, **kw) -> ModelError:
    with pytest.raises(ModelError) as info:
        fn(*args, **kw)
    err = info.value
    assert err.coord is not None, err
    assert "\n" not in str(err)
    return err


# ---------------------------------------------------------------------------------------------
# Reading files


def test_fifo_is_refused_without_blocking(tmp_path):
    fifo = tmp_path / "model.yaml"
    os.mkfifo(fifo)  # no writer: a plain read would block for ever
    err = refused(parse_file, fifo)
    assert "not a regular file" in err.message
    assert err.coord == Coord(str(fifo), 1, 1)


def test_folder_is_refused(tmp_path):
    err = refused(parse_file, tmp_path)
    assert "it is a folder" in err.message


@pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="no /dev/zero")
def test_device_is_refused():
    err = refused(parse_file, "/dev/zero")
    assert "not a regular file" in err.message


def test_size_is_checked_before_reading(tmp_path):
    big = tmp_path / "big.yaml"
    with open(big, "wb") as fh:  # sparse: 10 GB that occupy no disk
        fh.truncate(10 * 1024 ** 3)
    err = refused(parse_file, big)
    assert f"larger than the limit of {LIMITS.model_bytes} bytes" in err.message


def test_reading_stops_at_the_limit(tmp_path):
    p = tmp_path / "m.yaml"
    p.write_bytes(b"a" * 101)
    with pytest.raises(ModelError, match="limit of 100 bytes"):
        read_text_bounded(p, None, "model file", 100)
    assert read_text_bounded(p, None, "model file", 101) == "a" * 101


def test_scene_size_is_limited(tmp_path):
    (tmp_path / "m.yaml").write_text(MSD)
    scene = tmp_path / "s.yaml"
    scene.write_text("bgc_scene: 1\nmodel: m.yaml\nduration: 1\n# "
                     + "x" * LIMITS.scene_bytes + "\n")
    err = refused(parse_scene, scene)
    assert f"scene file {str(scene)!r} is larger than the limit" in err.message


def test_symlink_loop_model_and_import(tmp_path):
    a, b = tmp_path / "a.yaml", tmp_path / "b.yaml"
    a.symlink_to(b)
    b.symlink_to(a)
    err = refused(parse_file, a)
    assert "symbolic links" in err.message
    main = tmp_path / "main.yaml"
    main.write_text(MSD.replace("name: msd\n", "name: msd\nimports: [{file: a.yaml}]\n"))
    err = refused(parse_file, main)
    assert err.coord.file == str(main) and err.coord.line == 3
    assert "symbolic links" in err.message


def test_non_utf8_is_located(tmp_path):
    p = tmp_path / "m.yaml"
    p.write_bytes(MSD.encode().replace(b"name: msd", b"name: m\xffsd"))
    err = refused(parse_file, p)
    assert (err.coord.line, err.coord.column) == (2, 8)
    assert "not UTF-8" in err.message


# ---------------------------------------------------------------------------------------------
# Imports


PART = """bgc: 1
name: part{i}
imports: [{{file: part{j}.yaml}}, {{file: part{j}.yaml}}]
components:
  C{i}:
    ports: {{a: x}}
    parameters: {{c: 1.0}}
    elements: {{x: {{type: C, stiffness: c}}}}
    bonds: []
elements: {{}}
bonds: []
"""


def test_imports_are_parsed_once(tmp_path, monkeypatch):
    """28 files, each importing the next twice: each is parsed once (not 2**27 times), and
    the component every path reaches is listed once."""
    n = 28
    for i in range(n):
        text = PART.format(i=i, j=i + 1)
        if i == n - 1:
            text = text.replace(f"imports: [{{file: part{n}.yaml}}, {{file: part{n}.yaml}}]\n", "")
        (tmp_path / f"part{i}.yaml").write_text(text)
    (tmp_path / "main.yaml").write_text(MSD.replace(
        "name: msd\n", "name: msd\nimports: [{file: part0.yaml}, {file: part1.yaml}]\n"))
    calls = []
    real = parse_mod.parse_text
    monkeypatch.setattr(parse_mod, "parse_text",
                        lambda text, path="<model>", *a: calls.append(path) or real(text, path, *a))
    m = parse_file(tmp_path / "main.yaml")
    assert sorted(c.name for c in m.components) == sorted(f"C{i}" for i in range(n))
    assert len(calls) == n + 1  # main and every part, once each
    assert len(set(calls)) == n + 1


def test_a_component_defined_in_two_files_is_refused(tmp_path):
    for name in ("p1", "p2"):
        (tmp_path / f"{name}.yaml").write_text(PART.format(i=0, j=9).replace(
            "imports: [{file: part9.yaml}, {file: part9.yaml}]\n", ""))
    (tmp_path / "main.yaml").write_text(MSD.replace(
        "name: msd\n", "name: msd\nimports: [{file: p1.yaml}, {file: p2.yaml}]\n"))
    err = refused(parse_file, tmp_path / "main.yaml")
    assert "component 'C0' is defined twice" in err.message


def test_number_of_imported_files_is_limited(tmp_path, monkeypatch):
    monkeypatch.setattr(parse_mod, "LIMITS", LIMITS.__class__(import_files=5))
    for i in range(8):
        text = PART.format(i=i, j=i + 1).replace(
            f"[{{file: part{i + 1}.yaml}}, {{file: part{i + 1}.yaml}}]",
            f"[{{file: part{i + 1}.yaml}}]")
        if i == 7:
            text = text.replace("imports: [{file: part8.yaml}]\n", "")
        (tmp_path / f"part{i}.yaml").write_text(text)
    err = refused(parse_file, tmp_path / "part0.yaml")
    assert "more than 5 imported files" in err.message


# ---------------------------------------------------------------------------------------------
# Instantiation


def _tree(fanout: int, levels: int) -> str:
    """Components L0..L{levels-1}, each holding ``fanout`` instances of the next."""
    lines = ["bgc: 1", "name: tree", "components:"]
    lines += ["  L0:", "    ports: {a: x}", "    elements: {x: {type: C, stiffness: 1}}",
              "    bonds: []"]
    for lv in range(1, levels):
        inst = ", ".join(f"i{k}: {{type: L{lv - 1}}}" for k in range(fanout))
        lines += [f"  L{lv}:", "    ports: {a: hub}",
                  f"    elements: {{hub: {{type: '0'}}, {inst}}}",
                  "    bonds: [" + ", ".join(f"[hub, i{k}.a]" for k in range(fanout)) + "]"]
    lines += ["elements:", "  F: {type: Sf, flow: '1'}", f"  top: {{type: L{levels - 1}}}",
              "bonds:", "  - [F, top.a]"]
    return "\n".join(lines) + "\n"


def test_instantiated_elements_are_limited():
    from bgc.core.graph import build_graph

    model = parse_text(_tree(16, 7), "tree.yaml")  # 16**6 leaves: refused on the way
    err = refused(build_graph, model)
    assert f"more than {LIMITS.flat_elements}" in err.message
    assert "the limit of instantiated elements" in err.message


def test_instances_per_level_are_limited():
    from bgc.core.graph import build_graph

    n = LIMITS.instances_per_level + 1
    text = ("bgc: 1\nname: wide\ncomponents:\n  L0:\n    ports: {a: x}\n"
            "    elements: {x: {type: C, stiffness: 1}}\n    bonds: []\nelements:\n"
            + "".join(f"  i{k}: {{type: L0}}\n" for k in range(n)) + "bonds: []\n")
    err = refused(build_graph, parse_text(text, "wide.yaml"))
    assert err.coord.line == 9 + LIMITS.instances_per_level
    assert f"more than {LIMITS.instances_per_level} component instances" in err.message


# ---------------------------------------------------------------------------------------------
# Scenes


def _scene(tmp_path, body: str) -> Path:
    (tmp_path / "m.yaml").write_text(MSD)
    p = tmp_path / "s.yaml"
    p.write_text("bgc_scene: 1\nmodel: m.yaml\n" + body)
    return p


@pytest.mark.parametrize("body,line,msg", [
    ("t_span: [0, 1e309]\n", 3, "not finite"),
    ("t_span: [0, .inf]\n", 3, "not a finite number"),
    ("duration: 1e20\n", 3, "beyond the limit of times"),
    ("t_span: [2, 1]\n", 3, "the end time 1 is not after the start 2"),
    ("duration: 7\nsolver: {dt: 1.0e-9}\n", 4, "more than the limit of 1000000"),
    ("duration: 7\nsolver: {max_step: 1.0e-300}\n", 4, "max_step 1e-300 is below the limit"),
    ("duration: 7\nsolver: {rtol: 1.0e-20}\n", 4, "the limit of tolerances"),
    ("duration: 7\nsolver: {rtol: .inf}\n", 4, "not a finite number"),
    ("duration: 7\nsolver: {atol: 0}\n", 4, "solver atol must be positive"),
    ("duration: 7\nsolver: {method: Euler}\n", 4, "unknown solver method 'Euler'"),
    ("duration: 7\nbreakpoints: [1.0e400]\n", 4, "not finite"),
    ("duration: 7\nbreakpoints: [" + ", ".join(["1"] * (LIMITS.breakpoints + 1)) + "]\n", 4,
     f"more than {LIMITS.breakpoints} breakpoints"),
])
def test_scene_limits(tmp_path, body, line, msg):
    p = _scene(tmp_path, body)
    err = refused(parse_scene, p)
    assert err.coord.file == str(p) and err.coord.line == line, err
    assert msg in err.message, err.message


def test_scene_version_true_is_refused(tmp_path):
    p = _scene(tmp_path, "duration: 1\n")
    p.write_text(p.read_text().replace("bgc_scene: 1", "bgc_scene: true"))
    assert "unsupported scene format version" in refused(parse_scene, p).message


def test_scene_within_limits_is_accepted(tmp_path):
    sc = parse_scene(_scene(tmp_path, "duration: 7\nsolver: {dt: 1.0e-5, rtol: 1.0e-12, "
                                      "max_step: 1.0e-9}\nbreakpoints: [1, 2]\n"))
    assert sc.t_span == (0.0, 7.0) and sc.dt == 1e-5 and sc.max_step == 1e-9


# ---------------------------------------------------------------------------------------------
# Names: the generated module's own names are reserved

#: The generated functions in which model names become local variables.
BINDING_FUNCTIONS = ("_unpack", "_inputs", "initial_state", "rhs", "jacobian", "outputs",
                     "input_jacobian", "output_jacobian")


def _model_symbols(eqs) -> set[str]:
    out = {p.code for p in eqs.params}
    for group in (eqs.params, eqs.inputs):
        for v in group:
            out.update(map(str, v.symbols))
    for a in (*eqs.derived, *eqs.assignments, *eqs.jac_assignments):
        out.add(str(a.symbol))
    out.update(str(sv.symbol) for sv in eqs.states)
    return out


@pytest.mark.parametrize("model", ["msd", "dc_motor", "point_mass_3d", "motor_thermal",
                                   "algebraic_loop"])
def test_reserved_covers_the_module(model):
    """Render a module and walk its syntax tree: every name used in a function that binds model
    names, other than the model's own symbols, builtins and _private names, is reserved, so a
    parameter can never shadow what the module itself uses there."""
    c = compile_file(ROOT / "models" / f"{model}.yaml")
    mine = _model_symbols(c.equations)
    tree = ast.parse(c.source)
    funcs = [n for n in tree.body if isinstance(n, ast.FunctionDef) and (
        n.name in BINDING_FUNCTIONS or re.fullmatch(r"_newton_\d+", n.name))]
    assert {f.name for f in funcs} >= {"_unpack", "initial_state", "rhs", "jacobian", "outputs"}
    used = set()  # a function's own name is no local of it: a model name may take it

    def visit(node, hidden):  # hidden: parameters of an enclosing lambda (their own scope)
        if isinstance(node, ast.Lambda):
            hidden = hidden | {a.arg for a in node.args.args}
            visit(node.body, hidden)
            return
        if isinstance(node, ast.Name) and node.id not in hidden:
            used.add(node.id)
        elif isinstance(node, ast.arg):
            used.add(node.arg)
        for child in ast.iter_child_nodes(node):
            visit(child, hidden)

    for f in funcs:
        visit(f, frozenset())
    # the module's imports too (np, scipy...)
    for node in tree.body:
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            used.update((a.asname or a.name).split(".")[0] for a in node.names)
    missing = {n for n in used - mine
               if not n.startswith("_") and n not in dir(builtins) and n not in RESERVED}
    assert not missing, f"names the module uses that a model could shadow: {sorted(missing)}"


@pytest.mark.parametrize("name", ["x", "u", "np", "t", "sin", "q"])
def test_module_arguments_and_language_words_cannot_be_parameters(name):
    err = refused(parse_text, MSD.replace("{m: 2.0, k: 200.0}", f"{{m: 2.0, k: 200.0, {name}: 1}}"),
                  "m.yaml")
    assert f"invalid parameter name {name!r}: reserved" in err.message


ORDINARY_NAMES = ["P", "x0", "dx", "J", "B", "C", "D", "y", "rhs", "jacobian", "outputs",
                  "simulate", "initial_state", "X0", "N_STATES"]


def test_ordinary_names_compile_to_the_same_model():
    """Issue 21: a pressure P, an initial volume x0, a capacitance C... are model names like
    any other: the module's own locals start with "_" (no model name can). Each name in turn
    replaces the stiffness k (read by the rhs, the Jacobians and an output): the functions
    agree with the model that calls it k, value for value."""
    law = MSD.replace("elements:", 'inputs: {F: "1.0"}\nelements:').replace(
        'effort: "1"', 'effort: "F"') + 'outputs: {spring_force: "k*q(spring)", pos: "q(spring)"}\n'
    ref = load_module(compile_model(parse_text(law, "ref.yaml")).source, "ordinary_ref")
    x = np.array([0.3, -0.2])
    for name in ORDINARY_NAMES:
        text = law.replace("k: 200.0", f"{name}: 200.0").replace('"k"', f'"{name}"').replace(
            '"k*q', f'"{name}*q')
        mod = load_module(compile_model(parse_text(text, f"{name}.yaml")).source, f"o_{name}")
        assert np.allclose(mod.rhs(0.0, x), ref.rhs(0.0, x)), name
        assert np.allclose(mod.jacobian(0.0, x), ref.jacobian(0.0, x)), name
        assert np.allclose(mod.input_jacobian(0.0, x), ref.input_jacobian(0.0, x)), name
        for a, b in zip(mod.output_jacobian(0.0, x), ref.output_jacobian(0.0, x)):
            assert np.allclose(a, b), name
        assert np.allclose(mod.outputs(0.0, x)["spring_force"], 200.0 * x[1]), name
        assert np.allclose(mod.initial_state({name: 3.0}), ref.initial_state({"k": 3.0}))
        assert np.allclose(mod.rhs(0.0, x, {name: 3.0}), ref.rhs(0.0, x, {"k": 3.0})), name


@pytest.mark.parametrize("name", ["k\n", "k\r", "k "])
def test_names_match_in_full(name):
    from bgc.format.parse import check_name

    with pytest.raises(ModelError, match="invalid parameter name"):
        check_name(name, Coord("m.yaml", 1, 1), "parameter")


# ---------------------------------------------------------------------------------------------
# Messages


def test_messages_are_capped_and_one_line():
    err = ModelError(Coord("m.yaml", 1, 1), "x" * 10_000 + "\nimport os")
    assert len(err.message) <= LIMITS.message_chars and "\n" not in str(err)
    long_key = "k" * 5000
    err = refused(parse_text, MSD.replace("  mass:   {type: I,", f"  mass:   {{{long_key}: 1, type: I,"),
                  "m.yaml")
    assert len(err.message) <= LIMITS.message_chars


def test_advice_follows_the_message_uncut():
    """A long first line is cut at the cap; bgc's advice follows on its own lines, whole."""
    advice = "Do this first: " + "a" * 700 + "\nthen\x1b that."
    err = ModelError(Coord("m.yaml", 3, 4), "y" * 10_000, advice)
    lines = str(err).splitlines()
    assert lines[0].startswith("m.yaml:3:4: ") and len(err.message) <= LIMITS.message_chars
    assert lines[1] == "  Do this first: " + "a" * 700
    assert lines[2] == "  then\\x1b that."  # made printable, not cut
    assert len(lines) == 3


# ---------------------------------------------------------------------------------------------
# The bugs list


MTF = """bgc: 1
name: slider
parameters: {a: 0.6, b: 0.8, m: 2.0, k: 3.0}
elements:
  F:      {type: Se, effort: "5"}
  j:      {type: "1"}
  mass:   {type: I, inertia: m}
  lever:  {type: MTF, modulus: "[[a], [b]]"}
  spring: {type: C, stiffness: k}
bonds:
  - [F, j]
  - [j, mass]
  - [j, lever]
  - {from: lever, to: spring, n: 2}
"""


def _module(text: str, name: str = "m.yaml"):
    from bgc.backends.load import load_module

    c = compile_model(parse_text(text, name))
    return load_module(c.source, c.model.name)


def test_mtf_from_a_scalar_to_a_two_vector():
    """A slider (scalar momentum p) driving a planar spring (2-vector q) through a 2x1 modulus:
    by hand, f2 = M f1 = [a, b] p/m, e1 = M^T e2 = k (a q0 + b q1), dp/dt = F - e1."""
    mod = _module(MTF)
    assert mod.STATE_NAMES == ("mass.p", "spring.q[0]", "spring.q[1]")
    a, b, m, k = 0.6, 0.8, 2.0, 3.0
    x = np.array([1.5, 0.2, -0.7])
    want = [5 - k * (a * x[1] + b * x[2]), a * x[0] / m, b * x[0] / m]
    np.testing.assert_allclose(mod.rhs(0.0, x), want, rtol=1e-14)
    # the Jacobian of that linear system, by hand
    jac = np.array([[0, -k * a, -k * b], [a / m, 0, 0], [b / m, 0, 0]])
    np.testing.assert_allclose(mod.jacobian(0.0, x), jac, rtol=1e-14)


def test_tf_from_a_two_vector_to_a_scalar():
    """The other way round, with a TF: a 1x2 ratio from a 2-vector to a scalar (f2 = M f1 is
    1x1)."""
    text = """bgc: 1
name: gather
parameters: {a: 0.6, b: 0.8, m: 2.0, k: 3.0}
elements:
  F:      {type: Se, effort: "[1, 2]"}
  j:      {type: "1"}
  mass:   {type: I, inertia: m}
  lever:  {type: TF, ratio: "[[a, b]]"}
  spring: {type: C, stiffness: k}
bonds:
  - {from: F, to: j, n: 2}
  - {from: j, to: mass, n: 2}
  - {from: j, to: lever, n: 2}
  - [lever, spring]
"""
    mod = _module(text)
    a, b, m, k = 0.6, 0.8, 2.0, 3.0
    x = np.array([1.5, -0.5, 0.3])  # p0, p1, q
    e1 = k * x[2] * np.array([a, b])  # M^T e2
    want = [1 - e1[0], 2 - e1[1], (a * x[0] + b * x[1]) / m]
    np.testing.assert_allclose(mod.rhs(0.0, x), want, rtol=1e-14)


def test_automatic_bond_names_give_way_to_parameters():
    """Parameters named b2 and b3 beside unnamed bonds 2 and 3: the parameters keep their
    meaning (an inertia of 4, a stiffness of 50)."""
    text = MSD.replace("{m: 2.0, k: 200.0}", "{b2: 4.0, b3: 50.0}").replace(
        'inertia: "m"', 'inertia: "b2"').replace('stiffness: "k"', 'stiffness: "b3"')
    mod = _module(text)
    x = np.array([2.0, 0.1])  # p, q
    np.testing.assert_allclose(mod.rhs(0.0, x), [1 - 50.0 * 0.1, 2.0 / 4.0], rtol=1e-14)


def test_a_user_bond_name_equal_to_an_automatic_one_is_located():
    text = MSD.replace("  - [v, spring]", "  - {from: v, to: spring, name: b2}")
    err = refused(parse_text, text, "m.yaml")
    assert err.coord.line == 12 and "automatic name of the bond at line 11" in err.message


def test_check_does_not_warn_of_a_loop_it_solved():
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    res = subprocess.run([sys.executable, "-m", "bgc.cli.commands", "check", "models/algebraic_loop.yaml"],
                         cwd=ROOT, env=env, text=True, capture_output=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert "linear algebraic loop solved through" in res.stdout
    assert "possible algebraic loop" not in res.stdout


@pytest.mark.parametrize("law,msg", [
    ('effort: "e(u_in)"', "e() takes a bond, element or junction; 'u_in' is an input"),
    ('effort: "k.x"', "'k' is a parameter: it has no 'x'"),
])
def test_articles(law, msg):
    text = MSD.replace("name: msd\n", "name: msd\ninputs: {u_in: 1}\n").replace(
        'effort: "1"', law)
    err = refused(compile_model, parse_text(text, "m.yaml"))
    assert msg in err.message, err.message


@pytest.mark.parametrize("value", ["inf", "nan", "1e-20"])
def test_cli_rtol_is_checked(value, tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    res = subprocess.run([sys.executable, "-m", "bgc.cli.commands", "simulate",
                          str(ROOT / "models" / "scenes" / "msd_step.yaml"), "--rtol", value],
                         cwd=tmp_path, env=env, text=True, capture_output=True, timeout=300)
    assert res.returncode == 2, res.stderr
    assert res.stderr.strip() == (f"error: --rtol {float(value):g} is outside [1e-14, 1] (the "
                                  "limit of tolerances: doubles carry about 16 digits)")
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------------------------
# libyaml's events and PyYAML's own give the same nodes


def _nodes(node, out):
    m = node.start_mark
    out.append((type(node).__name__, node.tag, getattr(node, "style", None), m.line, m.column,
                node.value if isinstance(node.value, str) else len(node.value)))
    if not isinstance(node.value, str):
        for item in node.value:
            for sub in (item if isinstance(item, tuple) else (item,)):
                _nodes(sub, out)
    return out


@pytest.mark.skipif(reader_mod._FastLoader is None, reason="PyYAML without libyaml")
def test_fast_and_pure_python_composers_agree():
    import yaml

    files = sorted((ROOT / "models").rglob("*.yaml")) + sorted((ROOT / "tests").rglob("*.yaml"))
    compared = 0
    for f in files:
        try:
            text = f.read_text(encoding="utf-8")
            slow = yaml.compose(text, Loader=reader_mod._Loader)
        except Exception:  # noqa: BLE001 - bad files: test_bad_input checks their messages
            continue
        loader = reader_mod._FastLoader(text)
        try:
            fast = loader.get_single_node()
        except yaml.YAMLError:  # libyaml refuses what PyYAML reads (hostile text in the fuzz
            continue  # corpus): bgc's reader then falls back to PyYAML's nodes themselves
        finally:
            loader.dispose()
        if slow is None:
            assert fast is None, f
            continue
        assert _nodes(fast, []) == _nodes(slow, []), f
        compared += 1
    assert compared >= 40


@pytest.mark.parametrize("value,msg", [
    ("[" + ", ".join(["1"] * 65) + "]", "a 65x1 matrix is larger than the limit of matrix size"),
    ("[[" + ", ".join(["1"] * 65) + "]]", "a 1x65 matrix is larger than the limit"),
    ("[[]]", "an empty matrix or row"),
    ("[]", "an empty matrix or row"),
])
def test_matrix_parameters_are_bounded(value, msg):
    err = refused(parse_text, MSD.replace("{m: 2.0, k: 200.0}", f"{{m: 2.0, k: 200.0, K: {value}}}"),
                  "m.yaml")
    assert err.coord.line == 3 and msg in err.message, err
