"""Sweeps: the scene's sweep: section (samples and located errors), and bgc sweep on a real
local Dask cluster (two worker processes): samples equal single runs, failures are recorded,
interrupted sweeps resume, stores of another sweep are refused."""
from __future__ import annotations

import dataclasses
import math
import textwrap
from pathlib import Path

import numpy as np
import pytest
from conftest import bgc_in_process, seed_c_runtime

from bgc.base.errors import ModelError

pytest.importorskip("distributed")
pytest.importorskip("xarray")
pytest.importorskip("zarr")

from bgc.backends.c import build as cbuild
from bgc.studies import sweep  # noqa: E402

MODELS = Path(__file__).resolve().parents[1] / "models"
MSD = MODELS / "msd.yaml"


def _scene(tmp_path, sweep_text, name="s", params="", extra=""):
    text = textwrap.dedent(f"""\
        bgc_scene: 1
        model: {MSD}
        duration: 2.0
        inputs: {{F: "where(t < 0.5, 0, F0)"}}
        breakpoints: [0.5]
        outputs: [position, velocity]
        solver: {{method: Radau, rtol: 1.0e-7, atol: 1.0e-10, dt: 0.02}}
        {params}
        {extra}
        """) + sweep_text
    p = tmp_path / f"{name}.yaml"
    p.write_text(text)
    return p


# ---------------------------------------------------------------------------------------------
# the sweep: section


def test_grids_lists_and_log_ranges_crossed_in_order(tmp_path):
    p = _scene(tmp_path, textwrap.dedent("""\
        sweep:
          parameters:
            m: {linspace: [1, 3, 3]}
            k: {logspace: [10, 1000, 3]}
            c: {values: [0.5, 7]}
        """))
    s = sweep.samples(sweep.parse_sweep(p))
    assert list(s) == ["m", "k", "c"]
    assert len(s["m"]) == 18
    # every combination exactly once, the first entry varying slowest
    combos = set(zip(s["m"], s["k"], s["c"]))
    assert combos == {(m, k, c) for m in (1.0, 2.0, 3.0) for k in (10.0, 100.0, 1000.0)
                      for c in (0.5, 7.0)}
    assert list(s["m"][:6]) == [1.0] * 6 and list(s["c"][:2]) == [0.5, 7.0]
    np.testing.assert_allclose(np.unique(s["k"]), [10.0, 100.0, 1000.0], rtol=1e-14)


def test_zip_pairs_and_rejects_unequal_lengths(tmp_path):
    p = _scene(tmp_path, "sweep:\n  combine: zip\n  parameters:\n"
                         "    m: {values: [1, 2, 3]}\n    k: {linspace: [100, 300, 3]}\n")
    s = sweep.samples(sweep.parse_sweep(p))
    assert list(zip(s["m"], s["k"])) == [(1, 100), (2, 200), (3, 300)]
    p = _scene(tmp_path, "sweep:\n  combine: zip\n  parameters:\n"
                         "    m: {values: [1, 2, 3]}\n    k: {linspace: [100, 300, 4]}\n")
    with pytest.raises(ModelError, match="zip: the axes differ in length"):
        sweep.parse_sweep(p)


def test_latin_hypercube_puts_one_sample_in_each_stratum(tmp_path):
    from scipy.stats import norm

    n = 50
    p = _scene(tmp_path, textwrap.dedent(f"""\
        sweep:
          parameters:
            m: {{uniform: [1, 3]}}
            k: {{loguniform: [10, 1000]}}
            c: {{normal: [4, 0.5]}}
          samples: {n}
          method: lhs
          seed: 7
        """))
    spec = sweep.parse_sweep(p)
    s = sweep.samples(spec)
    # back to the unit interval through each distribution's own CDF (scipy.stats)
    u = {"m": (s["m"] - 1) / 2, "k": np.log(s["k"] / 10) / np.log(100),
         "c": norm.cdf(s["c"], loc=4, scale=0.5)}
    for name, v in u.items():
        strata = np.floor(v * n).astype(int)
        assert sorted(strata) == list(range(n)), name  # each of the n strata exactly once
    # seeded: the same samples again, other samples with another seed
    assert np.array_equal(sweep.samples(spec)["m"], s["m"])
    o = tmp_path / "o.yaml"
    o.write_text(p.read_text().replace("seed: 7", "seed: 8"))
    other = sweep.samples(sweep.parse_sweep(o))
    assert not np.array_equal(other["m"], s["m"])
    # plain random draws: uniform on [1, 3), mean near 2 (n = 2000: 5 sigma = 0.065)
    p2 = _scene(tmp_path, "sweep:\n  parameters:\n    m: {uniform: [1, 3]}\n  samples: 2000\n"
                          "  method: random\n", name="r")
    r = sweep.samples(sweep.parse_sweep(p2))["m"]
    assert r.min() >= 1 and r.max() < 3 and abs(r.mean() - 2) < 0.065


def test_random_block_crossed_with_a_grid(tmp_path):
    p = _scene(tmp_path, "sweep:\n  parameters:\n    m: {values: [1, 2]}\n"
                         "    k: {uniform: [100, 200]}\n  samples: 5\n")
    s = sweep.samples(sweep.parse_sweep(p))
    assert len(s["m"]) == 10
    assert np.array_equal(s["k"][:5], s["k"][5:])  # the same 5 samples for each m


@pytest.mark.parametrize("body, where, msg", [  # where: (line, text the column points at)
    ("    m: {linspace: [1, 2]}\n", (12, "[1, 2]"), "linspace is [start, stop, count]"),
    ("    m: {logspace: [0, 2, 3]}\n", (12, "[0, 2"), "positive start and stop"),
    ("    m: {uniform: [3, 1]}\n  samples: 4\n", (12, "[3, 1]"), "needs low < high"),
    ("    m: {normal: [1, 0]}\n  samples: 4\n", (12, "[1, 0]"), "sigma must be positive"),
    ("    m: {uniform: [1, 3]}\n", (12, "m:"), "give the number of samples"),
    ("    m: {values: [1, 2]}\n  samples: 4\n", (13, "4"), "no entry is random"),
    ("    m: {values: []}\n", (12, "[]"), "empty list"),
    ("    m: {between: [1, 2]}\n", (12, "between"), "unknown rule 'between'"),
    ("    m: {values: [1, 2], linspace: [1, 2, 3]}\n", (12, "{"), "exactly one of"),
    ("    m: {linspace: [1, 2, 2000]}\n    k: {linspace: [1, 2, 2000]}\n", (10, "sweep"),
     "4000000 samples, more than the limit 1000000"),
    ("    m: {linspace: [1, 2, 1.5]}\n", (12, "1.5"), "whole number"),
    ("  combine: both\n    m: {values: [1]}\n", (11, "both"), "combine 'both'"),
])
def test_bad_sweeps_are_located_errors(tmp_path, body, where, msg):
    p = _scene(tmp_path, "sweep:\n  parameters:\n" + body)
    if "combine" in body:
        p.write_text(p.read_text().replace("  parameters:\n  combine: both\n",
                                           "  combine: both\n  parameters:\n"))
    line, marker = where
    col = p.read_text().splitlines()[line - 1].index(marker) + 1
    with pytest.raises(ModelError) as ei:
        sweep.parse_sweep(p)
    assert msg in ei.value.message
    assert (ei.value.coord.line, ei.value.coord.column) == (line, col), str(ei.value)


def test_unknown_parameter_and_state_are_located(tmp_path):
    p = _scene(tmp_path, "sweep:\n  parameters:\n    mass: {values: [1, 2]}\n")
    with pytest.raises(ModelError, match="no parameter 'mass'") as ei:
        sweep.prepare(p)
    assert (ei.value.coord.line, ei.value.coord.column) == (12, 5)
    p = _scene(tmp_path, "sweep:\n  initial:\n    spring.x: {values: [1, 2]}\n")
    with pytest.raises(ModelError, match="no state 'spring.x'") as ei:
        sweep.prepare(p)
    assert ei.value.coord.line == 12


def test_a_scene_value_of_a_swept_parameter_stays_a_parameter(tmp_path):
    # the scene sets m (normally folded into the module); the sweep needs it as a parameter
    p = _scene(tmp_path, "sweep:\n  parameters:\n    m: {values: [1, 2]}\n",
               params="parameters: {m: 5.0, k: 300.0}")
    prep = sweep.prepare(p)
    mod = sweep.load(prep)
    assert "m" in mod.PARAM_DEFAULTS and "k" not in mod.PARAM_DEFAULTS  # k folded, m free


def _step(t, m, k):
    """The closed-form position of the scene's step response (c = 4 N s/m, F0 = 10 N from
    0.5 s, underdamped)."""
    tau, wn = np.clip(t - 0.5, 0, None), math.sqrt(k / m)
    z = 4.0 / (2 * math.sqrt(k * m))
    wd = wn * math.sqrt(1 - z * z)
    return 10.0 / k * (1 - np.exp(-z * wn * tau) * (np.cos(wd * tau)
                                                    + z * wn / wd * np.sin(wd * tau)))


def _need(backend):
    if backend == "c" and not cbuild.available():
        pytest.skip("no C compiler")


# ---------------------------------------------------------------------------------------------
# the backend


def test_without_a_compiler_the_sweep_says_so_and_runs_numpy(tmp_path, monkeypatch):
    p = _scene(tmp_path, "sweep:\n  parameters:\n    m: {values: [1.0, 2.0]}\n")
    with_c = sweep.prepare(p) if cbuild.available() else None
    monkeypatch.setenv("CC", "/nonexistent/cc")
    for asked in (None, "c"):
        said = []
        prep = sweep.prepare(p, said.append, backend=asked)
        assert prep.backend == "numpy" and prep.c_files == {} and not prep.c_wrapper
        assert any("no C compiler" in m and "/nonexistent/cc" in m
                   and "using the numpy backend" in m for m in said), said
    # it runs (in this process): the closed-form step response (k = 200 N/m)
    res = sweep.run_chunk(prep, 0, 2)
    assert (res["status"] == 0).all()
    t = np.linspace(0.0, 2.0, 101)
    for j, m in enumerate((1.0, 2.0)):
        assert np.max(np.abs(res["y"]["position"][j] - _step(t, m, 200.0))) < 1e-5 * 10 / 200
    if with_c is not None:
        assert with_c.backend == "c"
        # the results depend on the backend: a store of one is refused for the other
        out = tmp_path / "r.zarr"
        sweep.open_or_create(with_c, out, 2)
        with pytest.raises(sweep.SweepMismatch):
            sweep.open_or_create(prep, out, 2)
        assert sweep.open_results(out).attrs["backend"] == "c"


def test_a_process_without_the_library_builds_it_from_the_shipped_sources(tmp_path,
                                                                         monkeypatch):
    """What a worker on another machine does: an empty compile cache, the texts only."""
    import pickle

    from bgc.backends.skeleton import SkeletonError

    _need("c")
    p = _scene(tmp_path, "sweep:\n  parameters:\n    m: {values: [1.0, 2.0]}\n")
    prep = pickle.loads(pickle.dumps(sweep.prepare(p)))  # as Dask ships it
    here = sweep.run_chunk(prep, 0, 2)
    cache = seed_c_runtime(tmp_path / "other-cache")  # (the runtime's objects built)
    monkeypatch.setenv("BGC_CACHE_DIR", str(cache))
    monkeypatch.setattr(sweep, "_MODULES", {})
    there = sweep.run_chunk(prep, 0, 2)
    assert len(list((cache / "c").glob("*/*/libmodel.so"))) == 1  # built there, kept
    for o in here["y"]:
        assert np.array_equal(here["y"][o], there["y"][o])
    # a wrapper that is not the template's is refused before anything is built or run
    monkeypatch.setattr(sweep, "_MODULES", {})
    bad = dataclasses.replace(prep, c_wrapper=prep.c_wrapper.replace(
        "def _autobind():", "import os\ndef _autobind():"))
    assert bad.c_wrapper != prep.c_wrapper
    with pytest.raises(SkeletonError):
        sweep.load(bad)
    assert len(list((cache / "c").glob("*/*"))) == 1


def test_a_model_with_table_inputs_is_swept_in_c_like_numpy(tmp_path):
    # table inputs are printed in C (bgc_tables.c): the sweep runs C, and its samples agree
    # with the numpy backend's over the same instances
    _need("c")
    src = MODELS / "scenes" / "quarter_car_bump.yaml"
    text = src.read_text().replace("../quarter_car.yaml", str(MODELS / "quarter_car.yaml"))
    # the table beside the scene (table files are relative to the scene)
    (tmp_path / "road_bump.csv").write_bytes((MODELS / "scenes" / "road_bump.csv").read_bytes())
    p = tmp_path / "qc.yaml"
    p.write_text(text.split("plots:")[0] + "sweep:\n  parameters:\n"
                                           "    c_s: {values: [800.0, 1200.0]}\n")
    said = []
    prep = sweep.prepare(p, said.append, backend="c")
    assert prep.backend == "c" and prep.c_files
    ref = sweep.prepare(p, said.append, backend="numpy")
    idx = np.arange(2)
    tc, yc, _ = sweep._call(sweep.load(prep), prep, idx)
    tn, yn, _ = sweep._call(sweep.load(ref), ref, idx)
    np.testing.assert_array_equal(tc, tn)
    for o in prep.outputs:
        scale = np.max(np.abs(yn[o])) + 1e-12
        np.testing.assert_allclose(yc[o], yn[o], atol=1e-3 * scale, rtol=0)
    # the two instances differ (the swept damping reaches the outputs)
    o = prep.outputs[0]
    assert not np.allclose(yc[o][0], yc[o][1])


def test_the_scene_solver_backend_chooses_unless_the_command_does(tmp_path):
    _need("c")
    p = _scene(tmp_path, "sweep:\n  parameters:\n    m: {values: [1.0, 2.0]}\n")
    p.write_text(p.read_text().replace("dt: 0.02}", "dt: 0.02, backend: numpy}"))
    said = []
    prep = sweep.prepare(p, said.append)
    assert prep.backend == "numpy" and not any("numpy backend" in m for m in said)
    assert sweep.prepare(p, backend="c").backend == "c"
    assert sweep.solver_backend(p) == "numpy"


def test_c_tasks_share_the_cores_of_their_host(client):
    import os

    slots = sweep.host_slots(client)
    assert sum(slots.values()) == 2  # the fixture's two one-thread workers
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    got = client.submit(sweep.task_threads, slots, pure=False).result()
    assert got == max(1, cpus // 2)
    # a host the client did not see: one thread; outside a worker: the C default (None)
    assert client.submit(sweep.task_threads, {}, pure=False).result() == 1
    assert sweep.task_threads(slots) is None


@pytest.mark.slow
def test_c_sweep_samples_equal_single_c_runs(tmp_path, client):
    """Each C sample is the same run as the scene alone with the C backend (each instance of a
    C batch takes its own steps), to the last bit; it agrees with the numpy backend's run
    within the tolerance and with the closed-form step response."""
    from bgc.run.runner import run_scene

    _need("c")
    mk = [(1.0, 100.0), (2.5, 400.0), (0.7, 250.0)]
    p = _scene(tmp_path, "sweep:\n  combine: zip\n  parameters:\n"
                         f"    m: {{values: {[m for m, _ in mk]}}}\n"
                         f"    k: {{values: {[k for _, k in mk]}}}\n")
    prep = sweep.prepare(p)
    assert prep.backend == "c" and "model.c" in prep.c_files
    out = tmp_path / "r.zarr"
    rep = sweep.run_sweep(prep, out, client, chunk=2, quiet=True)
    assert (rep.chunks, rep.computed, rep.failed) == (2, 2, 0)
    ds = sweep.open_results(out).load()
    assert ds.attrs["backend"] == "c"
    nsteps = []
    for s, (m, k) in enumerate(mk):
        # the scene alone, m and k kept as run-time parameters (free) as the sweep keeps them
        alone = _scene(tmp_path, "", name=f"alone{s}",
                       params=f"parameters: {{m: {m!r}, k: {k!r}}}", extra="free: [m, k]")
        ref = run_scene(alone, backend="c")
        ref_np = run_scene(alone, backend="numpy")
        assert (ref.backend, ref_np.backend) == ("c", "numpy")
        nsteps.append(ref.stats["nsteps"])
        for o in ("position", "velocity"):
            assert np.array_equal(ds[o].values[s], ref.y[o]), (s, o)
            b = ref_np.y[o]
            assert np.max(np.abs(ds[o].values[s] - b)) <= 1e-5 * np.max(np.abs(b)), (s, o)
        x = _step(ds["time"].values, m, k)
        assert np.max(np.abs(ds["position"].values[s] - x)) < 1e-5 * 10.0 / k
    # a chunk's statistics are its instances' together: their own step counts, summed
    assert list(ds["nsteps"].values) == [nsteps[0] + nsteps[1]] * 2 + [nsteps[2]]


# ---------------------------------------------------------------------------------------------
# on a real local cluster


@pytest.fixture(scope="module")
def client():
    c = sweep.client_for("local", 2)
    assert len(c.scheduler_info()["workers"]) == 2
    yield c
    sweep.close_client(c)


def test_local_workers_drop_only_a_closing_workers_broken_connection(client):
    """The CI failure of 6371dfb: a worker's heartbeat, in flight while that worker closed its
    own connections, printed distributed's traceback at the end of `bgc sweep`. Each worker of
    bgc's local cluster carries the filter; it drops that record while the worker closes and
    keeps every record of a running worker."""
    import logging

    from distributed.comm.core import CommClosedError
    from distributed.core import Status

    from bgc.studies.quiet_close import ClosingCommFilter

    names = client.run(lambda: [type(f).__name__
                                for f in logging.getLogger("distributed.worker").filters])
    assert len(names) == 2 and all("ClosingCommFilter" in v for v in names.values()), names

    class W:
        status = Status.running

    def record(exc):
        try:
            raise exc
        except Exception:
            import sys
            info = sys.exc_info()
        return logging.LogRecord("distributed.worker", logging.ERROR, __file__, 1,
                                 "Failed to communicate with scheduler during heartbeat.",
                                 None, info)

    w = W()
    f = ClosingCommFilter(w)
    broken = record(CommClosedError("in <TCP (closed) ConnectionPool.heartbeat_worker>"))
    assert f.filter(broken)  # running: a broken connection is news
    for s in (Status.closing, Status.closed, Status.closing_gracefully):
        w.status = s
        assert not f.filter(broken), s
        assert f.filter(record(ValueError("a real error")))  # only broken connections go
        plain = logging.LogRecord("distributed.worker", logging.INFO, __file__, 1, "x", None,
                                  None)
        assert f.filter(plain)


_ALONE: dict = {}


def _alone(tmp_path, m, k, tag):
    """The same scene with the sample's values, run alone by bgc simulate's runner (numpy, the
    scenes' backend); run once per (m, k) in a worker: both backends' sweeps of the test below
    sample the same (m, k) and compare with the same runs."""
    from bgc.run.runner import run_scene

    if (m, k) not in _ALONE:
        p = _scene(tmp_path, "", name=f"alone_{tag}",
                   params=f"parameters: {{m: {m!r}, k: {k!r}}}")
        _ALONE[m, k] = run_scene(p)
    return _ALONE[m, k]


@pytest.mark.slow
@pytest.mark.parametrize("backend", ["c", "numpy"])
def test_sweep_samples_equal_single_runs_and_failures_are_recorded(tmp_path, client, backend):
    # m = 0 divides by zero: that instance fails; the rest of its batch still finishes
    p = _scene(tmp_path, "sweep:\n  parameters:\n    m: {values: [1.0, 0.0, 2.5]}\n"
                         "    k: {values: [100.0, 400.0]}\n")
    _need(backend)
    prep = sweep.prepare(p, backend=backend)
    assert prep.backend == backend
    out = tmp_path / "r.zarr"
    rep = sweep.run_sweep(prep, out, client, chunk=4, quiet=True)
    assert (rep.chunks, rep.computed, rep.skipped) == (2, 2, 0)
    ds = sweep.open_results(out).load()
    assert ds.sizes["sample"] == 6 and ds["position"].dims == ("sample", "time")
    assert ds["time"].attrs["units"] == "s" and ds["m"].attrs["units"] == "kg"
    failed = ds["status"].values != 0
    assert list(np.nonzero(failed)[0]) == [2, 3]  # m = 0 with both k
    assert rep.failed == 2
    for s in (2, 3):
        assert ds["message"].values[s]  # the solver's message is kept
        assert np.all(np.isnan(ds["position"].values[s]))
    assert set(ds["batch"].values[:4]) == {1}  # chunk 0 failed as a batch: run one by one
    assert set(ds["batch"].values[4:]) == {2}
    for s in np.nonzero(~failed)[0]:
        m, k = float(ds["m"][s]), float(ds["k"][s])
        ref = _alone(tmp_path, m, k, s)
        for o in ("position", "velocity"):
            a, b = ds[o].values[s], ref.y[o]
            assert np.max(np.abs(a - b)) <= 1e-5 * np.max(np.abs(b)), (s, o)
        assert ds["nsteps"].values[s] > 0
        # and the physics: the closed-form step response (c = 4 N s/m, F0 = 10 N at 0.5 s)
        t = ds["time"].values
        tau, wn = np.clip(t - 0.5, 0, None), math.sqrt(k / m)
        z = 4.0 / (2 * math.sqrt(k * m))
        wd = wn * math.sqrt(1 - z * z)
        x = 10.0 / k * (1 - np.exp(-z * wn * tau) * (np.cos(wd * tau)
                                                     + z * wn / wd * np.sin(wd * tau)))
        assert np.max(np.abs(ds["position"].values[s] - x)) < 1e-5 * 10.0 / k


class _Stop(Exception):
    pass


@pytest.mark.slow
@pytest.mark.parametrize("backend", ["c", "numpy"])
def test_an_interrupted_sweep_resumes_with_the_missing_chunks_only(tmp_path, client, backend):
    p = _scene(tmp_path, "sweep:\n  parameters:\n    m: {linspace: [1, 2, 4]}\n"
                         "    k: {values: [100.0, 200.0]}\n")
    _need(backend)
    prep = sweep.prepare(p, backend=backend)
    assert prep.backend == backend
    out = tmp_path / "r.zarr"
    seen = []

    def stop_after_two(k):
        seen.append(k)
        if len(seen) == 2:
            raise _Stop

    with pytest.raises(_Stop):
        sweep.run_sweep(prep, out, client, chunk=2, quiet=True, after_chunk=stop_after_two)
    first = sweep.open_results(out).load()
    assert first["chunk_done"].values.sum() == 2
    walls = first["chunk_wall"].values.copy()
    again = []
    rep = sweep.run_sweep(prep, out, client, chunk=2, quiet=True, after_chunk=again.append)
    assert (rep.chunks, rep.skipped, rep.computed) == (4, 2, 2)
    assert sorted(again) == sorted(set(range(4)) - set(seen))  # only the missing chunks ran
    ds = sweep.open_results(out).load()
    assert ds["chunk_done"].values.all() and (ds["status"].values == 0).all()
    for k in seen:  # the finished chunks were not rewritten
        assert np.array_equal(ds["chunk_wall"].values[2 * k:2 * k + 2], walls[2 * k:2 * k + 2])
    assert ds.attrs["backend"] == backend
    # a third run has nothing to do
    assert sweep.run_sweep(prep, out, client, chunk=2, quiet=True).computed == 0
    if cbuild.available():  # the same sweep on the other backend: other results, refused
        other = sweep.prepare(p, backend="numpy" if backend == "c" else "c")
        with pytest.raises(sweep.SweepMismatch, match="another sweep"):
            sweep.run_sweep(other, out, client, chunk=2, quiet=True)
    # another sweep (or chunking) into the same store is refused, with --restart it starts over
    with pytest.raises(sweep.SweepMismatch, match="another sweep"):
        sweep.run_sweep(prep, out, client, chunk=3, quiet=True)
    p2 = _scene(tmp_path, "sweep:\n  parameters:\n    m: {linspace: [1, 2, 5]}\n", name="s2")
    prep2 = sweep.prepare(p2)
    with pytest.raises(sweep.SweepMismatch):
        sweep.run_sweep(prep2, out, client, chunk=2, quiet=True)
    rep = sweep.run_sweep(prep2, out, client, chunk=2, quiet=True, restart=True)
    assert rep.computed == 3 and sweep.open_results(out).sizes["sample"] == 5


@pytest.mark.slow
def test_cli_on_a_running_scheduler_with_initial_states_and_plots(tmp_path, client,
                                                                   monkeypatch):
    from click.testing import CliRunner

    from bgc.cli.commands import main

    p = _scene(tmp_path, textwrap.dedent("""\
        sweep:
          parameters:
            k: {values: [100.0, 400.0]}
          initial:
            spring.q: {values: [0.0, 0.05]}
          plot: {outputs: [position], stat: final, units: {position: m}}
        """))
    out, figs = tmp_path / "r.zarr", tmp_path / "figs"
    addr = client.scheduler.address
    res = CliRunner().invoke(main, ["sweep", str(p), "--out", str(out), "--scheduler", addr,
                                    "--chunk", "3", "--plot", str(figs), "--backend", "numpy"])
    assert res.exit_code == 0, res.output
    assert "4 instances, 2 chunks (2 computed" in res.output and "numpy backend" in res.output
    ds = sweep.open_results(out).load()
    assert list(ds["x0_spring.q"].values) == [0.0, 0.05, 0.0, 0.05]
    np.testing.assert_allclose(ds["position"].values[:, 0], ds["x0_spring.q"].values)
    # undamped start from x0 = 0.05: the mass moves towards the spring's rest first
    assert ds["position"].values[1, 1] < 0.05
    assert (figs / "s_sweep_position.png").stat().st_size > 10_000
    # the same store for another sweep: a one-line error, exit 2
    p.write_text(p.read_text().replace("400.0", "500.0"))
    res = CliRunner().invoke(main, ["sweep", str(p), "--out", str(out), "--scheduler", addr])
    assert res.exit_code == 2 and "another sweep" in res.output and "Traceback" not in res.output


# ---------------------------------------------------------------------------------------------
# bgc accuracy on the same engine


@pytest.mark.slow
def test_accuracy_with_two_workers_gives_the_results_of_one(tmp_path, client, monkeypatch):
    """In this process (`python -m bgc`'s front door, conftest's bgc_in_process): the
    property is the study's rows, not the process. One worker on a cluster of its own
    (--workers 1: the command starts and closes it), two on the module's running cluster
    (--scheduler: its two one-thread workers, as --workers 2 makes them; starting a second
    cluster of processes is most of a run's time). The serial run draws the figures; the runs
    on workers leave them out (three work-precision plots that no assertion reads)."""
    import csv

    from bgc.studies import accuracy_report

    scene = str(MODELS / "scenes" / "pendulum_swing.yaml")
    assert len(client.scheduler_info()["workers"]) == 2
    on = {0: (), 1: ("--workers", "1"), 2: ("--scheduler", client.scheduler.address)}
    rows = {}
    for w in (0, 1, 2):  # 0: today's serial study, no Dask
        out = tmp_path / f"w{w}"
        if w:
            monkeypatch.setattr(accuracy_report, "plot_study", lambda *a, **k: [])
        r = bgc_in_process("accuracy", scene, "--out", str(out), "--methods", "RK45,Radau",
                           "--tols", "1e-3:1e-5", "--jac-methods", "Radau", "--jac-tols",
                           "1e-4", "--repeats", "1", "--t-end", "3", "--ref-rtol", "1e-10",
                           "-q", *on[w])
        assert r.returncode == 0, r.stderr[-2000:]
        assert (out / "pendulum_swing_wp_time.png").is_file() == (w == 0)
        with open(out / "pendulum_swing_runs.csv") as f:
            rows[w] = list(csv.DictReader(f))
    assert len(rows[1]) == len(rows[2]) == 2 + 2 * 3 + 3  # refs, study grid, Jacobian modes
    timing = {"wall_s", "walls_s", "n_repeats"}
    for a, b, c in zip(rows[1], rows[2], rows[0]):
        assert a["status"] == "ok", a
        # everything but the wall times is the same: counts exactly, errors to the digit
        assert {k: v for k, v in a.items() if k not in timing} == \
            {k: v for k, v in b.items() if k not in timing} == \
            {k: v for k, v in c.items() if k not in timing}
    # and the study is a study: Radau's error falls as its tolerance tightens
    radau = [float(r["err"]) for r in rows[2] if r["kind"] == "study" and r["method"] == "Radau"]
    assert radau[0] > radau[1] > radau[2]
