"""A red-team pass (branch harden): each defect a hostile or careless user found, paired with
the input that showed it and what bgc says now.

* a table or an import named through a YAML escape (``"t\\x61ble"``) was missing from the
  compile cache's key, the run record and the run's inputs: an edited table replayed the old
  result, and ``--out`` could replace the table;
* an empty output path (``--out ''``, ``--plot ''``, ``--scene ''``) was taken as no option:
  exit 0 with nothing written;
* ``bgc sweep --scheduler bogus`` was an internal error; ``--max-wall nan`` was accepted;
* a scene's (or a sweep's) parameter value outside the model's ``min``/``max`` ran;
* ``linearize --at`` a time that is not finite, before the start or past the limit of times
  was blamed on the model (or integrated backwards);
* a 5000-digit number in an expression showed Python's own advice;
* a model path naming a folder or a device said "does not exist".
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from bgc.base.reach import reached_files
from bgc.cli.commands import main
from conftest import bgc_in_process, seed_c_runtime

ROOT = Path(__file__).resolve().parents[1]
MSD = (ROOT / "models" / "msd.yaml").read_text(encoding="utf-8")
STEP = """bgc_scene: 1
model: msd.yaml
duration: 2.0
outputs: [position]
solver: {method: Radau, rtol: 1.0e-6, atol: 1.0e-9, dt: 0.1, backend: numpy}
"""


def one_line(r, status: int = 2) -> str:
    """The one line a user error prints (progress lines, which start with '[', aside)."""
    assert r.exit_code == status, (r.exit_code, r.output)
    assert "Traceback" not in r.output, r.output
    lines = [ln for ln in r.output.strip().splitlines() if not ln.startswith("[")]
    assert len(lines) == 1, r.output
    return lines[0]


def cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def files(root: Path) -> dict:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and "cache" not in p.relative_to(root).parts}


# -- a table named through a YAML escape ---------------------------------------------------------

ESCAPED = STEP + 'inputs:\n  F: {"t\\x61ble": force.csv, columns: [time, F]}\n'


def _escaped_project(root: Path) -> Path:
    (root / "msd.yaml").write_text(MSD)
    (root / "force.csv").write_text("time,F\n0,0\n1,10\n2,10\n")
    scene = root / "scene.yaml"
    scene.write_text(ESCAPED)
    assert b"table" not in scene.read_bytes()  # the escape is the whole point
    return scene


@pytest.mark.parametrize("key", ['"t\\x61ble"', '"\\u0074able"', '"\\U00000074able"'])
def test_a_table_named_through_an_escape_is_reached(tmp_path, key):
    (tmp_path / "msd.yaml").write_text(MSD)
    (tmp_path / "force.csv").write_text("time,F\n0,0\n1,1\n")
    scene = tmp_path / "scene.yaml"
    scene.write_text(STEP + f"inputs:\n  F: {{{key}: force.csv}}\n")
    reached = [Path(r.resolved).name for r in reached_files(tmp_path / "msd.yaml", scene)]
    assert reached == ["msd.yaml", "force.csv"]


def test_an_import_named_through_an_escape_is_reached(tmp_path):
    parts = tmp_path / "parts.yaml"
    parts.write_text("bgc: 1\nname: parts\nelements: {}\nbonds: []\n")
    model = tmp_path / "m.yaml"
    model.write_text(MSD.replace("units: strict", '"imp\\x6frts": [{file: parts.yaml}]'))
    assert b"imports" not in model.read_bytes()
    assert [Path(r.resolved).name for r in reached_files(model)] == ["m.yaml", "parts.yaml"]


def test_an_edited_escaped_table_is_not_replayed_and_never_replaced(tmp_path):
    """The run with the first table, the table edited, the warm run: it must be the --no-cache
    run's answer (the force doubled: the static deflection F/k doubles), and an output aimed
    at the table is refused."""
    scene, cache = _escaped_project(tmp_path), seed_c_runtime(tmp_path / "cache")
    env = {"BGC_CACHE_DIR": cache}

    def position(name, *extra):
        r = bgc_in_process("simulate", scene, "-q", "--out", tmp_path / name, *extra, env=env)
        assert r.returncode == 0, r.stderr
        return np.load(tmp_path / name)["position"]

    first = position("a.npz")
    (tmp_path / "force.csv").write_text("time,F\n0,0\n1,20\n2,20\n")
    warm, cold = position("b.npz"), position("c.npz", "--no-cache")
    np.testing.assert_array_equal(warm, cold)
    assert warm[-1] > 1.5 * first[-1]
    before = (tmp_path / "force.csv").read_bytes()
    r = bgc_in_process("simulate", scene, "-q", "--out", tmp_path / "force.csv", env=env)
    assert r.returncode == 2 and "is an input of this run" in r.stderr, r.stderr
    assert (tmp_path / "force.csv").read_bytes() == before


# -- an empty output path is refused, never taken as no option ----------------------------------

def _step_project(root: Path) -> Path:
    (root / "msd.yaml").write_text(MSD)
    scene = root / "scene.yaml"
    scene.write_text(STEP)
    return scene


SWEEP = STEP + "sweep:\n  parameters:\n    m: {values: [1.0, 2.0]}\n"


@pytest.mark.parametrize("argv, words", [
    (["simulate", "{scene}", "--out", ""], "error: --out '': the path is empty"),
    (["linearize", "{model}", "--out", ""], "error: --out '': the path is empty"),
    (["accuracy", "{scene}", "--out", "", "--methods", "RK45", "--tols", "1e-3"],
     "error: --out '': the path is empty"),
    (["sweep", "{sweep}", "--out", "r.zarr", "--plot", ""], "error: --plot '': the path is empty"),
    (["compile", "{model}", "--scene", "", "-o", "m.py"], "cannot read scene file '': no such file"),
])
def test_an_empty_output_path_is_one_message_and_writes_nothing(tmp_path, monkeypatch, argv,
                                                                  words):
    scene = _step_project(tmp_path)
    (tmp_path / "sweep.yaml").write_text(SWEEP)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("BGC_CACHE_DIR", str(seed_c_runtime(tmp_path / "cache")))
    before = files(tmp_path)
    subs = {"{scene}": scene, "{model}": tmp_path / "msd.yaml", "{sweep}": tmp_path / "sweep.yaml"}
    r = cli(*[subs.get(a, a) for a in argv], "-q")
    assert words in one_line(r)
    assert files(tmp_path) == before


# -- bgc sweep's and bgc accuracy's options ------------------------------------------------------

@pytest.mark.parametrize("address", ["bogus", "foo://host:1", "tcp://"])
def test_a_scheduler_that_is_not_an_address_is_a_usage_error(tmp_path, monkeypatch, address):
    (tmp_path / "msd.yaml").write_text(MSD)
    (tmp_path / "sweep.yaml").write_text(SWEEP)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("BGC_CACHE_DIR", str(seed_c_runtime(tmp_path / "cache")))
    r = cli("sweep", "sweep.yaml", "--out", "r.zarr", "--scheduler", address, "-q",
            "--backend", "numpy")
    line = one_line(r)
    assert line.startswith(f"error: --scheduler {address!r} is not a Dask scheduler's address")
    assert not (tmp_path / "r.zarr").exists()


@pytest.mark.parametrize("value", ["nan", "inf", "-1", "0"])
def test_sweep_max_wall_is_a_positive_finite_number(tmp_path, value):
    (tmp_path / "msd.yaml").write_text(MSD)
    (tmp_path / "sweep.yaml").write_text(SWEEP)
    r = cli("sweep", tmp_path / "sweep.yaml", "--out", tmp_path / "r.zarr", "--max-wall", value)
    assert "Invalid value for '--max-wall'" in one_line(r)
    assert not (tmp_path / "r.zarr").exists()


# -- a scene's or a sweep's value outside the model's min and max --------------------------------

@pytest.mark.parametrize("line, words", [
    ("parameters: {m: -1.0}", "parameter 'm': the scene gives -1, below the model's min 0 "
                              "(line 16 of "),
    ("parameters: {k: -200}", "parameter 'k': the scene gives -200, below the model's min 0"),
    ("parameters: {m: 1.0e-9}", None),  # within: runs
])
def test_scene_parameters_keep_the_models_bounds(tmp_path, line, words):
    """msd.yaml says ``min: 0`` for m, k and c; the model's own value had to keep it, and so
    must a scene's (a negative mass is a different, unstable system)."""
    scene = _step_project(tmp_path)
    scene.write_text(STEP + line + "\n")
    r = cli("simulate", scene, "-q", "--out", tmp_path / "r.npz")
    if words is None:
        assert r.exit_code == 0, r.output
        return
    text = one_line(r)
    assert text.startswith(f"{scene}:6:14: ") and words in text, text
    assert not (tmp_path / "r.npz").exists()


@pytest.mark.parametrize("rule, words", [
    ("{linspace: [-1.0, 3.0, 3]}", "the sweep gives -1, below the model's min 0"),
    ("{values: [2.0, -0.5]}", "the sweep gives -0.5, below the model's min 0"),
    ("{normal: [0.1, 1.0]}\n  samples: 8\n  seed: 1", "below the model's min 0"),
])
def test_swept_values_keep_the_models_bounds(tmp_path, rule, words):
    (tmp_path / "msd.yaml").write_text(MSD)
    sweep = tmp_path / "sweep.yaml"
    sweep.write_text(STEP + f"sweep:\n  parameters:\n    m: {rule}\n")
    r = cli("sweep", sweep, "--out", tmp_path / "r.zarr", "-q")
    text = one_line(r)
    assert text.startswith(f"{sweep}:8:5: parameter 'm': ") and words in text, text
    assert not (tmp_path / "r.zarr").exists()


# -- linearize --at: a time a run from the start reaches -----------------------------------------

@pytest.mark.parametrize("at", ["nan", "inf", "-1", "1e308"])
def test_linearize_at_a_time_outside_the_run_is_a_usage_error(at):
    r = cli("linearize", ROOT / "models" / "msd.yaml", "--at", at, "-q")
    assert one_line(r) == (f"error: --at {at!r}: a time from the start, 0 s, to 1e+15 s (the "
                           "limit of times)")


def test_linearize_at_nan_from_python_is_a_bgc_error():
    import bgc

    with pytest.raises(bgc.BgcError, match="--at nan: a time from the start"):
        bgc.linearize(ROOT / "models" / "msd.yaml", at=float("nan"))


def test_jac_tols_message_names_its_own_option():
    r = cli("accuracy", ROOT / "models" / "scenes" / "msd_step.yaml", "--jac-tols", "x")
    assert one_line(r) == "error: --jac-tols 'x': give 1e-3:1e-10 or a comma list"


# -- a number of thousands of digits ---------------------------------------------------------------

def test_a_number_of_thousands_of_digits_is_named_not_pythons_advice():
    from bgc.format.parse import parse_text

    text = MSD.replace('inertia: "m"', 'inertia: "' + "9" * 5000 + '"')
    with pytest.raises(Exception) as err:
        parse_text(text, "m.yaml")
    line = text[:text.index("9" * 5000)].count("\n") + 1
    msg = str(err.value)
    assert msg.startswith(f"m.yaml:{line}:") and "a number with thousands of digits" in msg, msg
    assert "set_int_max_str_digits" not in msg


# -- a model path that names a folder or a device ------------------------------------------------

@pytest.mark.parametrize("target, words", [
    ("folder", "model file is a folder"),
    ("/dev/null", "model file is not a regular file (a device, FIFO or socket)"),
    ("missing.yaml", "model file does not exist"),
])
def test_a_model_path_says_what_it_names(tmp_path, monkeypatch, target, words):
    import bgc

    monkeypatch.chdir(tmp_path)
    (tmp_path / "folder").mkdir()
    r = cli("equations", target)
    assert one_line(r) == f"{target}:1:1: {words}"
    with pytest.raises(bgc.BgcError, match="^" + re.escape(f"{target}:1:1: {words}")):
        bgc.compile(target)
    scene = tmp_path / "scene.yaml"
    scene.write_text(STEP.replace("model: msd.yaml", f"model: {target}"))
    r = cli("simulate", scene, "-q")
    shown = repr(target)
    assert one_line(r) == f"{scene}:2:8: model file {shown} {words.removeprefix('model file ')}"


# -- plots named after a hidden scene file: refused before anything is written ----------------------

@pytest.mark.parametrize("plots", ["", "plots:\n  - {kind: time, outputs: [position]}\n"])
def test_plot_names_are_checked_before_any_output_is_written(tmp_path, plots):
    """A scene without ``name:`` names its plots after its file: '.hidden.yaml' gives hidden
    file names, refused; --out used to be written first, and the plots' folder made."""
    (tmp_path / "msd.yaml").write_text(MSD)
    scene = tmp_path / ".hidden.yaml"
    scene.write_text(STEP + plots)
    before = files(tmp_path)
    r = cli("simulate", scene, "-q", "--out", tmp_path / "r.npz", "--plot", tmp_path / "figs")
    text = one_line(r)
    assert text.startswith(f"{scene}:1:1: plot file name '.hidden_") and "name: ..." in text
    assert files(tmp_path) == before and not (tmp_path / "figs").exists()
    scene.write_text(STEP.replace("bgc_scene: 1", "bgc_scene: 1\nname: visible") + plots)
    r = cli("simulate", scene, "-q", "--out", tmp_path / "r.npz", "--plot", tmp_path / "figs")
    assert r.exit_code == 0, r.output
    assert all(p.name.startswith("visible_") for p in (tmp_path / "figs").iterdir())


# -- bgc cache clear in a folder that holds a user's files ----------------------------------------

def test_cache_clear_removes_only_what_bgc_made(tmp_path, monkeypatch):
    """BGC_CACHE_DIR pointed at a project folder: its own run/, numpy/, c/ sub-folders were
    removed whole, files bgc never made with them; now only bgc's entries go."""
    proj = tmp_path / "proj"
    mine = {"run/notes.txt": "precious", "numpy/ab/x.txt": "mine", "c/keep.c": "int x;",
            "c-runtime/a.txt": "k", "msd.yaml": MSD}
    for rel, text in mine.items():
        (proj / rel).parent.mkdir(parents=True, exist_ok=True)
        (proj / rel).write_text(text)
    proj.chmod(0o700)
    monkeypatch.setenv("BGC_CACHE_DIR", str(proj))
    r = CliRunner().invoke(main, ["simulate", str(proj / "msd.yaml"), "-q", "--backend",
                                  "numpy", "--t-end", "0.1"])
    assert r.exit_code == 0, r.output
    assert list((proj / "numpy").glob("*/*" + "?" * 60)), "no entry made"
    r = CliRunner().invoke(main, ["cache", "clear"])
    assert r.exit_code == 0 and "removed 2 entries" in r.output, r.output  # module, record
    assert "note: left 4 item(s) bgc did not make" in r.output
    for rel, text in mine.items():
        assert (proj / rel).read_text() == text, rel
    assert not list((proj / "numpy").glob("*/*" + "?" * 60))
    assert sorted(p.name for p in (proj / "numpy").iterdir()) == ["ab"]


# -- a component instance's number outside the component parameter's min and max -----------------

SD = """bgc: 1
name: tm
parameters: {m: 2.0}
components:
  sd:
    parameters: {k: {value: 1.0, min: 0, max: 100}, r: 0.5}
    ports: {a: v}
    elements:
      v: {type: "1"}
      C: {type: C, stiffness: "k"}
      R: {type: R, resistance: "r"}
    bonds: [[v, C], [v, R]]
elements:
  f: {type: Se, effort: '1'}
  j: {type: '1'}
  mm: {type: I, inertia: m}
  s1: {type: sd, k: VALUE}
bonds: [[f, j], [j, mm], [j, s1.a]]
"""


@pytest.mark.parametrize("value, words", [
    ("-3", "instance 's1': parameter 'k' = -3 is below the min 0 of component 'sd'"),
    ("1e3", "instance 's1': parameter 'k' = 1000 is above the max 100 of component 'sd'"),
    ("50", None), ('"3*m"', None),  # within; an expression's value is the run's
])
def test_instance_numbers_keep_the_component_parameters_bounds(value, words):
    from bgc.api import check

    text = SD.replace("VALUE", value)
    if words is None:
        assert check(text).states
        return
    with pytest.raises(Exception) as err:
        check(text)
    assert str(err.value) == f"<string>:17:21: {words}"


# -- a junction of thousands of bonds; a law of a hundred nested where(...) ------------------------

def _wide(n: int, per: int) -> str:
    """n dampers on 1-junctions of at most ``per`` dampers each, joined in a chain."""
    js = -(-n // per)
    text = ["bgc: 1", "name: wide", "parameters: {m: 2.0, k: 200.0}", "elements:",
            "  force: {type: Se, effort: '1'}", "  mass: {type: I, inertia: m}",
            "  spring: {type: C, stiffness: k}"]
    text += [f"  v{j}: {{type: '1'}}" for j in range(js)]
    text += [f"  r{i}: {{type: R, resistance: '1 + q(spring)**2'}}" for i in range(n)]
    bonds = ["[force, v0]", "[v0, mass]", "[v0, spring]"] + [f"[v{j}, v{j + 1}]"
                                                             for j in range(js - 1)]
    bonds += [f"[v{i // per}, r{i}]" for i in range(n)]
    return "\n".join(text) + "\nbonds: [" + ", ".join(bonds) + "]\n"


def test_a_junction_of_more_bonds_than_the_limit_is_located(tmp_path):
    """3 000 bonds on one junction: Python's parser refused the generated module's balance
    line (an unlocated 'nested too deeply', after seconds of work); now the junction is
    named, and the remedy (joined junctions) compiles."""
    model = tmp_path / "wide.yaml"
    model.write_text(_wide(3000, 3000))
    r = cli("compile", model, "-o", tmp_path / "w.py", "-q")
    assert one_line(r) == (f"{model}:8:3: junction 'v0' has 3003 bonds, more than 1000 (the "
                           "limit of bonds on one junction): split it into joined junctions")
    assert not (tmp_path / "w.py").exists()


@pytest.mark.slow
def test_split_junctions_compile(tmp_path):
    model = tmp_path / "wide.yaml"
    model.write_text(_wide(2400, 800))
    r = cli("compile", model, "-o", tmp_path / "w.py", "-q")
    assert r.exit_code == 0, r.output


def _nested_where(n: int) -> str:
    return "".join(f"where(q(spring) > {i}, 1, " for i in range(n)) + "0" + ")" * n


@pytest.mark.parametrize("where, line, words", [
    ("law", 6, "C 'spring': its law is nested too deeply to differentiate"),
    ("output", 9, "output 'x': its expression is nested too deeply to differentiate"),
])
def test_a_law_too_deep_to_differentiate_names_its_element(tmp_path, where, line, words):
    law = f"k + {_nested_where(120)}" if where == "law" else "k"
    out = _nested_where(120) if where == "output" else "q(spring)"
    model = tmp_path / "deep.yaml"
    model.write_text(f"""bgc: 1
name: deep
parameters: {{m: 2.0, k: 200.0}}
elements:
  force: {{type: Se, effort: '1'}}
  spring: {{type: C, stiffness: "{law}"}}
  mass: {{type: I, inertia: m}}
  v: {{type: '1'}}
outputs: {{x: "{out}"}}
bonds: [[force, v], [v, mass], [v, spring]]
""")
    r = cli("compile", model, "-o", tmp_path / "d.py", "-q", "--no-cache")
    text = one_line(r)
    assert text.startswith(f"{model}:{line}:") and words in text, text


# -- a quiet sweep says nothing on stderr ----------------------------------------------------------

@pytest.mark.slow
def test_a_quiet_sweep_prints_no_warning(tmp_path):
    """Zarr warned about the store's marker file (.bgc-output) each time it listed the
    folder: seven warnings on every run's stderr, twice as many on a resumed one."""
    import os
    import subprocess
    import sys

    (tmp_path / "msd.yaml").write_text(MSD)
    (tmp_path / "sweep.yaml").write_text(SWEEP)
    env = {**os.environ, "BGC_CACHE_DIR": str(seed_c_runtime(tmp_path / "cache"))}
    for _ in range(2):  # a run, then a resumed one
        r = subprocess.run([sys.executable, "-m", "bgc", "sweep", "sweep.yaml", "--out", "r.zarr",
                            "--workers", "1", "-q"], cwd=tmp_path, env=env, capture_output=True,
                           text=True, timeout=300)
        # (only Zarr's lines: a loaded machine may have Dask log an unresponsive event loop)
        assert r.returncode == 0, r.stderr
        assert "ZarrUserWarning" not in r.stderr and ".bgc-output" not in r.stderr, r.stderr


# -- initial: equilibrium where the search itself fails ----------------------------------------------

def test_an_equilibrium_search_that_fails_is_located_at_initial(tmp_path):
    """two_tanks.yaml starts with empty tanks, where the orifice law's slope is infinite: the
    search's SVD fails. It was an internal error (exit 3) with a numpy warning; linearize
    already said it in one line."""
    (tmp_path / "two_tanks.yaml").write_text((ROOT / "models" / "two_tanks.yaml").read_text())
    scene = tmp_path / "eq.yaml"
    scene.write_text("bgc_scene: 1\nmodel: two_tanks.yaml\nduration: 0.5\n"
                     "initial: equilibrium\nsolver: {backend: numpy}\n")
    r = cli("simulate", scene, "-q", "--out", tmp_path / "r.npz")
    text = one_line(r)
    assert text.startswith(f"{scene}:4:1: initial: no equilibrium found"), text
    assert not (tmp_path / "r.npz").exists()


# -- a scene with both duration and t_span ---------------------------------------------------------

@pytest.mark.parametrize("keys, line", [("duration: 5.0\nt_span: [0, 2]\n", 5),
                                        ("t_span: [1, 6]\nduration: 5.0\n", 5)])
def test_duration_and_t_span_together_are_refused(tmp_path, keys, line):
    """Both used to run, t_span winning silently over the duration."""
    (tmp_path / "msd.yaml").write_text(MSD)
    scene = tmp_path / "s.yaml"
    scene.write_text("bgc_scene: 1\nmodel: msd.yaml\nsolver: {backend: numpy}\n" + keys)
    r = cli("simulate", scene, "-q", "--out", tmp_path / "r.npz")
    assert one_line(r) == f"{scene}:{line}:1: the scene: give duration or t_span, not both"


# -- a periodic event whose period is not positive -------------------------------------------------

TICK = """bgc: 1
name: tick
parameters: {m: 2.0, k: 200.0, T: PERIOD, T2: "T - 1"}
modes: {on: 0}
elements:
  force: {type: Se, effort: 'where(on > 0.5, 1, 0)'}
  mass: {type: I, inertia: m}
  spring: {type: C, stiffness: k}
  v: {type: '1'}
bonds: [[force, v], [v, mass], [v, spring]]
events:
  tick: {every: EVERY, do: {on: '1 - on'}}
"""


@pytest.mark.parametrize("period, every, shown", [("0.0", "T", "0"), ("-1.0", "T", "-1"),
                                                  ("1.0", "T2", "0"), ("0.5", "T", None)])
def test_a_periodic_event_needs_a_positive_period(period, every, shown):
    """every: 0 (or -1) compiled and ran, the event never firing, exit 0."""
    from bgc.api import check

    text = TICK.replace("PERIOD", period).replace("EVERY", every)
    if shown is None:
        assert "tick_count" in " ".join(check(text).states)
        return
    with pytest.raises(Exception) as err:
        check(text)
    assert str(err.value) == (f"<string>:12:17: event 'tick': the period is {shown} with the "
                              "parameters' values (the model's, or a scene's): it must be "
                              "positive")


# -- a scene's initial: in a sweep and in an accuracy study ---------------------------------------

INIT = STEP.replace("outputs: [position]", "outputs: [position]\ninitial: {spring.q: 0.2}")


def _msd_from(x0: float, t: np.ndarray, m: float = 3.0) -> np.ndarray:
    """An independent answer: m x'' + c x' + k x = F0 (msd.yaml's defaults, the scene's m)
    from x(0) = x0 at rest, by scipy."""
    from scipy.integrate import solve_ivp

    k, c, f0 = 200.0, 4.0, 10.0
    sol = solve_ivp(lambda _, y: [y[1], (f0 - k * y[0] - c * y[1]) / m], (0.0, t[-1]),
                    [x0, 0.0], t_eval=t, rtol=1e-11, atol=1e-13)
    return sol.y[0]


def test_a_sweep_starts_where_its_scene_does(tmp_path):
    """A sweep ignored the scene's initial: every sample started from the model's own x0
    (the docs say a sample is the same run as the scene alone)."""
    from bgc.studies.sweep import prepare, run_chunk

    (tmp_path / "msd.yaml").write_text(MSD)
    scene = tmp_path / "init.yaml"
    scene.write_text(INIT + "sweep:\n  parameters:\n    m: {values: [3.0, 1.0]}\n")
    res = run_chunk(prepare(scene, backend="numpy"), 0, 2)
    assert list(res["status"]) == [0, 0]
    t = np.linspace(0.0, 2.0, 21)
    for row, m in zip(res["y"]["position"], (3.0, 1.0)):
        np.testing.assert_allclose(row, _msd_from(0.2, t, m), atol=2e-5)


def test_a_sweep_starts_each_sample_at_its_own_equilibrium(tmp_path):
    """initial: equilibrium in a swept scene: each sample's static deflection F0/k (F0 = 10 N
    held), whatever the mass; without the start they all began at rest at zero."""
    from bgc.studies.sweep import prepare, run_chunk

    (tmp_path / "msd.yaml").write_text(MSD)
    scene = tmp_path / "eq.yaml"
    scene.write_text(STEP + "initial: equilibrium\nsweep:\n  parameters:\n"
                            "    k: {values: [100.0, 400.0]}\n")
    res = run_chunk(prepare(scene, backend="numpy"), 0, 2)
    assert list(res["status"]) == [0, 0]
    for row, k in zip(res["y"]["position"], (100.0, 400.0)):
        np.testing.assert_allclose(row, 10.0 / k, rtol=1e-6)


def test_an_accuracy_study_starts_where_its_scene_does(tmp_path):
    from bgc.studies.runs import prepare, solve

    (tmp_path / "msd.yaml").write_text(MSD)
    scene = tmp_path / "init.yaml"
    scene.write_text(INIT.replace("duration: 2.0", "duration: 2.0\nparameters: {m: 3.0}"))
    setup = prepare(scene)
    res, _ = solve(setup, "Radau", 1e-10, 1e-12)
    np.testing.assert_allclose(np.asarray(res.y["position"]).reshape(-1),
                               _msd_from(0.2, setup.t_eval), atol=1e-7)


# -- bgc export --scene with an initial: the FMU does not carry ------------------------------------

def test_export_of_a_scene_with_initial_states_says_the_fmu_does_not_carry_them(tmp_path):
    """The FMU starts from the model's x0 (FMPy: position 0 at t = 0, not the scene's 0.2):
    the export now says so instead of silently differing from the scene."""
    import shutil as sh

    if sh.which("cc") is None:
        pytest.skip("no C compiler")
    (tmp_path / "msd.yaml").write_text(MSD)
    scene = tmp_path / "init.yaml"
    scene.write_text(INIT)
    r = cli("export", tmp_path / "msd.yaml", "--scene", scene, "--fmu", tmp_path / "i.fmu")
    assert r.exit_code == 0, r.output
    assert ("warning: the FMU starts from the model's initial state: the scene's initial: "
            "(line 5) is not carried into it") in r.output
