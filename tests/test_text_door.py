"""Issue 10, the one door for text: a model's free text reaches generated code only as an
escaped literal or a one-line comment, and a rendered module whose top level is not the
template's is never written nor executed.

The payloads are the attacker's: each tries to end the docstring (or a comment, or a string)
and run ``import os`` at import time, touching a canary file. The check is the canary itself,
after importing the generated module in a separate, isolated Python process.
"""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from bgc.backends.load import load_module
from bgc.base.errors import ModelError
from bgc.backends.numpy.printer import (
    SkeletonError,
    check_skeleton,
    docstring,
    lit,
    oneline,
)
from bgc.run.driver import compile_file

ROOT = Path(__file__).resolve().parent.parent


def _payloads(canary: Path) -> list[str]:
    cmd = f"import os; os.system('touch {canary}')"
    return [
        f'x"""\n{cmd}\n"""',
        f"x'''\n{cmd}\n'''",
        f'end\\\n"""\n{cmd}\n#',
        f'"\n{cmd}',
        f'\\"""\n{cmd}\n"""',
        f'a\r{cmd}',
        f'a\u2028{cmd}\u2029"""',
        f'a\x00b"""\n{cmd}\n"""',
        f'\\N{{LATIN SMALL LETTER A}}"""\n{cmd}\n"""',
        '"' * 7 + f"\n{cmd}\n" + '"' * 7,
    ]


def _hostile_model(tmp_path: Path, field: str, text: str) -> Path:
    d = yaml.safe_load((ROOT / "models" / "msd.yaml").read_text())
    if field == "description":
        d["description"] = text
    elif field == "unit":
        d["parameters"]["m"] = {"value": 2.0, "unit": text}
    elif field == "param_description":
        d["parameters"]["k"] = {"value": 200.0, "unit": "N/m", "description": text}
    out = tmp_path / "m.yaml"
    out.write_text(yaml.safe_dump(d, allow_unicode=False), encoding="utf-8")
    return out


def _import_isolated(canary: Path, module_files: list) -> subprocess.CompletedProcess:
    """Each module imported, one after another, in one separate isolated Python process:
    after each, a line with its number of states and whether the canary exists."""
    code = ("import importlib.util as u, os, sys\n"
            "for k, f in enumerate(sys.argv[2:]):\n"
            "    s = u.spec_from_file_location(f'm{k}', f); m = u.module_from_spec(s)\n"
            "    s.loader.exec_module(m); print(len(m.STATE_NAMES), os.path.exists(sys.argv[1]))\n")
    argv = [sys.executable, "-I", "-c", code, str(canary), *map(str, module_files)]
    return subprocess.run(argv, capture_output=True, text=True, timeout=60)


@pytest.mark.parametrize("field", ["description", "unit", "param_description"])
def test_free_text_never_runs(tmp_path, field):
    canary = tmp_path / "CANARY"
    written = []
    for k, text in enumerate(_payloads(canary)):
        model = _hostile_model(tmp_path, field, text)
        if field == "unit":  # a unit is parsed (bgc.format.units): hostile text is refused
            with pytest.raises(ModelError) as exc:
                compile_file(model)
            assert exc.value.message.startswith("parameter 'm': unit ")
            assert "\n" not in str(exc.value) and not canary.exists()
            continue
        c = compile_file(model)
        check_skeleton(c.source)
        out = tmp_path / f"m{k}.py"
        out.write_text(c.source, encoding="utf-8")
        written.append(out)
        assert not canary.exists(), f"payload {k} in {field} ran"
        # and the text survives, exactly, inside the docstring when it is the description
        if field == "description":
            doc = ast.get_docstring(ast.parse(c.source), clean=False)
            assert text in doc
    if written:  # every module imported in the isolated process, the canary seen after each
        r = _import_isolated(canary, written)
        assert r.returncode == 0, r.stderr
        assert r.stdout.splitlines() == ["2 False"] * len(written), (field, r.stdout)
        assert not canary.exists(), f"a payload in {field} ran"


def test_load_module_from_memory_leaves_nothing(tmp_path, monkeypatch):
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    c = compile_file(ROOT / "models" / "msd.yaml")
    mod = load_module(c.source, "msd_memory")
    assert list(tmp_path.iterdir()) == []
    assert mod.rhs(0.0, mod.X0).shape == (2,)
    import inspect

    assert "def rhs(" in inspect.getsource(mod.rhs)  # tracebacks and inspect see the code


@pytest.mark.parametrize("stmt", [
    "import os",
    "os.system('x')",
    "rhs = None",
    "def simulate():\n    pass",
    "from os import system",
    "if True:\n    pass",
    "class SimulationError:\n    pass",
])
def test_skeleton_refuses_foreign_statements(stmt):
    src = compile_file(ROOT / "models" / "msd.yaml").source
    check_skeleton(src)
    cut = src.index("\ndef rhs(")
    bad = src[:cut] + "\n" + stmt + "\n" + src[cut:]
    with pytest.raises(SkeletonError):
        check_skeleton(bad)
    with pytest.raises(SkeletonError):
        load_module(bad, "refused")


def test_skeleton_refuses_changed_runtime():
    src = compile_file(ROOT / "models" / "msd.yaml").source
    bad = src.replace("def _rms(x):", "def _rms(x):\n    __import__('os')", 1)
    assert bad != src
    with pytest.raises(SkeletonError):
        check_skeleton(bad)


@settings(max_examples=300, deadline=None)
@given(st.text(alphabet=st.characters(exclude_categories=()), max_size=60))
def test_docstring_literal_means_the_text(text):
    s = docstring(text)
    tree = ast.parse(s)
    assert len(tree.body) == 1 and isinstance(tree.body[0], ast.Expr)
    assert ast.literal_eval(s) == text


@settings(max_examples=300, deadline=None)
@given(st.text(max_size=60))
def test_lit_and_oneline(text):
    assert ast.literal_eval(lit(text)) == text
    one = oneline(text)
    assert "\n" not in one and "\r" not in one and one.isprintable()
    assert len(one) <= 200


def test_lit_refuses_non_finite_and_objects():
    with pytest.raises(ValueError):
        lit(float("inf"))
    with pytest.raises(TypeError):
        lit(object())


def test_start_check_code_leaves_out_only_the_functions_named():
    """The start check's code (skeleton.checked_code(..., without=)): the module less exactly
    the functions named, every other line where it was, and the same rhs at X0 as the whole
    module (msd's: an independent closed form, p' = F0 - k q - c p/m, q' = p/m)."""
    import numpy as np

    from bgc.backends.skeleton import checked_code
    from bgc.run.runner import START_UNUSED

    src = compile_file(ROOT / "models" / "msd.yaml").source
    whole, part = {}, {}
    exec(checked_code(src, "<bgc msd_whole>"), whole)  # noqa: S102 - the checked module
    exec(checked_code(src, "<bgc msd_part>", without=START_UNUSED), part)  # noqa: S102
    assert set(START_UNUSED) <= set(whole) and not set(START_UNUSED) & set(part)
    assert set(whole) - set(part) == set(START_UNUSED)
    for name in ("rhs", "initial_state", "_params", "simulate"):
        assert part[name].__code__.co_firstlineno == whole[name].__code__.co_firstlineno
    x = np.array([0.3, -0.02])  # p, q
    m, k, c, f0 = 2.0, 200.0, 4.0, 10.0
    want = [f0 - k * x[1] - c * x[0] / m, x[0] / m]
    assert np.allclose(part["rhs"](0.0, x), want, rtol=1e-14, atol=0)
    assert np.array_equal(part["rhs"](0.0, x), whole["rhs"](0.0, x))
    cut = src.index("\ndef rhs(")
    bad = src[:cut] + "\nimport os\n" + src[cut:]
    with pytest.raises(SkeletonError):
        checked_code(bad, "<bgc bad>", without=START_UNUSED)


def test_compile_start_check_names_the_law_that_is_not_finite(tmp_path):
    """A module whose rhs is not finite at X0 with its defaults (a zero mass: v = p/m) is one
    located ModelError from the start check, with the module loaded less its unused parts."""
    from bgc.run.runner import check_module_start

    text = (ROOT / "models" / "msd.yaml").read_text(encoding="utf-8")
    text = text.replace("m:  {value: 2.0,", "m:  {value: 0.0,", 1)
    (tmp_path / "zero.yaml").write_text(text, encoding="utf-8")
    c = compile_file(tmp_path / "zero.yaml")
    with pytest.raises(ModelError) as exc:
        check_module_start(c)
    assert "not finite with the default parameters" in str(exc.value)
    assert "zero.yaml:28:3:" in str(exc.value) and "divides by m, which is 0" in str(exc.value)


# The plain runs (bgc.backends.skeleton): a long run of plain lines is parsed as one `pass`.
# The reference verdict is the whole model part's syntax tree, checked the same way.

def _whole_verdict(text: str):
    """What the check says when the model part is parsed whole: (top-level statements, the
    functions' spans), or the refusal."""
    from bgc.backends import skeleton

    rt = _runtime_of(text)
    body = text.rstrip("\n")
    if not body.endswith("\n\n\n" + rt):
        return "refused"
    try:
        tree = ast.parse(body[:-len(rt)])
        spans = skeleton._check_head(tree.body)
    except (SyntaxError, SkeletonError):
        return "refused"
    return [(type(n).__name__, n.lineno) for n in tree.body], spans


def _runtime_of(text: str) -> str:
    from bgc.backends import skeleton

    rt = skeleton.runtime_source()
    if "\nEVENT_NAMES = (" in text:  # a hybrid model's: the events' runtime follows
        rt += "\n\n\n" + skeleton.events_runtime_source()
    return rt


def _plain_verdict(text: str):
    from bgc.backends import skeleton

    rt = _runtime_of(text)
    try:
        spans = skeleton._check_skeleton(text, "numpy")
    except SkeletonError:
        return "refused"
    whole = text.rstrip("\n")[:-len(rt)]
    head, _ = skeleton._plain_runs_passed(whole)
    try:
        tree = ast.parse(head)
    except SyntaxError:  # (runs inside brackets: the whole tree decided)
        tree = ast.parse(whole)
    return [(type(n).__name__, n.lineno) for n in tree.body], spans


def test_plain_runs_give_every_golden_the_whole_tree_s_verdict():
    """Every golden module: the same top-level statements and the same function spans as
    its whole syntax tree; the large ones' equations really are left to the scan."""
    from bgc.backends import skeleton

    reduced = 0
    for path in sorted((ROOT / "generated").glob("*.py")):
        text = path.read_text(encoding="utf-8")
        assert _plain_verdict(text) == _whole_verdict(text) != "refused", path.name
        rt = _runtime_of(text)
        reduced += bool(skeleton._plain_runs_passed(text.rstrip("\n")[:-len(rt)])[1])
    assert reduced >= 5


def _in_jacobian(text: str, line: str, after: int = 200) -> str:
    """``line`` put ``after`` lines into the Jacobian's body (inside its plain run)."""
    at = text.index("\ndef jacobian(")
    for _ in range(after):
        at = text.index("\n", at + 1)
    return text[:at] + "\n" + line + text[at:]


@pytest.mark.parametrize("line, refused", [
    ("import os", True),  # a top-level statement in the middle of the equations
    ("X0 = 1", True),
    ("rhs = None", True),
    ("    # a note\rimport os", True),  # a line break only Python sees
    ("    _z = (1 +\nimport os\n    )", True),  # a bracket left open over a top-level line
    ("\t_z = 1", True),  # a tab in the indentation
    ("    _z = 1)", True),  # a bracket closed that was never opened
    ("def rhs(t, x):\n    pass", True),
    ("    import os", False),  # inside the function: a body is not looked into, as before
    ("    _z = 1  # \"quoted\" 'text'", False),
])
def test_plain_runs_refuse_what_the_whole_tree_refuses(line, refused):
    text = (ROOT / "generated" / "mech3r2s.py").read_text(encoding="utf-8")
    bad = _in_jacobian(text, line)
    whole = _whole_verdict(bad)
    assert (whole == "refused") is refused
    assert _plain_verdict(bad) == whole


def test_plain_runs_in_a_string_stay_string():
    """Plain lines inside the module's docstring (a model's description may hold anything)
    are string content: the same verdict as the whole tree, and the description unchanged."""
    text = (ROOT / "generated" / "mech3r2s.py").read_text(encoding="utf-8")
    block = "\n".join(["    x = 1"] * 60 + ["import os"] + ["    y = 2"] * 60)
    at = text.index("\n", text.index('"""') + 3)
    doc = text[:at] + "\n" + block + text[at:]
    assert _plain_verdict(doc) == _whole_verdict(doc) != "refused"


def test_plain_runs_inside_brackets_are_no_refusal():
    """Plain lines inside a top-level bracket (a long table of index arrays) do not parse as
    pass: the whole tree decides, and accepts the module as before."""
    text = (ROOT / "generated" / "mech3r2s.py").read_text(encoding="utf-8")
    rows = "".join("    np.array([%d, %d], dtype=np.intp),\n" % (k, k + 1) for k in range(80))
    at = text.index("\ndef _unpack(") + 1
    tables = text[:at] + "_IX = (\n" + rows + ")\n\n\n" + text[at:]
    assert _plain_verdict(tables) == _whole_verdict(tables) != "refused"


def _parses(monkeypatch, text: str) -> list:
    """The texts the check parses for ``text`` (each a syntax tree built)."""
    from bgc.backends import skeleton

    parsed = []
    real = skeleton._parse
    monkeypatch.setattr(skeleton, "_parse", lambda t, w: (parsed.append(t), real(t, w))[1])
    skeleton._check_skeleton(text, "numpy")
    return parsed


def test_index_tables_and_a_block_after_a_run_are_parsed_once(monkeypatch):
    """A long table of index arrays (a literal's items, given as one ``0,``) and a run that
    ends on a block's header whose body is not plain (the run then stops before it): one
    tree, much smaller than the text, and the whole tree's verdict."""
    text = (ROOT / "generated" / "mech3r2s.py").read_text(encoding="utf-8")
    rows = "".join("    np.array([%s], dtype=np.intp),\n" % ", ".join(map(str, range(k, k + 40)))
                   for k in range(300))
    at = text.index("\ndef _unpack(") + 1
    tables = text[:at] + "_IX = (\n" + rows + ")\n\n\n" + text[at:]
    block = "    if x.shape[1:] != _bs:\n        x = xp.reshape(x, (\n            3,))"
    both = _in_jacobian(tables, block)
    for t in (tables, both):
        assert _plain_verdict(t) == _whole_verdict(t) != "refused"
        parsed = _parses(monkeypatch, t)
        assert len(parsed) == 1 and len(parsed[0]) < len(t) / 3


@pytest.mark.parametrize("item", [
    "    __import__('os').system('true'),",  # not a literal line: parsed as it is
    ")\nimport os\n_IY = (",  # a top-level statement between two tables
    ")\nrhs = None\n_IX = (",  # a name the model part defines, twice
    "    np.array([1, 2], dtype=np.intp)),",  # a bracket closed that was never opened
    "    np.array([1, 2], dtype=np.intp),\rimport os",  # a line break only Python sees
    "    [1, 2],  # a comment ends no literal line",
    "    [ - ],",  # integer-like lines that are no list of integers
    "    [, ],",
    "    [01, 2],",
    "    [1 2],",
    "    [1, 2]\n    np.array([3], dtype=np.intp),",  # an item without its comma
    "    [1, 2]\n)\n_IY = (",  # the last item of a table without its comma
    "    [1, 2]\n    )",  # the same, its bracket closed on an indented line
])
def test_index_tables_give_the_whole_tree_s_verdict(item):
    text = (ROOT / "generated" / "mech3r2s.py").read_text(encoding="utf-8")
    rows = ["    np.array([%d, %d], dtype=np.intp)," % (k, k + 1) for k in range(80)]
    rows.insert(40, item)
    at = text.index("\ndef _unpack(") + 1
    tables = text[:at] + "_IX = (\n" + "\n".join(rows) + "\n)\n\n\n" + text[at:]
    assert _plain_verdict(tables) == _whole_verdict(tables)
