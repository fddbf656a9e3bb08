"""Throughput of `bgc sweep` against a serial loop of single runs, numpy and C backends side by
side in one run.

    python bench/bench_sweep.py [--workers 2] [--chunk 8] [--serial 4] [--t-end T] [--no-c]
                                [--write]

The scene is models/scenes/3r2s_circle_sweep.yaml: the 3R2S circle (95 states, Radau, rtol
1e-6) over the masses of links 2 and 3 and the rotational couplings' stiffness (16 instances).
Measured, in this order, in one process:

* serial: single runs (`simulate` with scalar parameters, one instance per call) of
  `--serial` instances spread over the sweep, one after another: instances per second;
* batch: one vectorised `simulate` call over `--chunk` instances in this process (what one
  Dask task does), so the gain of batching shows apart from the gain of workers;
* sweep: the whole sweep through `bgc.studies.sweep.run_sweep` on a new local Dask cluster of
  `--workers` processes (one thread each), chunks of `--chunk`, into a Zarr store: instances
  per second with the cluster already started (its start-up is reported apart), the workers
  compiling their module from its source text within the measured time.

Then the same with the C backend (the step loop in C, each instance of a batch with its own
step size): a serial loop of single C runs over every instance of the sweep (the numpy loop's
instances among them, so the two backends are also compared on the same instances), one C
batch of `--chunk` in this process (every CPU), and the C sweep on the same cluster (each task
one thread per core share; the workers load the library the client built into the compile
cache). The cluster's workers import bgc first (apart from the measured times), so that
neither backend's sweep pays the imports.

The serial runs' outputs are checked against the sweep's (the same instances), and the
largest difference in the joint angles is reported; the C sweep against the single C runs
(expected: identical) and against the numpy sweep (within the tolerance). --t-end T
integrates 0..T s only (a quicker run; the figures then say so). --write replaces
bench/RESULTS_sweep.md.
"""
from __future__ import annotations

import argparse
import os
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from bgc.studies import sweep  # noqa: E402

SCENE = ROOT / "models" / "scenes" / "3r2s_circle_sweep.yaml"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--chunk", type=int, default=8)
    ap.add_argument("--serial", type=int, default=4, help="single runs in the serial loop")
    ap.add_argument("--t-end", type=float, default=None,
                    help="integrate from the scene's start to T only (a quicker run)")
    ap.add_argument("--no-c", action="store_true", help="numpy rows only")
    ap.add_argument("--write", action="store_true", help="write bench/RESULTS_sweep.md")
    ap.add_argument("--accuracy", action="store_true",
                    help="also: bgc accuracy on the pendulum, serially and on --workers")
    ap.add_argument("--accuracy-only", action="store_true",
                    help="only the accuracy study's timing (prints; writes nothing)")
    a = ap.parse_args()
    acc = accuracy_walls(a.workers) if a.accuracy or a.accuracy_only else ""
    if a.accuracy_only:
        return

    t0 = time.perf_counter()
    prep = sweep.prepare(SCENE, backend="numpy")
    mod = sweep.load(prep)
    t_compile = time.perf_counter() - t0
    n = prep.n
    if a.t_end is not None:
        prep.t_span = (prep.t_span[0], a.t_end)
    print(f"compiled {SCENE.name}: {mod.N_STATES} states, {n} instances "
          f"({t_compile:.1f} s)", flush=True)
    cprep = None
    if not a.no_c:
        t0 = time.perf_counter()
        cprep = sweep.prepare(SCENE, print, backend="c")
        t_ccompile = time.perf_counter() - t0
        if cprep.backend != "c":
            print("no C backend here: numpy rows only", flush=True)
            cprep = None
        else:
            cprep.t_span = prep.t_span
            cmod = sweep.load(cprep)
            print(f"C backend: compiled and built in {t_ccompile:.1f} s", flush=True)

    # serial loop of single runs
    pick = np.unique(np.linspace(0, n - 1, a.serial).round().astype(int))
    serial_y, t_serial, nfev = {}, [], []
    for i in pick:
        t1 = time.perf_counter()
        _, out, st = sweep._call(mod, prep, np.array([i]))
        t_serial.append(time.perf_counter() - t1)
        serial_y[int(i)] = out
        nfev.append(st["nfev"])
        print(f"  single run {i}: {t_serial[-1]:.2f} s, {st['nfev']} rhs calls", flush=True)
    rate_serial = len(pick) / sum(t_serial)

    # one batch of `chunk` instances in this process
    t1 = time.perf_counter()
    _, bout, bst = sweep._call(mod, prep, np.arange(min(a.chunk, n)))
    t_batch = time.perf_counter() - t1
    rate_batch = min(a.chunk, n) / t_batch
    print(f"  one batch of {min(a.chunk, n)}: {t_batch:.2f} s, {bst['nfev']} rhs calls",
          flush=True)

    # the C backend, in this process: every instance alone, then one batch
    c_serial_y, t_cserial, cnfev = {}, [], []
    if cprep is not None:
        for i in range(n):
            t1 = time.perf_counter()
            _, out, st = sweep._call(cmod, cprep, np.array([i]))
            t_cserial.append(time.perf_counter() - t1)
            c_serial_y[i] = out
            cnfev.append(st["nfev"])
        print(f"  {n} single C runs: {sum(t_cserial):.2f} s", flush=True)
        t1 = time.perf_counter()
        _, cbout, cbst = sweep._call(cmod, cprep, np.arange(min(a.chunk, n)))
        t_cbatch = time.perf_counter() - t1
        print(f"  one C batch of {min(a.chunk, n)}: {t_cbatch:.2f} s", flush=True)

    # the sweeps on a local Dask cluster
    t1 = time.perf_counter()
    client = sweep.client_for("local", a.workers)
    client.run(_warm)  # imports, apart from the measured times
    t_cluster = time.perf_counter() - t1
    tmp = Path(tempfile.mkdtemp())
    try:
        t1 = time.perf_counter()
        rep = sweep.run_sweep(prep, tmp / "r.zarr", client, a.chunk, quiet=False)
        t_sweep = time.perf_counter() - t1
        ds = sweep.open_results(tmp / "r.zarr").load()
        if cprep is not None:
            t1 = time.perf_counter()
            crep = sweep.run_sweep(cprep, tmp / "c.zarr", client, a.chunk, quiet=False)
            t_csweep = time.perf_counter() - t1
            cds = sweep.open_results(tmp / "c.zarr").load()
    finally:
        sweep.close_client(client)
        shutil.rmtree(tmp, ignore_errors=True)
    rate_sweep = n / t_sweep
    assert (ds["status"].values == 0).all(), ds["message"].values
    angles = ("theta1", "theta2", "theta3", "theta4")
    diff = max(float(np.max(np.abs(ds[o].values[i] - serial_y[i][o][0])))
               for i in serial_y for o in angles)
    bdiff = max(float(np.max(np.abs(ds[o].values[:len(bout[o])] - bout[o])))
                for o in angles)

    rows = [
        ("numpy", "serial loop of single runs", f"{len(pick)} runs", sum(t_serial),
         rate_serial, rate_serial),
        ("numpy", f"one batch of {min(a.chunk, n)} in one process", "1 call", t_batch,
         rate_batch, rate_serial),
        ("numpy", f"bgc sweep, {a.workers} workers, chunks of {a.chunk}",
         f"{rep.chunks} tasks", t_sweep, rate_sweep, rate_serial),
    ]
    cnotes = ""
    if cprep is not None:
        assert (cds["status"].values == 0).all(), cds["message"].values
        rate_cserial = n / sum(t_cserial)
        rows += [
            ("C", "serial loop of single runs", f"{n} runs", sum(t_cserial), rate_cserial,
             rate_cserial),
            ("C", f"one batch of {min(a.chunk, n)} in one process ({os.cpu_count()} threads)",
             "1 call", t_cbatch, min(a.chunk, n) / t_cbatch, rate_cserial),
            ("C", f"bgc sweep, {a.workers} workers, chunks of {a.chunk}",
             f"{crep.chunks} tasks", t_csweep, n / t_csweep, rate_cserial),
        ]
        cdiff = max(float(np.max(np.abs(cds[o].values[i] - c_serial_y[i][o][0])))
                    for i in c_serial_y for o in angles)
        cbdiff = max(float(np.max(np.abs(cds[o].values[:len(cbout[o])] - cbout[o])))
                     for o in angles)
        xdiff = max(float(np.max(np.abs(cds[o].values - ds[o].values))) for o in angles)
        same = sum(t_cserial[i] for i in pick)
        cnotes = (f"- C sweep: its {crep.chunks} tasks took {_task_walls(cds)} s each (in the "
                  "worker: loading the library, the simulate call); the rest of its wall time "
                  "is the store's creation, Dask's scheduling and the client's chunk writes\n"
                  f"- C: the sweep's joint angles against the single C runs of the same "
                  f"instances: within {cdiff:.2e} rad; against the in-process C batch: within "
                  f"{cbdiff:.2e} rad; against the numpy sweep: within {xdiff:.2e} rad\n"
                  f"- on the numpy loop's {len(pick)} instances alone: numpy "
                  f"{sum(t_serial):.1f} s, C {same:.2f} s ({sum(t_serial) / same:.0f}x)\n"
                  f"- rhs calls (C): {np.mean(cnfev):.0f} per single run (mean); "
                  f"{cbst['nfev']} for the batch of {min(a.chunk, n)} (each instance its "
                  "own steps: about the sum of its single runs')\n")
    lines = [
        "| backend | | work | wall [s] | instances/s | vs numpy serial | vs its serial |",
        "|---|---|---|---|---|---|---|",
    ]
    for be, label, work, wall, rate, base in rows:
        lines.append(f"| {be} | {label} | {work} | {wall:.2f} | {rate:.3f} | "
                     f"{rate / rate_serial:.2f}x | {rate / base:.2f}x |")
    table = "\n".join(lines)
    notes = (f"- local cluster start-up and the workers' imports (not in the sweeps' wall "
             f"times): {t_cluster:.1f} s; compile: {t_compile:.1f} s\n"
             + (f"- integrated 0..{prep.t_span[1]:g} s only (--t-end)\n"
                if a.t_end is not None else "")
             + f"- numpy sweep: its {rep.chunks} tasks took {_task_walls(ds)} s each\n"
             + f"- the sweep's joint angles against the single runs of the same instances: "
             f"within {diff:.2e} rad; against the in-process batch: within {bdiff:.2e} rad\n"
             f"- rhs calls: {np.mean(nfev):.0f} per single run (mean); {bst['nfev']} for the "
             f"whole batch of {min(a.chunk, n)} (a batch shares its steps: one error norm "
             "over all its instances)\n" + cnotes)
    print()
    print(table)
    print(notes)
    print(acc)
    if a.write:
        cmd = "python bench/bench_sweep.py " + " ".join(sys.argv[1:])
        text = (
            "# bgc sweep: throughput against a serial loop of single runs\n\n"
            f"Command: `{cmd}` (one run; {platform.machine()}, {os.cpu_count()} cores shared "
            "with other jobs, one BLAS thread per process).\n\n"
            f"Scene `models/scenes/3r2s_circle_sweep.yaml`: the 3R2S circle, {mod.N_STATES} "
            f"states, Radau rtol {prep.rtol:g}, {prep.t_span[1] - prep.t_span[0]:g} s; "
            f"{n} instances (m2 x m3 x k_r: 2 x 2 x 4).\n\n"
            + table + "\n\n" + notes + acc)
        (ROOT / "bench" / "RESULTS_sweep.md").write_text(text, encoding="utf-8")
        print("wrote bench/RESULTS_sweep.md")


def _task_walls(ds) -> str:
    """The tasks' own wall times (from the store's chunk_wall), comma-separated."""
    walls = ds["chunk_wall"].values
    chunk = int(ds.attrs["chunk"])
    return ", ".join(f"{w:.2f}" for w in walls[::chunk])


def _warm():
    """Run on each worker: the imports a task needs (bgc's sweep, numpy, scipy)."""
    import scipy.linalg  # noqa: F401

    import bgc.studies.sweep  # noqa: F401


def accuracy_walls(workers) -> str:
    """Wall time of one work-precision study of the pendulum (4 methods x 6 tolerances, the
    two references), run one after another here and as Dask tasks on `workers` processes."""
    from bgc.studies.accuracy import prepare as acc_prepare
    from bgc.studies.accuracy import study

    setup = acc_prepare(ROOT / "models" / "scenes" / "pendulum_swing.yaml", t_end=10.0)
    kw = dict(methods=("RK45", "DOP853", "Radau", "BDF"), tols=tuple(10.0 ** -k for k in
                                                                    range(3, 9)),
              budget=60.0, repeats=1, ref_rtol=1e-11, jac_methods=())
    t1 = time.perf_counter()
    s1 = study(setup, **kw)
    serial = time.perf_counter() - t1
    client = sweep.client_for("local", workers)
    try:
        t1 = time.perf_counter()
        s2 = study(setup, client=client, **kw)
        cold = time.perf_counter() - t1
        t1 = time.perf_counter()  # again, on workers that have compiled and warmed up
        s2 = study(setup, client=client, **kw)
        par = time.perf_counter() - t1
    finally:
        sweep.close_client(client)
    same = all((r.status, r.nfev, r.njev, r.nsteps, r.err) == (q.status, q.nfev, q.njev,
                                                                 q.nsteps, q.err)
               for r, q in zip(s1.runs, s2.runs))
    line = (f"\n`bgc accuracy` on the pendulum (t = 0..10 s; RK45, DOP853, Radau, BDF x rtol "
            f"1e-3..1e-8; references at rtol 1e-11; one repeat; study() as --workers runs "
            f"it): {serial:.1f} s one run after another, {par:.1f} s as Dask tasks on "
            f"{workers} workers ({serial / par:.2f}x; {cold:.1f} s the first time, the workers "
            f"compiling the module and importing scipy; cluster start-up not included); the "
            f"runs' statuses, counts and errors {'identical' if same else 'DIFFER'}.\n")
    print(line, flush=True)
    return line


if __name__ == "__main__":
    main()
