"""Loop re-rolling (issue 27, bgc.lower.reroll): the C backend with and without it, side by side.

For each RC ladder size (bench/bench_scale.py's ladder: a source through R into node 1, R
between nodes, a C from each node to ground), in one process: the symbolic compile once
(parse, equations, lowering: the same for both), then for ``unrolled`` (the pass off) and
``rolled`` (on):
- the C sources: bytes and lines of the model's units (model_part*.c) and of model.c;
- ``print``: the C text and the wrapper from the IR (for ``rolled``, the pass included);
- ``build``: the system compiler on the model's units, and the library loaded (the runtime's
  objects come from the cache, built once before the first size);
- ``rhs``, ``jac``: one call of the compiled rhs and Jacobian through the wrapper (median of
  7 rounds);
- ``run``: a warm run of 10 s, Radau, rtol 1e-6 in C (the wrapper's simulate; the best of 3);
  the variants' calls and runs interleaved round by round.
Every rolled module is checked against the unrolled one (rhs and Jacobian at a random point).

``--chain`` adds the 3-D link chains of tests/test_compile_scale.py (3R2S links) with the
threshold MIN_RUN at 3 (the vectors' x, y, z become loops), 8 (the default) and off: what a
threshold costs or saves where the runs are short.

    python bench/bench_reroll.py --ladder 300,1000,3000,10000 --chain 4,8

Writes bench/RESULTS_reroll.md. CPU-bound and noisy on a shared machine: compare the
ratios within one run, not times across runs.
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))
sys.path.insert(0, str(ROOT / "tests"))
os.environ.setdefault("BGC_CACHE_DIR", tempfile.mkdtemp(prefix="bgc-reroll-cache-"))

from bench_scale import ladder_yaml  # noqa: E402

from bgc.backends.load import c_files, load_c  # noqa: E402
from bgc.base.limits import LIMITS  # noqa: E402
from bgc.format.parse import parse_file  # noqa: E402
from bgc.lower import reroll as rr  # noqa: E402
from bgc.run.driver import compile_model  # noqa: E402

# the bench only: a 10,000-node ladder's file is larger than a model may be
object.__setattr__(LIMITS, "model_bytes", 50_000_000)
object.__setattr__(LIMITS, "flat_elements", 1_000_000)

OFF = 10 ** 9


def _call_time(f, *args) -> float:
    """One call's time: the mean over calls for at least 0.05 s."""
    k, t0 = 0, time.perf_counter()
    while True:
        f(*args)
        k += 1
        dt = time.perf_counter() - t0
        if dt > 0.05:
            return dt / k


def _variant(compiled, min_run: int, tag: str) -> tuple[dict, object]:
    """The variant's C text and library: sizes, print and build times."""
    rr.MIN_RUN = min_run
    t0 = time.perf_counter()
    files, wrapper = c_files(compiled)
    row = {"print": time.perf_counter() - t0}
    parts = [t for f, t in files.items() if f.startswith("model_part")]
    row["part_kb"] = sum(len(t.encode()) for t in parts) / 1024
    row["part_lines"] = sum(t.count("\n") for t in parts)
    row["main_kb"] = len(files["model.c"].encode()) / 1024
    row["units"] = len(parts)
    row["loops"] = sum(t.count("for (int bgc_i") for t in parts)
    t0 = time.perf_counter()
    mod = load_c(files, wrapper, f"{compiled.model.name}_{tag}")
    row["build"] = time.perf_counter() - t0
    return row, mod


def _timings(rows: dict, mods: dict, run: bool) -> None:
    """rhs, Jacobian and warm-run times, the variants interleaved round by round (median of
    7 rounds for the calls, the best of 3 runs)."""
    x = np.asarray(next(iter(mods.values())).X0, dtype=float) + 0.01
    calls: dict = {tag: {"rhs_us": [], "jac_us": []} for tag in mods}
    for _ in range(7):
        for tag, mod in mods.items():
            calls[tag]["rhs_us"].append(1e6 * _call_time(mod.rhs, 0.3, x))
            calls[tag]["jac_us"].append(1e6 * _call_time(mod.jacobian, 0.3, x))
    for tag in mods:
        for k, v in calls[tag].items():
            rows[tag][k] = statistics.median(v)
    if not run:
        return
    for tag in mods:
        rows[tag]["run"] = float("inf")
    for _ in range(3):
        for tag, mod in mods.items():
            t0 = time.perf_counter()
            res = mod.simulate((0.0, 10.0), method="Radau", rtol=1e-6, atol=1e-9)
            rows[tag]["run"] = min(rows[tag]["run"], time.perf_counter() - t0)
            rows[tag]["x_end"] = np.asarray(res.x)[-1]


def _check(a, b, n: int) -> float:
    x = np.random.default_rng(n).standard_normal(len(a.X0)) * 0.01
    err = 0.0
    for f in ("rhs", "jacobian"):
        ra, rb = np.asarray(getattr(a, f)(0.7, x)), np.asarray(getattr(b, f)(0.7, x))
        err = max(err, float(np.abs(ra - rb).max() / max(np.abs(rb).max(), 1e-300)))
    assert err < 1e-13, err
    return err


def measure(label: str, text: str, work: Path, modes, run: bool = True) -> dict:
    path = work / f"{label}.yaml"
    path.write_text(text)
    t0 = time.perf_counter()
    compiled = compile_model(parse_file(path))
    row = {"model": label, "n": len(compiled.equations.states),
           "symbolic": time.perf_counter() - t0}
    mods = {}
    for tag, min_run in modes:
        row[tag], mods[tag] = _variant(compiled, min_run, tag)
    _timings(row, mods, run)
    base = mods[modes[0][0]]
    row["err"] = max(_check(m, base, row["n"]) for t, m in mods.items() if m is not base)
    if run:
        ends = [row[t]["x_end"] for t, _ in modes]
        row["run_diff"] = max(float(np.abs(e - ends[0]).max()) for e in ends)
    print({k: v for k, v in row.items()}, flush=True)
    return row


def table(rows, modes) -> list[str]:
    cols = [("part_kb", "units [KiB]", "{:.0f}"), ("part_lines", "unit lines", "{}"),
            ("units", "units", "{}"), ("loops", "loops", "{}"),
            ("print", "print [s]", "{:.2f}"), ("build", "build [s]", "{:.2f}"),
            ("rhs_us", "rhs [us]", "{:.1f}"), ("jac_us", "jac [us]", "{:.1f}"),
            ("run", "warm run [s]", "{:.3f}")]
    cols = [c for c in cols if c[0] in rows[0][modes[0][0]]]
    head = ["model", "states", "symbolic [s]", "variant"] + [c[1] for c in cols]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        for tag, _ in modes:
            v = r[tag]
            out.append("| " + " | ".join([r["model"], str(r["n"]), f"{r['symbolic']:.1f}", tag]
                                         + [f.format(v[k]) for k, _, f in cols]) + " |")
        ref, new = r[modes[0][0]], r[modes[-1][0]]
        ratio = ["", "", "", f"{modes[0][0]} / {modes[-1][0]}"]
        for k, _, _ in cols:
            ratio.append(f"{ref[k] / new[k]:.1f}x" if new[k] and k not in ("units", "loops")
                         else "")
        out.append("| " + " | ".join(ratio) + " |")
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ladder", default="300,1000")
    ap.add_argument("--chain", default="")
    ap.add_argument("--out", default="RESULTS_reroll.md", help="file name in bench/")
    a = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="bgc-reroll-"))
    lmodes = [("unrolled", OFF), ("rolled", rr.MIN_RUN)]
    cmodes = [("off", OFF), ("MIN_RUN 8", 8), ("MIN_RUN 3", 3)]
    warm = work / "warm.yaml"  # the runtime's objects built once, before any timing
    warm.write_text(ladder_yaml(3))
    load_c(*c_files(compile_model(parse_file(warm))), "warmup")
    cmd = f"python bench/bench_reroll.py --ladder {a.ladder}" + \
        (f" --chain {a.chain}" if a.chain else "") + \
        (f" --out {a.out}" if a.out != "RESULTS_reroll.md" else "")
    ladders, chains = [], []
    for n in [n for n in a.ladder.split(",") if n]:
        ladders.append(measure(f"ladder{n}", ladder_yaml(int(n)), work, lmodes))
        write(cmd, ladders, chains, lmodes, cmodes, a.out)
    from test_compile_scale import link_chain  # (tests/ is on the path here only)
    for n in [n for n in a.chain.split(",") if n]:
        chains.append(measure(f"chain{n}", link_chain(int(n)), work, cmodes, run=False))
        write(cmd, ladders, chains, lmodes, cmodes, a.out)


def write(cmd, ladders, chains, lmodes, cmodes, name: str) -> None:
    intro = (f"`{cmd}` (one process, side by side; load average {os.getloadavg()[0]:.1f} "
             f"at the end on {os.cpu_count()} cores, shared). symbolic: parse, equations and "
             "lowering, once for every variant; print: the C text and wrapper from the IR "
             "(the pass included); build: gcc on the model's units and the load (the "
             "runtime's objects cached); rhs, jac: one call through the wrapper (median of 7 "
             "rounds); warm run: 10 s, Radau, rtol 1e-6, in C (best of 3); the variants' calls "
             "and runs interleaved. Ratios: the first variant over the last.")
    lines = ["# Loop re-rolling: the C backend with and without bgc.lower.reroll", "", intro,
             ""]
    if ladders:
        lines += ["## RC ladders", ""] + table(ladders, lmodes) + [""]
        lines.append("Largest relative difference of rhs and Jacobian, rolled against unrolled: "
                     f"{max(r['err'] for r in ladders):.1e}; of the runs' final states: "
                     f"{max(r['run_diff'] for r in ladders):.1e}.")
        lines.append("")
    if chains:
        lines += ["## 3-D link chains (tests/test_compile_scale.py's links), by threshold", ""]
        lines += table(chains, cmodes) + [""]
    out = ROOT / "bench" / Path(name).name
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
