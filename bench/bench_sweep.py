"""Throughput of `bgc sweep` against a serial loop of single runs, side by side in one run.

    python bench/bench_sweep.py [--workers 2] [--chunk 8] [--serial 4] [--write]

The scene is models/scenes/3r2s_circle_sweep.yaml: the 3R2S circle (95 states, Radau, rtol
1e-6) over the masses of links 2 and 3 and the rotational couplings' stiffness (16 instances).
Measured, in this order, in one process:

* serial: single runs (`simulate` with scalar parameters, one instance per call) of
  `--serial` instances spread over the sweep, one after another: instances per second;
* batch: one vectorised `simulate` call over `--chunk` instances in this process (what one
  Dask task does), so the gain of batching shows apart from the gain of workers;
* sweep: the whole sweep through `bgc.sweep.run_sweep` on a new local Dask cluster of
  `--workers` processes (one thread each), chunks of `--chunk`, into a Zarr store: instances
  per second with the cluster already started (its start-up is reported apart), the workers
  compiling their module from its source text within the measured time.

The serial runs' outputs are checked against the sweep's (the same instances), and the
largest difference in the joint angles is reported. --write replaces bench/RESULTS_sweep.md.
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

from bgc import sweep  # noqa: E402

SCENE = ROOT / "models" / "scenes" / "3r2s_circle_sweep.yaml"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--chunk", type=int, default=8)
    ap.add_argument("--serial", type=int, default=4, help="single runs in the serial loop")
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
    prep = sweep.prepare(SCENE)
    mod = sweep.load(prep)
    t_compile = time.perf_counter() - t0
    n = prep.n
    print(f"compiled {SCENE.name}: {mod.N_STATES} states, {n} instances "
          f"({t_compile:.1f} s)", flush=True)

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

    # the sweep on a local Dask cluster
    t1 = time.perf_counter()
    client = sweep.client_for("local", a.workers)
    t_cluster = time.perf_counter() - t1
    tmp = Path(tempfile.mkdtemp())
    try:
        t1 = time.perf_counter()
        rep = sweep.run_sweep(prep, tmp / "r.zarr", client, a.chunk, quiet=False)
        t_sweep = time.perf_counter() - t1
        ds = sweep.open_results(tmp / "r.zarr").load()
    finally:
        sweep.close_client(client)
        shutil.rmtree(tmp, ignore_errors=True)
    rate_sweep = n / t_sweep
    assert (ds["status"].values == 0).all(), ds["message"].values
    diff = max(float(np.max(np.abs(ds[o].values[i] - serial_y[i][o][0])))
               for i in serial_y for o in ("theta1", "theta2", "theta3", "theta4"))
    bdiff = max(float(np.max(np.abs(ds[o].values[:len(bout[o])] - bout[o])))
                for o in ("theta1", "theta2", "theta3", "theta4"))

    rows = [
        ("serial loop of single runs", f"{len(pick)} runs", sum(t_serial), rate_serial),
        (f"one batch of {min(a.chunk, n)} in one process", "1 call", t_batch, rate_batch),
        (f"bgc sweep, {a.workers} workers, chunks of {a.chunk}", f"{rep.chunks} tasks", t_sweep,
         rate_sweep),
    ]
    lines = [
        "| | work | wall [s] | instances/s | vs serial |",
        "|---|---|---|---|---|",
    ]
    for label, work, wall, rate in rows:
        lines.append(f"| {label} | {work} | {wall:.1f} | {rate:.3f} | {rate / rate_serial:.2f}x |")
    table = "\n".join(lines)
    notes = (f"- local cluster start-up (not in the sweep's wall time): {t_cluster:.1f} s; "
             f"compile: {t_compile:.1f} s\n"
             f"- the sweep's joint angles against the single runs of the same instances: "
             f"within {diff:.2e} rad; against the in-process batch: within {bdiff:.2e} rad\n"
             f"- rhs calls: {np.mean(nfev):.0f} per single run (mean); {bst['nfev']} for the "
             f"whole batch of {min(a.chunk, n)} (a batch shares its steps: one error norm "
             "over all its instances)\n")
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


def accuracy_walls(workers) -> str:
    """Wall time of one work-precision study of the pendulum (4 methods x 6 tolerances, the
    two references), run one after another here and as Dask tasks on `workers` processes."""
    from bgc.accuracy import prepare as acc_prepare
    from bgc.accuracy import study

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
