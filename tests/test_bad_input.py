"""Malformed models: every mistake is one located line, exit status 2, and nothing written.

Each file in tests/bad/ holds one mistake (its first line, a YAML comment, says which). The
table pairs it with the place the error must point at and a piece of the message. Every case
runs through the whole pipeline in-process (parse, graph, causality, equations, rendering);
a representative handful also runs through the command line (``bgc check`` and
``bgc compile -o``), checking the exit status, the single ``file:line:col:`` line on stderr,
the absence of a traceback, and that no file was written: in-process under click's runner,
and a few of them in real processes too (in parallel).
"""
from __future__ import annotations

import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import pytest

from bgc.base.errors import ModelError
from bgc.run.driver import compile_file

ROOT = Path(__file__).resolve().parents[1]
BAD = ROOT / "tests" / "bad"


@dataclass(frozen=True)
class Case:
    file: str
    line: int
    col: int | None  # None where the column is not meaningful
    substr: str
    where: str | None = None  # the file the error is located in, when not ``file``


CASES = [
    # YAML and the top level
    Case("yaml_syntax", 7, 3, "YAML syntax error"),
    Case("yaml_alias", 7, 7, "YAML alias *stiff is not allowed"),
    Case("control_char", 3, 9, "character U+0007 is not allowed"),
    Case("empty", 1, 1, "the model file is empty"),
    Case("missing_bgc", 2, 1, "missing key 'bgc'"),
    Case("missing_name", 2, 1, "missing key 'name'"),
    Case("missing_elements", 2, 1, "missing key 'elements'"),
    Case("missing_bonds", 2, 1, "missing key 'bonds'"),
    Case("wrong_version", 2, 6, "unsupported format version 2"),
    Case("version_bool", 2, 6, "unsupported format version True"),
    # elements
    Case("unknown_type", 11, 3, "element 'spring': unknown element type 'Spring'"),
    Case("unknown_type_symbol", 12, 18, "element 'v': unknown element type '1-junction'"),
    Case("unknown_key", 10, 35, "element 'mass': unknown key 'mass'"),
    Case("two_laws", 11, 3, "element 'spring' (C) needs exactly one of"),
    Case("no_law", 10, 3, "element 'mass' (I) needs exactly one of: inertia, flow"),
    Case("element_not_mapping", 13, 11, "element 'damper' must be a mapping"),
    # graph structure
    Case("tf_three_bonds", 6, 3, "TF 'lever' needs exactly one incoming and one outgoing bond"),
    Case("tf_two_incoming", 6, 3, "it has 2 in and 0 out"),
    Case("oneport_two_bonds", 11, 3, "C 'spring' is a one-port element"),
    Case("unconnected", 13, 3, "R 'damper' is a one-port element: it needs exactly one bond, "
                               "it has 0"),
    Case("cardinality_mismatch", 7, 3, "junction 'v': cardinality mismatch"),
    Case("cardinality_limit", 15, 28, "cardinality must be 1..64, got 65"),
    Case("dangling_junction", 13, 3, "junction 'node' has 1 bond(s)"),
    Case("bond_unknown_element", 15, 5, "bond 'b2': no element 'masss'"),
    Case("bond_to_parameter", 17, 5, "bond 'b4': 'k' is a parameter, not an element"),
    Case("bond_instance_no_port", 21, 5, "'sd' is a component instance: name one of its ports"),
    Case("unknown_port", 21, 5, "instance 'sd' has no port 'b' (ports: a)"),
    Case("self_loop", 17, 5, "bond 'b4' joins 'v' to itself"),
    Case("component_unknown_param", 17, 35, "component 'spring_damper' has no parameter 'k'"),
    Case("import_cycle_a", 4, 18, "import cycle through 'import_cycle_a.yaml'",
         where="import_cycle_b"),
    Case("import_cycle_b", 4, 18, "import cycle through 'import_cycle_b.yaml'",
         where="import_cycle_a"),
    # a library part's error at the user's instance, naming the element's full path and the
    # part (the library's own line is not the user's to fix); the residual is the body's
    # spin about x, w0 = 2 rad/s, with the lock's frame Rd = I
    Case("library_lock_inconsistent", 13, 3,
         "element 'hinge.lock' (from bgc:mechanics.spatial revolute_lock): constraint "
         "'hinge.lock' closing the kinematic loop through hinge.lock, hinge.J, hinge.M: the "
         "initial velocities violate it: the flow of bond 'hinge.b2' differs from the "
         "source's by [2, 0]"),
    # names
    Case("duplicate_element", 13, 3, "elements: duplicate key 'mass'"),
    Case("duplicate_param_element", 13, 3, "duplicate name 'm': already a parameter"),
    Case("name_dunder_import", 13, 3, "invalid element name '__import__'"),
    Case("name_dotted", 13, 3, "invalid element name 'os.system'"),
    Case("name_semicolon", 13, 3, "invalid element name 'a;b'"),
    Case("name_newline", 8, 3, "invalid parameter name 'x1\\nimport os'"),
    Case("name_model_injection", 3, 7, "invalid model name 'bad; import os'"),
    Case("reserved_param_t", 8, 3, "invalid parameter name 't': reserved"),
    Case("reserved_param_sin", 8, 3, "invalid parameter name 'sin': reserved"),
    # parameters
    Case("param_out_of_range", 5, 14, "parameter 'm': value -2 is below its min 0"),
    Case("derived_self", 6, 3, "parameter 'k' is defined in terms of itself"),
    # expressions: the whitelist (column = the offending character)
    Case("expr_import", 11, 33, "element 'spring' (stiffness): only the built-in functions"),
    Case("expr_class", 11, 33, "element 'spring' (stiffness): attribute access"),
    Case("expr_lambda", 11, 33, "element 'spring' (stiffness): only the built-in functions"),
    Case("expr_string", 11, 37, "only numbers are allowed as constants, not 'abc'"),
    Case("expr_dunder_attr", 11, 37, "name '__dict__' is not allowed"),
    Case("expr_eval", 11, 33, "unknown function 'eval'"),
    Case("expr_keyword", 11, 33, "max(): keyword and starred arguments are not allowed"),
    Case("expr_comprehension", 11, 33, "ListComp is not allowed in an expression"),
    Case("expr_invalid_char", 11, 35, "invalid expression 'k $ 2'"),
    # expressions: meaning
    Case("undefined_symbol", 11, 37, "C 'spring': undefined name 'kk'"),
    Case("index_out_of_range", 12, 37, "C 'spring': index 3 is out of range for size 3"),
    Case("expr_division_by_zero", 11, 33, "C 'spring': the expression is infinite"),
    Case("expr_huge_power", 11, 36, "C 'spring': a number larger than 10**300"),
    Case("p_of_c", 18, 9, "output 'x': p() takes an I element, 'spring' is a C"),
    Case("se_vector_on_scalar", 9, 3, "Se 'force': cardinality mismatch: effort is 3x1"),
    Case("matrix_on_n3", 6, 3, "I 'mass': cardinality mismatch: inertia is 2x2"),
    # causality and algebraic loops
    Case("derivative_causality", 8, 3, "I 'flywheel_b' is forced into derivative causality by "
                                       "I 'flywheel_a'"),
    Case("causal_conflict", 6, 3, "Se 's2' and Se 's1' (through 0-junction 'node') both impose"),
    Case("nonlinear_loop", 7, 3, "is nonlinear"),
    # issue 10: numbers, bounds, names and the bugs list
    Case("number_inf", 6, 6, "parameter 'k': '.inf' is not a finite number"),
    Case("number_nan", 6, 6, "parameter 'k': '.NaN' is not a finite number"),
    Case("number_sexagesimal", 6, 6, "'1:30' is a sexagesimal (base 60) number"),
    Case("number_huge_int", 6, 6, "is out of range (larger than 10**300)"),
    Case("number_overflow_text", 6, 6, "number '1e999' is not finite"),
    Case("expr_sqrt_negative", 10, 37, "C 'spring': the constant is complex, not real"),
    Case("expr_exp_tower", 10, 43, "C 'spring': the constant is not a finite number"),
    Case("expr_matrix_huge", 10, 41, "eye() size must be 1..64 (the limit of matrix size)"),
    Case("expr_caret", 10, 33, "operator ^ is not allowed: write ** for a power"),
    Case("expr_signum", 10, 37, "unknown function 'signum' (did you mean sign?)"),
    Case("zero_inertia", 6, 3, "I 'mass': its inertia is zero"),
    Case("c_reads_own_effort", 6, 3, "C 'spring': its law reads its own effort"),
    Case("matrix_1x1_on_n3", 8, 3, "I 'mass': cardinality mismatch: inertia is 1x1, the bond "
                                   "(n=3) needs a scalar or a 3x3 matrix"),
    Case("r_fixed_form", 7, 3, "R 'leak': its law (effort: ...) is in resistance form, but its "
                               "causality must be conductance"),
    Case("import_nul", 4, 18, "import path 'parts\\x00.yaml' contains a NUL byte"),
    Case("import_missing", 4, 18, "cannot read imported file"),
]

BY_NAME = {c.file: c for c in CASES}


def path_of(name: str) -> Path:
    return BAD / f"{name}.yaml"


def test_every_bad_file_is_in_the_table():
    files = {p.stem for p in BAD.glob("*.yaml")}
    assert files == set(BY_NAME), (files ^ set(BY_NAME))
    assert len(files) >= 35


@pytest.mark.parametrize("name", sorted(BY_NAME))
def test_bad_file_starts_with_a_comment(name):
    first = path_of(name).read_text(encoding="utf-8").splitlines()[0]
    assert first.startswith("# ") and len(first) > 10


def _prefix(case: Case, path: str) -> str:
    where = str(Path(path).with_name(f"{case.where}.yaml")) if case.where else path
    col = f"{case.col}:" if case.col is not None else ""
    return f"{where}:{case.line}:{col}"


@pytest.mark.parametrize("name", sorted(BY_NAME))
def test_in_process(name):
    case = BY_NAME[name]
    path = str(path_of(name))
    with pytest.raises(ModelError) as info:
        compile_file(path)
    err = info.value
    assert err.coord is not None, err
    text = str(err)
    assert text.startswith(_prefix(case, path)), text
    assert case.substr in err.message, text
    assert "\n" not in text, text
    assert len(text) < 600, text


if sys.platform == "win32":  # pragma: no cover
    pytest.skip("POSIX paths in messages", allow_module_level=True)

#: The cases that also go through the command line: a sample from every stage. Each runs
#: both commands in-process (click's runner: exit status, the one located line on stderr, no
#: traceback, nothing written); a few of them also in a real process (:data:`PROCESS_RUNS`).
CLI_CASES = ["yaml_syntax", "unknown_key", "self_loop", "expr_import", "import_cycle_a",
             "causal_conflict", "undefined_symbol", "nonlinear_loop", "expr_exp_tower",
             "zero_inertia", "library_lock_inconsistent"]
#: The runs that also go through a real `python -m bgc.cli.commands` process (its exit status
#: and stderr as a shell sees them): one per command and stage group (YAML, graph/causality,
#: expressions, the library lock).
PROCESS_RUNS = [("yaml_syntax", "check"), ("causal_conflict", "compile"),
                ("expr_exp_tower", "check"), ("library_lock_inconsistent", "compile")]


def _args(name: str, command: str, out: Path) -> list[str]:
    rel = str(path_of(name).relative_to(ROOT))
    if command == "check":
        return ["check", rel]
    return ["compile", "-q", rel, "-o", str(out / "out.py")]


def _run(args: list[str]) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    src = str(ROOT / "src")
    env["PYTHONPATH"] = src + os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else src
    return subprocess.run([sys.executable, "-m", "bgc.cli.commands", *args], cwd=ROOT, env=env,
                          text=True, capture_output=True, timeout=300, stdin=subprocess.DEVNULL)


@pytest.fixture(scope="module")
def cli_runs(tmp_path_factory):
    """Run the real-process cases at once; {(name, command): (result, outdir)}."""
    jobs = {}
    for name, command in PROCESS_RUNS:
        out = tmp_path_factory.mktemp(f"out_{name}")
        jobs[(name, command)] = (_args(name, command, out), out)
    with ThreadPoolExecutor(max_workers=max(2, os.cpu_count() or 2)) as pool:
        futures = {k: pool.submit(_run, args) for k, (args, _) in jobs.items()}
        return {k: (f.result(), jobs[k][1]) for k, f in futures.items()}


def _check_one_located_line(case: Case, name: str, status: int, stderr: str, out: Path):
    rel = str(path_of(name).relative_to(ROOT))
    assert status == 2, (status, stderr)
    assert "Traceback" not in stderr, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    assert lines[0].startswith(_prefix(case, rel)), stderr
    assert case.substr in lines[0], stderr
    assert list(out.iterdir()) == [], "something was written"


CLI_PARAMS = [pytest.param(name, command, id=f"{name}-{command}")
              for name in CLI_CASES for command in ("check", "compile")]


@pytest.mark.parametrize("name,command", CLI_PARAMS)
def test_cli(name, command, tmp_path, monkeypatch):
    """The command line in-process (bgc.cli.commands.main under click's runner, from the
    repository root as the real runs): the same one line, exit 2, nothing written."""
    from click.testing import CliRunner

    from bgc.cli.commands import main

    monkeypatch.chdir(ROOT)
    out = tmp_path / "out"
    out.mkdir()
    r = CliRunner().invoke(main, _args(name, command, out), prog_name="bgc")
    assert r.exception is None or isinstance(r.exception, SystemExit), \
        (r.exception, r.stderr)
    _check_one_located_line(BY_NAME[name], name, r.exit_code, r.stderr, out)


@pytest.mark.parametrize("name,command", [pytest.param(n, c, id=f"{n}-{c}")
                                          for n, c in PROCESS_RUNS])
def test_cli_process(cli_runs, name, command):
    """A real process: exit status 2, one located line on stderr, no traceback."""
    res, out = cli_runs[(name, command)]
    _check_one_located_line(BY_NAME[name], name, res.returncode, res.stderr, out)
