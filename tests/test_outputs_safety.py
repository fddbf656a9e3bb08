"""Outputs never destroy anything: bgc's one checked writer (bgc.base.outfiles) and every command's
outputs through it; numerical failures as one located line; exit statuses; no temporaries.

Each malformed invocation is paired with the message it must give. The writer's rules are
checked in-process (fast); a few end-to-end runs show that every command uses it.
"""
from __future__ import annotations

import os
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bgc.base.outfiles import (
    Inputs,
    OutputError,
    check_output,
    model_inputs,
    write_output,
)

ROOT = Path(__file__).resolve().parents[1]
HERE = Path(__file__).resolve().parent / "outputs_safety"
MSD = ROOT / "models" / "msd.yaml"
MSD_SCENE = ROOT / "models" / "scenes" / "msd_step.yaml"


def bgc(*args, cwd=None, env=None, umask=None):
    full_env = {**os.environ, **(env or {})}
    return subprocess.run([sys.executable, "-m", "bgc", *map(str, args)], capture_output=True,
                          text=True, cwd=cwd, timeout=600, env=full_env,
                          preexec_fn=(lambda: os.umask(umask)) if umask is not None else None)


def one_error_line(r, status=2):
    """The run failed with `status`, printed exactly one line on stderr (with -q) and no
    traceback; returns that line."""
    assert r.returncode == status, (r.returncode, r.stderr)
    assert "Traceback" not in r.stderr and "Warning" not in r.stderr, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    return lines[0]


def listing(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


# ---------------------------------------------------------------------------------------------
# the writer, in-process


@pytest.fixture
def model(tmp_path):
    m = tmp_path / "model.yaml"
    m.write_text("original model\n")
    return m


def test_writes_atomically_and_replaces_a_regular_file(tmp_path):
    out = tmp_path / "sub" / "deeper" / "out.py"  # missing folders are created
    write_output(out, "first\n")
    write_output(out, b"second\n")
    assert out.read_bytes() == b"second\n"
    assert listing(out.parent) == ["out.py"]  # no temporary left


@pytest.mark.parametrize("mask,mode", [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_permissions_follow_the_umask(tmp_path, mask, mode):
    """What open() would give a new file: 0o666 & ~umask (mkstemp alone gives 0o600)."""
    old = os.umask(mask)
    try:
        p = write_output(tmp_path / "f.txt", "x")
    finally:
        os.umask(old)
    assert stat.S_IMODE(p.stat().st_mode) == mode


def test_an_input_is_never_replaced_by_any_name_or_link(tmp_path, model):
    ins = Inputs([model])
    (tmp_path / "linkdir").symlink_to(tmp_path, target_is_directory=True)
    os.link(model, tmp_path / "hard.yaml")
    spellings = [model, tmp_path / "." / "model.yaml", tmp_path / "linkdir" / "model.yaml",
                 tmp_path / "hard.yaml"]
    for p in spellings:
        with pytest.raises(OutputError, match="is an input of this run"):
            write_output(p, "overwritten", ins, "-o")
    assert model.read_text() == "original model\n"
    assert listing(tmp_path) == ["hard.yaml", "linkdir", "model.yaml"]


def test_only_regular_files_are_replaced(tmp_path, model):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    (tmp_path / "folder").mkdir()
    (tmp_path / "to_model").symlink_to(model)
    (tmp_path / "to_other").symlink_to(tmp_path / "other.txt")  # dangling, then real
    cases = {
        "/dev/null": "is a character device, not a regular file",
        fifo: "is a FIFO, not a regular file",
        tmp_path / "folder": "is a folder, not a regular file",
        tmp_path / "to_model": "is a symbolic link",
        tmp_path / "to_other": "is a symbolic link",
    }
    for p, msg in cases.items():
        with pytest.raises(OutputError, match=msg):
            write_output(p, "x", Inputs([model]), "--out")
    (tmp_path / "other.txt").write_text("keep")
    with pytest.raises(OutputError, match="is a symbolic link"):
        write_output(tmp_path / "to_other", "x")
    assert (tmp_path / "other.txt").read_text() == "keep"
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode) and (tmp_path / "folder").is_dir()
    assert model.read_text() == "original model\n"
    assert listing(tmp_path) == ["fifo", "folder", "model.yaml", "other.txt", "to_model",
                                 "to_other"]


def test_unwritable_paths_are_one_message(tmp_path):
    (tmp_path / "afile").write_text("")
    cases = {
        "": "'': the path is empty",
        "a" * 300 + ".py": "File name too long",
        "/proc/x.py": "cannot create a file in '/proc'",
        str(tmp_path / "afile" / "x.py"): "is a file, not a folder",
        str(tmp_path / "dir") + "/": "names a folder, not a file",
        "bad\0name.py": "NUL",
    }
    for p, msg in cases.items():
        with pytest.raises(OutputError) as exc:
            write_output(p, "x", what="-o")
        text = str(exc.value)
        assert msg in text and text.startswith("-o ") and "\n" not in text
        assert len(text) < 400
    assert listing(tmp_path) == ["afile"]


def test_a_failure_while_writing_leaves_nothing(tmp_path, monkeypatch):
    out = tmp_path / "out.py"
    out.write_text("before")

    def full(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", full)
    with pytest.raises(OutputError, match="No space left on device"):
        write_output(out, "after")
    assert out.read_text() == "before" and listing(tmp_path) == ["out.py"]


def test_model_inputs_follow_imports_through_files_without_components():
    """uses_parts.yaml imports mid.yaml (no components of its own), which imports parts.yaml."""
    got = {p.resolve() for p in model_inputs(HERE / "uses_parts.yaml")}
    assert got == {HERE / "uses_parts.yaml", HERE / "mid.yaml", HERE / "parts.yaml"}
    assert check_output(HERE / "new.py", Inputs(model_inputs(HERE / "uses_parts.yaml")))


# ---------------------------------------------------------------------------------------------
# every command through the writer (end to end)


def test_compile_never_overwrites_its_inputs(tmp_path):
    """The model, a file it imports (also one defining nothing itself), the scene: each named
    as the output is refused, and stays byte for byte as it was."""
    before = {p: p.read_bytes() for p in HERE.iterdir()}
    for target in ("uses_parts.yaml", "mid.yaml", "parts.yaml"):
        r = bgc("compile", HERE / "uses_parts.yaml", "-o", HERE / target, "-q")
        line = one_error_line(r)
        assert line == f"error: -o '{HERE / target}': is an input of this run; choose another " \
                       "output name"
    scene = HERE / "orifice_equal.yaml"
    r = bgc("compile", HERE / "orifice.yaml", "--scene", scene, "-o", scene, "-q")
    assert "is an input of this run" in one_error_line(r)
    # simulate: the imported file (known once the model has parsed) refused after the run
    r = bgc("simulate", HERE / "uses_parts_scene.yaml", "--out", HERE / "parts.yaml", "-q")
    assert one_error_line(r) == (f"error: --out '{HERE / 'parts.yaml'}': is an input of this "
                                 "run; choose another output name")
    assert {p: p.read_bytes() for p in HERE.iterdir()} == before


def test_compile_output_permissions_and_device(tmp_path):
    r = bgc("compile", MSD, "-o", tmp_path / "m.py", "-q", umask=0o027)
    assert r.returncode == 0, r.stderr
    assert stat.S_IMODE((tmp_path / "m.py").stat().st_mode) == 0o640
    r = bgc("compile", MSD, "-o", "/dev/null", "-q")
    assert one_error_line(r) == ("error: -o '/dev/null': is a character device, not a regular "
                                 "file; bgc replaces only regular files")
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)


def test_graph_creates_folders_and_refuses_the_unwritable(tmp_path):
    r = bgc("graph", MSD, "-o", tmp_path / "out" / "g.dot")
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "out" / "g.dot").read_text().startswith("digraph")
    (tmp_path / "plain").write_text("")
    r = bgc("graph", MSD, "-o", tmp_path / "plain" / "g.dot")
    assert one_error_line(r) == (f"error: -o '{tmp_path / 'plain' / 'g.dot'}': a part of the "
                                 "path is a file, not a folder")
    r = bgc("graph", MSD, "-o", "/proc/g.dot")
    assert one_error_line(r).startswith("error: -o '/proc/g.dot': cannot create a file in")


def test_simulate_refuses_bad_outputs_before_running(tmp_path):
    """--out naming a FIFO (which would block a writer), a folder, the scene; --plot naming a
    file: refused before the run (no 'simulating' progress line), nothing changed."""
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    (tmp_path / "dir").mkdir()
    (tmp_path / "file").write_text("keep")
    scene_bytes = MSD_SCENE.read_bytes()
    cases = [
        (("--out", fifo), f"error: --out '{fifo}': is a FIFO, not a regular file; bgc "
                          "replaces only regular files"),
        (("--out", tmp_path / "dir"), f"error: --out '{tmp_path / 'dir'}': is a folder, not a "
                                      "regular file; bgc replaces only regular files"),
        (("--out", MSD_SCENE), f"error: --out '{MSD_SCENE}': is an input of this run; choose "
                               "another output name"),
        (("--out", MSD), f"error: --out '{MSD}': is an input of this run; choose another "
                         "output name"),
        (("--plot", tmp_path / "file"), f"error: --plot '{tmp_path / 'file'}': exists and is "
                                        "not a folder"),
        (("--plot", tmp_path / "file" / "sub"), f"error: --plot '{tmp_path / 'file' / 'sub'}'"
                                                ": a part of the path is a file, not a folder"),
    ]
    for args, msg in cases:
        r = bgc("simulate", MSD_SCENE, *args)
        assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
        assert r.stderr.strip().splitlines()[-1] == msg
        assert "simulating" not in r.stderr
    assert MSD_SCENE.read_bytes() == scene_bytes and (tmp_path / "file").read_text() == "keep"
    assert listing(tmp_path) == ["dir", "fifo", "file"] and listing(tmp_path / "dir") == []


# ---------------------------------------------------------------------------------------------
# numerical failures: one located line naming the element, exit 1, nothing written


def test_orifice_at_equal_levels_names_the_orifice_and_the_remedy(tmp_path):
    """sign(e)*sqrt(abs(e)) at e = 0 (equal levels): the slope dQ/de is infinite there, so the
    Jacobian d(dV1/dt)/dV1 = -k/(2 sqrt|e|) * rho g / A is not finite at t = 0. bgc simulate:
    one line at the orifice's place in the model, with the remedy; exit 1; nothing written."""
    out = tmp_path / "r.npz"
    r = bgc("simulate", HERE / "orifice_equal.yaml", "--out", out, "--plot", tmp_path / "plots",
            "-q")
    line = one_error_line(r, status=1)
    assert line.startswith(f"{HERE / 'orifice.yaml'}:17:3: simulation failed: Radau failed at "
                           "t = 0: the Jacobian entry (0, 0), d(dtank1.q/dt)/d(tank1.q), is ")
    assert "it comes from orifice (R): flow law" in line and "infinite slope" in line
    assert "regularise" in line and "sqrt(abs(e) + eps**2) - eps" in line
    assert listing(tmp_path) == []
    # bgc accuracy: the same line (its start checked before the study), exit 1, no folder
    r = bgc("accuracy", HERE / "orifice_equal.yaml", "--out", tmp_path / "acc", "--methods",
            "RK45", "--jac-methods", "", "-q")
    assert one_error_line(r, status=1) == line  # (its check runs Radau too)
    assert listing(tmp_path) == []


@pytest.fixture(scope="module")
def orifice():
    from bgc.format.scene import parse_scene
    from bgc.run.runner import compile_scene

    return compile_scene(parse_scene(HERE / "orifice_equal.yaml"))


@pytest.mark.parametrize("method", ["RK23", "RK45", "DOP853", "Radau", "BDF", "LSODA", "Rodas4"])
def test_orifice_stops_every_method(orifice, method):
    """Every method stops at t = 0 on the orifice's infinite slope (the explicit ones in their
    stiffness check, LSODA in its Jacobian check at t0), and the diagnosis names the orifice."""
    from bgc.run.runner import nonfinite_culprit

    c, mod = orifice
    with pytest.raises(mod.NonFiniteError) as exc:
        mod.simulate((0.0, 10.0), method=method, dt=0.1)
    err = exc.value
    assert err.t == 0.0 and err.where == "jacobian" and err.index == (0, 0)
    np.testing.assert_array_equal(err.x, [0.1, 0.1])
    coord, text = nonfinite_culprit(c, mod, err)
    assert (coord.file, coord.line) == (str(HERE / "orifice.yaml"), 17)
    assert text.startswith("; it comes from orifice (R): flow law") and "regularise" in text


def test_regularised_orifice_runs_and_conserves_volume(tmp_path):
    """The remedy works: with sqrt(abs(e) + eps^2) - eps the same start runs, and the total
    volume V1 + V2 stays at 2 V0 (nothing leaves the two tanks) while the levels stay equal."""
    text = (HERE / "orifice.yaml").read_text().replace(
        'flow: "k*sign(e)*sqrt(abs(e))"', 'flow: "k*sign(e)*(sqrt(abs(e) + 1e-4) - 1e-2)"')
    (tmp_path / "orifice.yaml").write_text(text)
    (tmp_path / "s.yaml").write_text((HERE / "orifice_equal.yaml").read_text())
    r = bgc("simulate", tmp_path / "s.yaml", "--out", tmp_path / "r.npz", "-q")
    assert r.returncode == 0, r.stderr
    d = np.load(tmp_path / "r.npz")
    assert np.max(np.abs(d["dp"])) < 1e-9
    g, rho, A, V0 = 9.81, 1000.0, 0.2, 0.1
    np.testing.assert_allclose(d["levels"], rho * g * V0 / A, rtol=1e-9)


def test_log_of_zero_in_the_rhs_at_t0(tmp_path):
    r = bgc("simulate", HERE / "log_law_scene.yaml", "--out", tmp_path / "r.npz", "-q")
    line = one_error_line(r, status=1)
    assert line.startswith(f"{HERE / 'log_law.yaml'}:6:3: simulation failed: Radau failed at "
                           "t = 0: the right-hand side is not finite: dstore.q/dt is ")
    assert "it comes from store (C, integral)" in line and "log of q_store, which is 0" in line
    assert listing(tmp_path) == []


def test_nan_parameter_is_named():
    """A parameter override of NaN (through the module API) makes the rhs NaN at t0: the
    module names the state whose equation reads it, bgc's diagnosis the parameter."""
    from bgc.format.scene import parse_scene
    from bgc.run.runner import compile_scene, nonfinite_culprit

    c, mod = compile_scene(parse_scene(MSD_SCENE))
    p = {"c": np.nan}
    with pytest.raises(mod.NonFiniteError) as exc:
        mod.simulate((0.0, 1.0), method="Rodas4", p=p)
    err = exc.value
    assert err.t == 0.0 and err.where == "rhs" and err.stats["nfev"] == 1
    assert "dmass.p/dt is nan (state 0 'mass.p', element 'mass')" in str(err)
    coord, text = nonfinite_culprit(c, mod, err, p)
    assert text == "; parameter 'c' is nan"
    declared = [k for k, ln in enumerate(MSD.read_text().splitlines(), 1)
                if ln.startswith("  c:")]
    assert (Path(coord.file).name, [coord.line]) == ("msd.yaml", declared)  # c's declaration


def test_nan_derived_parameter_at_t0(tmp_path):
    """c = sqrt(c2 - c1) with c2 < c1 is NaN; the damper's force c v makes dp/dt NaN at
    t = 0: one line at the parameter's place, exit 1, nothing written."""
    assert "c: \"sqrt(c2 - c1)\"" in (HERE / "nan_param.yaml").read_text().splitlines()[9]
    r = bgc("simulate", HERE / "nan_param_scene.yaml", "--out", tmp_path / "r.npz", "-q")
    assert one_error_line(r, status=1) == (
        f"{HERE / 'nan_param.yaml'}:10:3: simulation failed: Radau failed at t = 0: the "
        "right-hand side is not finite: dmass.p/dt is nan (state 0 'mass.p', element 'mass'); "
        "the derived parameter c is nan (= sqrt(-c1 + c2) with the parameters' values) (it "
        "takes a fractional power of -c1 + c2, which is negative here: keep the argument "
        "positive)")
    assert listing(tmp_path) == []


@pytest.mark.parametrize("method", ["RK23", "RK45", "DOP853", "Radau", "BDF", "LSODA", "Rodas4"])
def test_every_method_stops_on_a_nan_rhs(gen, method):
    """The msd with a force that turns NaN at t = 0.5: every method stops with one
    NonFiniteError at the first rhs call past 0.5, naming mass.p, and warns of nothing."""
    import warnings

    msd = gen("msd")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a numpy RuntimeWarning would fail the test
        with pytest.raises(msd.NonFiniteError) as exc:
            msd.simulate((0.0, 1.0), method=method,
                         u={"F": lambda t: np.where(np.asarray(t) < 0.5, 10.0, np.nan)})
    err = exc.value
    assert 0.5 <= err.t < 1.0 and msd.STATE_NAMES[err.index] == "mass.p"
    assert str(err).startswith(f"{method} failed at t = ")


def test_the_cheap_finiteness_check(gen):
    """The per-call check (a sum of squares) against numpy's element-wise isfinite, including
    finite entries whose squares overflow (1e200) and a lone nan or inf among many."""
    msd = gen("msd")
    rng = np.random.default_rng(7)
    cases = [np.zeros(0), np.ones(3), np.array([1e200, -1e200]), np.array([1e308, 1.0])]
    for bad in (np.nan, np.inf, -np.inf):
        for n in (1, 5, 1000):
            a = rng.normal(size=n) * 1e150
            a[rng.integers(n)] = bad
            cases.append(a)
    cases.append(rng.normal(size=(4, 4, 3)))
    with np.errstate(all="ignore"):  # as inside simulate
        for a in cases:
            assert msd._all_finite(a) == bool(np.isfinite(a).all()), a


def test_jacobian_entry_in_a_batch(gen):
    """Batched parameters: the instance whose Jacobian is not finite is named; the (row,
    column) entry is the one that reads the bad parameter (msd: J[0, 0] = -c/m)."""
    msd = gen("msd")
    with pytest.raises(msd.NonFiniteError) as exc:
        msd.simulate((0.0, 1.0), method="Radau", p={"c": np.array([4.0, np.inf, 4.0])})
    err = exc.value
    assert err.instance == 1 and "in batch instance 1" in str(err)
    assert (err.where, err.index) in (("rhs", 0), ("jacobian", (0, 0)))


# ---------------------------------------------------------------------------------------------
# options, plots, internal errors, temporaries


_RTOL_LIMIT = "is outside [1e-14, 1] (the limit of tolerances: doubles carry about 16 digits)"


@pytest.mark.parametrize("args,msg", [
    (("--rtol", "-1"), f"error: --rtol -1 {_RTOL_LIMIT}"),
    (("--rtol", "nan"), f"error: --rtol nan {_RTOL_LIMIT}"),
    (("--rtol", "1e-3x"), "Error: Invalid value for '--rtol': '1e-3x' is not a valid float."),
    (("--max-wall", "nan"), "Error: Invalid value for '--max-wall': 'nan' is not a finite "
                            "number"),
    (("--max-wall", "0"), "Error: Invalid value for '--max-wall': '0' is not in the range "
                          "0 < x"),
    (("--max-wall", "-inf"), "Error: Invalid value for '--max-wall': '-inf' is not a finite "
                             "number"),
])
def test_simulate_options_are_validated(args, msg):
    r = bgc("simulate", MSD_SCENE, *args)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()  # one line: click's usage error, shortened
    want = msg if msg.startswith("error:") else "error: " + msg.removeprefix("Error: ")
    assert lines[-1].startswith(want) and not any(ln.startswith(("Usage:", "Try ")) for ln in lines), lines


@pytest.mark.parametrize("args,msg", [
    (("--budget", "inf"), "Error: Invalid value for '--budget': 'inf' is not a finite number"),
    (("--repeats", "0"), "Error: Invalid value for '--repeats': 0 is not in the range "
                        "1<=x<=1000."),
    (("--ref-rtol", "2"), "Error: Invalid value for '--ref-rtol': '2' is not in the range "
                          "0 < x < 1"),
    (("--tols", "inf:1e-3"), "error: --tols 'inf:1e-3': give 1e-3:1e-10 or a comma list"),
    (("--tols", "nan"), "error: --tols 'nan': tolerances lie strictly between 0 and 1"),
    (("--breakpoints", "nan"), "error: --breakpoints 'nan': give finite numbers"),
    (("--t-end", "1e309"), "Error: Invalid value for '--t-end': '1e309' is not a finite "
                           "number"),
])
def test_accuracy_options_are_validated(args, msg, tmp_path):
    r = bgc("accuracy", MSD_SCENE, "--out", tmp_path / "acc", *args)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    lines = r.stderr.strip().splitlines()  # one line: click's usage error, shortened
    want = msg if msg.startswith("error:") else "error: " + msg.removeprefix("Error: ")
    assert lines[-1].startswith(want) and not any(ln.startswith(("Usage:", "Try ")) for ln in lines), lines
    assert listing(tmp_path) == []


def test_plot_of_the_wrong_shape_is_located(tmp_path):
    """A path3d plot of a 2x2 matrix output: the plot's place in the scene, before any run."""
    r = bgc("simulate", HERE / "bad_plot.yaml", "--plot", tmp_path / "p", "-q")
    assert one_error_line(r) == (f"{HERE / 'bad_plot.yaml'}:6:5: plot: a path3d plot needs "
                                 "a 3-vector for each output; output 'mix' is 2x2")
    assert listing(tmp_path) == []


# the bug planted where the command takes its parser from (the commands import it when run)
_BOOM = ("import sys, bgc.format.parse, bgc.cli.commands\n"
         "def boom(*a, **k):\n    raise ZeroDivisionError('planted bug')\n"
         "bgc.format.parse.parse_file = boom\n"
         "sys.argv = ['bgc', 'check', sys.argv[1]]\nbgc.cli.commands.main()\n")


def test_internal_error_is_one_line_exit_3():
    r = subprocess.run([sys.executable, "-c", _BOOM, str(MSD)], capture_output=True, text=True,
                       env={**os.environ, "BGC_DEBUG": ""})
    assert one_error_line(r, status=3) == (
        "bgc: internal error (ZeroDivisionError: planted bug); this is a bug in bgc, please "
        "report it with the command and its input files (BGC_DEBUG=1 shows the traceback)")
    r = subprocess.run([sys.executable, "-c", _BOOM, str(MSD)], capture_output=True, text=True,
                       env={**os.environ, "BGC_DEBUG": "1"})
    assert r.returncode == 3 and "Traceback" in r.stderr and "planted bug" in r.stderr


@pytest.mark.slow
def test_no_temporary_files_left(tmp_path):
    """compile, simulate (with plots), explain and accuracy with TMPDIR set to an empty
    folder: it stays empty (generated modules load from memory)."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    work = tmp_path / "work"
    work.mkdir()
    env = {"TMPDIR": str(tmp), "TEMP": str(tmp), "TMP": str(tmp)}
    runs = [
        ("compile", MSD, "-o", work / "m.py", "-q"),
        ("simulate", MSD_SCENE, "--out", work / "r.npz", "--plot", work / "plots", "-q"),
        ("explain", MSD_SCENE, "--rounds", "1", "-q"),
        ("accuracy", MSD_SCENE, "--out", work / "acc", "--methods", "RK45", "--tols",
         "1e-3,1e-4", "--jac-methods", "", "--repeats", "1", "--budget", "10",
         "--ref-rtol", "1e-9", "-q"),
    ]
    for args in runs:
        r = bgc(*args, env=env)
        assert r.returncode == 0, (args[0], r.stderr)
        assert listing(tmp) == [], args[0]
    assert sorted(p.name for p in (work / "acc").iterdir()) == [
        "msd_step_accuracy.md", "msd_step_runs.csv", "msd_step_wp_rhs.png",
        "msd_step_wp_time.png"]
