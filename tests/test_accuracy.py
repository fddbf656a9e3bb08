"""The work-precision study (bgc accuracy) on the mass-spring-damper step scene."""
from __future__ import annotations

import csv
import math
import types
from dataclasses import replace
from pathlib import Path

import click
import numpy as np
import pytest
from click.testing import CliRunner

from bgc.base.errors import ModelError
from bgc.cli.accuracy import register as register_accuracy
from bgc.studies import accuracy as A

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "models" / "scenes" / "msd_step.yaml"
# The force steps at t = 1 s (where(t < 1, 0, F0)); the scene declares no breakpoint, and
# Radau/BDF cannot pass the jump at rtol 1e-12 without one.
BPS = (1.0,)
TOLS = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7)


@pytest.fixture(scope="module")
def setup():
    return A.prepare(SCENE, breakpoints=BPS)


@pytest.fixture(scope="module")
def small_study(setup):
    return A.study(setup, methods=("DOP853", "Radau"), tols=TOLS, budget=30.0, repeats=1,
                   ref_rtol=1e-11, jac_methods=("Radau",), jac_tols=(1e-5,))


def test_setup_takes_the_scene(setup):
    assert setup.name == "msd_step"
    assert setup.outputs == ("position", "velocity")
    assert setup.atol_scale == pytest.approx(1e-3)  # the scene's atol / rtol
    assert setup.breakpoints == (1.0,)
    assert len(setup.t_eval) == 501 and setup.t_eval[-1] == 5.0


def test_reference_agreement_is_tiny(small_study):
    st = small_study
    assert not st.stiff
    # the default references: the C backend's Radau checked with its DOP853 (not stiff)
    # where a compiler works, scipy's on the numpy backend otherwise
    want = ["C-Radau", "C-DOP853"] if A.c_available() else ["Radau", "DOP853"]
    assert [r.method for r in st.refs] == want
    assert st.agreement["err"] < 1e-9
    assert st.agreement["final_err"] < 1e-9
    # the step response settles at F0 / k = 0.05 m
    assert st.refs[0].y["position"][-1] == pytest.approx(0.05, rel=0.05)


def test_reference_passes_the_step_at_the_default_ref_rtol(setup):
    """Radau at rtol 1e-12 (the study's default reference tolerance) through the force step
    at the breakpoint; simulate keeps the input one-sided at the segment's end (before, the
    study had to clamp t itself). Closed form: at rest until t = 1, then the underdamped
    step response x = F0/k [1 - e^(-z wn s)(cos wd s + z/sqrt(1-z^2) sin wd s)], s = t - 1,
    with the scene's m = 3 kg (k = 200 N/m, c = 4 N s/m, F0 = 10 N)."""
    short = replace(setup, t_span=(0.0, 1.5), t_eval=setup.t_eval[setup.t_eval <= 1.5])
    res, stats = A.solve(short, "Radau", 1e-12, 1e-15)
    assert res.t[-1] == 1.5
    assert stats["nsteps"] > 0 and stats["nfev"] >= stats["nsteps"]
    m, k, c, F0 = 3.0, 200.0, 4.0, 10.0
    wn, z = np.sqrt(k / m), c / (2 * np.sqrt(k * m))
    r = np.sqrt(1 - z * z)
    s = np.maximum(res.t - 1.0, 0.0)
    x = F0 / k * (1 - np.exp(-z * wn * s) * (np.cos(wn * r * s) + z / r * np.sin(wn * r * s)))
    np.testing.assert_allclose(res.y["position"], x, rtol=0, atol=1e-12)


def test_radau_error_decreases_as_the_tolerance_tightens(small_study):
    rs = sorted((r for r in small_study.runs if r.method == "Radau"), key=lambda r: -r.rtol)
    assert [r.status for r in rs] == ["ok"] * len(TOLS)
    errs = [r.err for r in rs]
    for a, b in zip(errs, errs[1:]):
        assert b < 2 * a  # monotone within noise
    assert errs[-1] < errs[0] / 100  # and by a lot over four decades
    assert all(r.err < 100 * r.rtol for r in rs)
    assert all(r.nfev > 0 and r.njev > 0 and r.wall > 0 for r in rs)
    assert all(0 < r.nsteps <= r.nfev for r in rs)
    steps = [r.nsteps for r in rs]
    assert steps[-1] > steps[0]  # tighter tolerances take more steps
    assert set(rs[0].err_abs) == {"position", "velocity"}


def test_explicit_method_has_no_jacobian(small_study):
    rs = [r for r in small_study.runs if r.method == "DOP853"]
    assert all(r.status == "ok" and r.jac == "none" and r.njev == 0 for r in rs)


def test_jacobian_comparison_counts_fd_jacobians(small_study):
    modes = {r.jac: r for r in small_study.jac_runs}
    assert set(modes) == set(A.JAC_MODES)
    for r in modes.values():
        assert r.status == "ok" and r.njev > 0
        # same accuracy whichever Jacobian
        assert r.err == pytest.approx(modes["analytic"].err, rel=0.5)


def test_over_budget_is_reported_not_raised(setup, small_study):
    r = A.measure(setup, small_study.refs[0], "RK45", 1e-6, budget=0.0, repeats=3)
    assert r.status == "budget" and "budget" in r.message
    assert math.isnan(r.wall)


def test_failure_is_reported_not_raised(setup, small_study):
    class SimulationError(RuntimeError):
        pass

    def simulate(*a, **k):
        raise SimulationError("Radau failed at t = 0.5: step size too small")

    fake = types.SimpleNamespace(**{k: getattr(setup.module, k) for k in
                                    ("rhs", "jacobian", "STATE_NAMES", "JAC_SPARSITY")},
                                 simulate=simulate, SimulationError=SimulationError)
    r = A.measure(replace(setup, module=fake), small_study.refs[0], "Radau", 1e-6)
    assert r.status == "failed" and "step size too small" in r.message


def test_a_killed_worker_is_reported():
    import time

    status, val = A.run_isolated(lambda: time.sleep(30), timeout=0.5)
    assert status == "killed"


def test_skips_tighter_tolerances_after_the_budget(setup, small_study, monkeypatch):
    calls = []

    def fake_measure(setup_, ref, method, rtol, **kw):
        calls.append(rtol)
        return A.Run(method, rtol, rtol, "none", "budget", "over")

    monkeypatch.setattr(A, "measure", fake_measure)
    monkeypatch.setattr(A, "reference", lambda s, m, *a: small_study.refs[0])
    st = A.study(setup, methods=("RK45",), tols=(1e-4, 1e-3, 1e-5), jac_methods=())
    assert calls == [1e-3]
    assert [r.status for r in st.runs] == ["budget", "skipped", "skipped"]


def test_files_are_written(small_study, tmp_path):
    files = A.write_all(small_study, tmp_path)
    names = sorted(f.name for f in files)
    assert names == sorted(["msd_step_runs.csv", "msd_step_accuracy.md", "msd_step_wp_time.png",
                            "msd_step_wp_rhs.png", "msd_step_jacobian.png"])
    for f in files:
        assert f.stat().st_size > 0
    assert (tmp_path / "msd_step_wp_time.png").read_bytes()[:4] == b"\x89PNG"
    rows = list(csv.DictReader((tmp_path / "msd_step_runs.csv").open()))
    assert {r["kind"] for r in rows} == {"reference", "study", "jacobian"}
    assert len([r for r in rows if r["kind"] == "study"]) == 2 * len(TOLS)
    assert "err_abs_position" in rows[0]
    study = [r for r in rows if r["kind"] == "study"]
    assert [int(r["nsteps"]) for r in study] == [r.nsteps for r in small_study.runs]
    assert all(int(r["nsteps"]) > 0 for r in rows)
    md = (tmp_path / "msd_step_accuracy.md").read_text()
    assert "Reference agreement" in md and "| Radau | 1e-05 |" in md
    assert "atol = rtol x 0.001" in md
    assert "| wall [s] | steps | rhs | Jac |" in md  # cheapest-run table
    assert "| wall [s] (runs) | steps | rhs | Jac | LU |" in md  # all runs


def test_markdown_rows_keep_their_columns(small_study, tmp_path):
    """A failure message that quotes |eigenvalue| (as StiffnessError's do) and spans lines
    stays in its cell: every row of the all-runs table has the header's column count."""
    import re

    bad = replace(small_study.runs[0], status="failed", method="RK45",
                  message="stiff: the largest |eigenvalue| is 9e4 1/s,\nh*|lambda| <= 3.31")
    st = replace(small_study, runs=list(small_study.runs) + [bad])
    A.write_all(st, tmp_path)
    md = (tmp_path / "msd_step_accuracy.md").read_text()
    table = md[md.index("## All runs"):].split("\n\n")[1].splitlines()
    pipes = [len(re.findall(r"(?<!\\)\|", row)) for row in table]
    assert len(table) == 2 + len(st.runs) and len(set(pipes)) == 1, pipes
    assert "largest \\|eigenvalue\\| is 9e4 1/s, h*\\|lambda\\|" in md


def test_parse_options():
    assert A.parse_tols("1e-3:1e-5") == (1e-3, 1e-4, 1e-5)
    assert A.parse_tols("1e-2,1e-6") == (1e-2, 1e-6)
    with pytest.raises(ModelError):
        A.parse_tols("2")
    with pytest.raises(ModelError):
        A.parse_methods("Radau,Euler")
    # bgc's Rodas4 is studied by default; it has no finite-difference Jacobian variant
    assert "Rodas4" in A.METHODS and "Rodas4" in A.IMPLICIT
    with pytest.raises(ModelError, match="Rodas4"):
        A.parse_methods("Radau,Rodas4", A.FD_JACOBIAN)


def test_param_sweep_on_the_spring(setup):
    def metrics(s, p, res):
        return {"peak": float(np.max(res.y["position"]))}

    pts = A.param_sweep(setup, "k", [100.0, 400.0], metrics, rtol=1e-6, atol=1e-9,
                        budget=30.0)
    assert [p.status for p in pts] == ["ok", "ok"]
    # a stiffer spring deflects less (static deflection F0 / k)
    assert pts[1].metrics["peak"] < pts[0].metrics["peak"]


def test_cli_command(tmp_path):
    group = click.Group()
    register_accuracy(group)
    out = tmp_path / "acc"
    r = CliRunner().invoke(group, ["accuracy", str(SCENE), "--out", str(out), "--methods",
                                   "RK45,Radau", "--tols", "1e-3:1e-5", "--repeats", "1",
                                   "--ref-rtol", "1e-10", "--breakpoints", "1",
                                   "--jac-methods", "Radau", "--jac-tols", "1e-4"])
    assert r.exit_code == 0, (r.output, r.exception)
    assert "reference agreement" in r.output
    assert (out / "msd_step_accuracy.md").is_file()
    assert (out / "msd_step_wp_rhs.png").is_file()


def test_cli_user_errors_are_model_errors(tmp_path):
    group = click.Group()
    register_accuracy(group)
    r = CliRunner().invoke(group, ["accuracy", str(SCENE), "--methods", "Euler"])
    assert isinstance(r.exception, ModelError)


def test_the_input_jump_is_a_breakpoint_without_being_told():
    """msd_step's force is where(t < 1, 0, F0) and the scene names no breakpoint: the study
    finds the jump in the expression (before, its reference at rtol 1e-12 failed at t = 1)."""
    su = A.prepare(SCENE)
    assert su.breakpoints == (1.0,)


def test_default_references_choose_the_backend():
    assert A.default_references(False, True) == (("C-Radau", "C-DOP853"), "")
    assert A.default_references(True, True) == (("C-Radau", "C-Rodas4"), "")
    ms, note = A.default_references(True, False)
    assert ms == ("Radau", "BDF") and "no C compiler" in note and "numpy" in note
    ms, note = A.default_references(False, False)
    assert ms == ("Radau", "DOP853") and note


def test_without_a_compiler_the_references_run_on_numpy_with_a_note(setup, monkeypatch):
    monkeypatch.setattr(A, "c_available", lambda: False)
    st = A.study(setup, methods=("DOP853",), tols=(1e-3,), repeats=1, ref_rtol=1e-9,
                 jac_methods=())
    assert [r.method for r in st.refs] == ["Radau", "DOP853"]
    assert "no C compiler" in st.settings["ref_note"]
    assert any("no C compiler" in line for line in A.skipped_lines(st))


def _fake_runs(monkeypatch, small_study, wall):
    """measure replaced by runs that each take `wall` seconds (as reported), and the
    reference by the small study's."""
    calls = []

    def fake_measure(setup_, ref, method, rtol, **kw):
        calls.append((method, rtol, kw.get("jac_mode")))
        return A.Run(method, rtol, rtol, "none", "ok", wall=wall, walls=(wall,), err=rtol,
                     err_output="position", err_abs={"position": rtol})

    monkeypatch.setattr(A, "measure", fake_measure)
    monkeypatch.setattr(A, "reference", lambda s, m, *a: small_study.refs[0])
    return calls


def test_a_sweep_past_its_budget_stops_and_the_summary_says_so(setup, small_study,
                                                               monkeypatch, tmp_path):
    calls = _fake_runs(monkeypatch, small_study, 4.0)
    st = A.study(setup, methods=("RK45", "DOP853"), tols=(1e-3, 1e-4, 1e-5, 1e-6),
                 jac_methods=(), sweep_budget=10.0, ref_methods=("Radau", "Radau"))
    # 4 s a run: after three runs (12 s) each sweep is past its 10 s budget
    assert calls == [(m, t, "analytic") for m in ("RK45", "DOP853")
                     for t in (1e-3, 1e-4, 1e-5)]
    assert [r.status for r in st.runs] == ["ok", "ok", "ok", "skipped"] * 2
    lines = A.skipped_lines(st)
    assert len(lines) == 2
    assert lines[0].startswith("RK45: rtol 1e-06 skipped:") and "10 s budget" in lines[0]
    A.write_all(st, tmp_path)
    md = (tmp_path / "msd_step_accuracy.md").read_text()
    assert "## What was skipped, and why" in md and "DOP853: rtol 1e-06 skipped" in md


def test_the_study_budget_skips_what_is_left(setup, small_study, monkeypatch):
    import time

    def slow_measure(setup_, ref, method, rtol, **kw):
        time.sleep(0.3)
        return A.Run(method, rtol, rtol, "none", "ok", wall=0.3, walls=(0.3,), err=rtol)

    monkeypatch.setattr(A, "measure", slow_measure)
    monkeypatch.setattr(A, "reference", lambda s, m, *a: small_study.refs[0])
    st = A.study(setup, methods=("RK45", "DOP853"), tols=(1e-3, 1e-4), jac_methods=(),
                 study_budget=0.5, sweep_budget=100.0, ref_methods=("Radau", "Radau"))
    assert [r.status for r in st.runs][:2] == ["ok", "ok"]
    assert [r.status for r in st.runs][2:] == ["skipped", "skipped"]
    assert any(line.startswith("DOP853: rtol 1e-03 to 1e-04 (2 runs) skipped: the study's "
                               "0.5 s budget") for line in A.skipped_lines(st))


def test_long_runs_are_not_repeated(setup, small_study):
    r = A.measure(setup, small_study.refs[0], "Radau", 1e-4, repeats=3, long_run=0.0)
    assert r.status == "ok" and len(r.walls) == 1
    r = A.measure(setup, small_study.refs[0], "Radau", 1e-4, repeats=3)
    assert len(r.walls) == 3


def test_cli_default_study_of_msd_step_runs(tmp_path):
    """The command --help shows, without --breakpoints, on short settings."""
    group = click.Group()
    register_accuracy(group)
    out = tmp_path / "acc"
    r = CliRunner().invoke(group, ["accuracy", str(SCENE), "--out", str(out), "--methods",
                                   "DOP853,Radau", "--tols", "1e-3:1e-4", "--repeats", "1",
                                   "--jac-methods", "", "--study-budget", "60"])
    assert r.exit_code == 0, (r.output, r.exception)
    assert "reference agreement" in r.output
    assert (out / "msd_step_accuracy.md").is_file()


def test_an_explicit_method_that_fails_on_a_stiff_scene_stops(setup, small_study,
                                                              monkeypatch):
    calls = []

    def failing(setup_, ref, method, rtol, **kw):
        calls.append((method, rtol))
        return A.Run(method, rtol, rtol, "none", "failed", "StiffnessError: stiff")

    monkeypatch.setattr(A, "measure", failing)
    monkeypatch.setattr(A, "reference", lambda s, m, *a: small_study.refs[0])
    monkeypatch.setattr(A, "is_stiff", lambda s: (True, 1e6))
    st = A.study(setup, methods=("RK45", "Radau"), tols=(1e-3, 1e-4, 1e-5), jac_methods=(),
                 ref_methods=("Radau", "Radau"))
    # the explicit method stops after its loosest tolerance; the implicit one goes on
    assert calls == [("RK45", 1e-3), ("Radau", 1e-3), ("Radau", 1e-4), ("Radau", 1e-5)]
    assert any(line.startswith("RK45: rtol 1e-04 to 1e-05 (2 runs) skipped: an explicit "
                               "method on a stiff scene") for line in A.skipped_lines(st))
