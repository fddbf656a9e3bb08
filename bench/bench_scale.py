"""How bgc scales with model size (issue 27): RC ladders and rigid rod chains of growing size.

For each size, side by side in one run, each a whole command in a fresh process:
- ``cold``: `bgc simulate SCENE --backend B` with an empty compile cache (parse, analysis,
  code generation, for C the build, then the run);
- ``warm``: the same command again (the run record replays it);
- ``script``: a hand-written scipy model of the same system (the ladder only: the node
  equations written by hand, scipy's Radau with the sparse Jacobian), as a whole process.
- ``compile``, ``first``: the cold command's own split (its summary line): the compile with
  the C build, and the first integration;
- the cold command's compile stages (``BGC_STAGE_TIMES=1`` makes `bgc simulate` print them:
  bgc.run.driver.STAGES), each with its share, in a second table.
Growth exponents are the slopes of log(time) against log(size) over the two largest sizes.

The RC ladder (the circuit of SciMLBenchmarks' RC-circuit benchmark): a source V(t) through
R into node 1, R between consecutive nodes, a C from each node to ground; 10 s, Radau, rtol
1e-6. Rigid chains: bench/planar_chain.py's n-rod pendulums (derivative causality
eliminated), 10 s, Radau, rtol 1e-6.

    python bench/bench_scale.py                  # ladders 10..300, chains 2..8
    python bench/bench_scale.py --ladder 100,1000,3000 --chain 2,3,5,8,12 --backends numpy,c
    python bench/bench_scale.py --ladder 1000,3000 --chain "" --backends c,numpy  # issue 27

Prints the tables (`--out FILE` writes them too; bench/RESULTS_scale.md keeps the runs, pasted
by hand). CPU-bound and noisy on a shared machine: compare ratios
within one run, not times across runs.
"""
from __future__ import annotations

import argparse
import math
import os
import shutil
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

from planar_chain import chain_yaml  # noqa: E402

BGC = [sys.executable, "-m", "bgc.cli"]


def ladder_yaml(n: int) -> str:
    """An n-node RC ladder as a flat bond graph: Se -> 1 (R0) -> 0 (C1) -> 1 (R1) -> 0 ..."""
    out = ["bgc: 1", f"name: rc_ladder_{n}",
           f"description: RC ladder of {n} nodes (bench/bench_scale.py)", "",
           "parameters:", "  R: {value: 1.0, unit: Ohm}", "  C: {value: 0.01, unit: F}",
           "  V0: {value: 1.0, unit: V}", "  f0: {value: 1.0, unit: Hz}", "",
           "inputs:", '  V: {default: "V0 * sin(2 * pi * f0 * t)", unit: V}', "",
           "elements:", '  src: {type: Se, effort: "V"}']
    bonds = []
    for i in range(n):
        out.append(f'  s{i}: {{type: "1"}}')
        out.append(f'  r{i}: {{type: R, resistance: "R"}}')
        out.append(f'  n{i}: {{type: "0"}}')
        out.append(f'  c{i}: {{type: C, compliance: "C"}}')
        bonds += [f"  - [{'src' if i == 0 else f'n{i - 1}'}, s{i}]", f"  - [s{i}, r{i}]",
                  f"  - [s{i}, n{i}]", f"  - [n{i}, c{i}]"]
    out += ["", "bonds:"] + bonds + ["", "outputs:", f'  v_end: {{expr: "e(c{n - 1})", unit: V}}']
    return "\n".join(out) + "\n"


LADDER_SCRIPT = """
import sys, numpy as np, scipy.sparse as sp
from scipy.integrate import solve_ivp
n = int(sys.argv[1]); R, C = 1.0, 0.01
def f(t, v):
    vin = np.sin(2 * np.pi * t)
    left = np.concatenate(([vin], v[:-1]))
    i_in = (left - v) / R
    i_out = np.concatenate(((v[:-1] - v[1:]) / R, [0.0]))
    return (i_in - i_out) / C
main = np.full(n, -2.0 / (R * C)); main[-1] = -1.0 / (R * C)
J = sp.diags([np.full(n - 1, 1 / (R * C)), main, np.full(n - 1, 1 / (R * C))], [-1, 0, 1],
             format="csc")
r = solve_ivp(f, (0.0, 10.0), np.zeros(n), method="Radau", rtol=1e-6, atol=1e-9,
              jac=lambda t, v: J, t_eval=np.linspace(0, 10, 1001))
print(r.status, r.y[-1, -1])
"""


def scene_yaml(model_file: str, method: str = "Radau") -> str:
    return (f"bgc_scene: 1\nmodel: {model_file}\nduration: 10.0\n"
            f"solver: {{method: {method}, rtol: 1.0e-6, atol: 1.0e-9, dt: 0.01}}\n")


def timed(cmd, env, parts=None) -> float:
    """The command's wall time; parts (a dict) gets the summary line's compile (with the C
    build) and integrate seconds, the run's own split, and its compile stages (the "stages:"
    line `bgc simulate` prints with BGC_STAGE_TIMES=1) under "stages"."""
    t0 = time.perf_counter()
    r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=3600)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed: {r.stderr[-800:]}")
    m = re.search(r"compile ([0-9.]+) s, integrate ([0-9.]+) s", r.stdout)
    if parts is not None and m:
        parts["compile"], parts["integrate"] = float(m.group(1)), float(m.group(2))
    st = re.search(r"^stages: (.*)$", r.stderr, re.M)
    if parts is not None and st:
        parts["stages"] = {k: float(v) for k, v in
                           re.findall(r"([a-zA-Z ]+?) ([0-9.]+) s(?:, |$)", st.group(1))}
    return wall


def measure(family: str, size: int, text: str, backends, workdir: Path) -> dict:
    model = workdir / f"{family}{size}.yaml"
    model.write_text(text)
    scene = workdir / f"{family}{size}_scene.yaml"
    scene.write_text(scene_yaml(model.name))
    row = {"family": family, "size": size}
    for b in backends:
        cache = Path(tempfile.mkdtemp(prefix="bgc-scale-cache-"))
        os.chmod(cache, 0o700)
        env = {**os.environ, "BGC_CACHE_DIR": str(cache), "PYTHONPATH": str(ROOT / "src"),
               "BGC_STAGE_TIMES": "1"}
        # as a user's machine runs it: bgc's own modules from their bytecode, not compiled from
        # source in every process (some images set PYTHONDONTWRITEBYTECODE=1)
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        cmd = BGC + ["simulate", str(scene), "--backend", b, "--out",
                     str(workdir / f"{family}{size}_{b}.npz"), "-q"]
        parts = {}
        row[f"{b}_cold"] = timed(cmd, env, parts)
        row[f"{b}_compile"] = parts.get("compile", float("nan"))
        row[f"{b}_first"] = parts.get("integrate", float("nan"))
        row[f"{b}_stages"] = parts.get("stages", {})
        row[f"{b}_warm"] = timed(cmd, env)
        shutil.rmtree(cache, ignore_errors=True)
    if family == "ladder":
        script = workdir / "ladder_script.py"
        script.write_text(LADDER_SCRIPT)
        env = dict(os.environ)
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        row["script"] = timed([sys.executable, str(script), str(size)], env)
    print(row, flush=True)
    return row


def exponent(rows, key) -> str:
    pts = [(r["size"], r[key]) for r in rows if key in r][-2:]
    if len(pts) < 2 or pts[0][0] == pts[1][0]:
        return "-"
    (n1, t1), (n2, t2) = pts
    return f"{math.log(t2 / t1) / math.log(n2 / n1):.2f}"


def table(rows, backends) -> list[str]:
    fam = rows[0]["family"]
    keys = ("cold", "compile", "first", "warm")
    head = ["size"] + [f"{b} {k} [s]" for b in backends for k in keys]
    if fam == "ladder":
        head += ["script [s]"] + [f"{b} {k} / script" for b in backends for k in ("cold", "warm")]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [str(r["size"])] + [f"{r[f'{b}_{k}']:.2f}" for b in backends for k in keys]
        if fam == "ladder":
            cells += [f"{r['script']:.2f}"] + [f"{r[f'{b}_{k}'] / r['script']:.2f}x"
                                               for b in backends for k in ("cold", "warm")]
        lines.append("| " + " | ".join(cells) + " |")
    exps = ["growth exponent"] + [exponent(rows, f"{b}_{k}") for b in backends for k in keys]
    if fam == "ladder":
        exps += [exponent(rows, "script")] + ["" for _ in backends for _k in (0, 1)]
    lines.append("| " + " | ".join(exps) + " |")
    return lines


def stage_table(rows, backends) -> list[str]:
    """Seconds per compile stage of each cold run (bgc.run.driver.STAGES), with its share."""
    names = []
    for r in rows:
        for b in backends:
            names += [k for k in r.get(f"{b}_stages", {}) if k not in names]
    lines = ["| size | backend | " + " | ".join(names) + " |", "|" + "---|" * (len(names) + 2)]
    for r in rows:
        for b in backends:
            st = r.get(f"{b}_stages", {})
            tot = sum(st.values()) or 1.0
            lines.append(f"| {r['size']} | {b} | " + " | ".join(
                f"{st[k]:.2f} ({100 * st[k] / tot:.0f} %)" if k in st else "" for k in names)
                + " |")
    return lines


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ladder", default="10,30,100,300")
    ap.add_argument("--chain", default="2,3,5,8")
    ap.add_argument("--backends", default="numpy,c")
    ap.add_argument("--out", default=None,
                    help="write the tables to this file too (bench/RESULTS_scale.md keeps the "
                         "history of runs: paste a run there by hand)")
    a = ap.parse_args()
    backends = [b for b in a.backends.split(",") if b]
    work = Path(tempfile.mkdtemp(prefix="bgc-scale-"))
    load0 = os.getloadavg()[0]
    ladders = [measure("ladder", int(n), ladder_yaml(int(n)), backends, work)
               for n in a.ladder.split(",") if n]
    chains = [measure("chain", int(n), chain_yaml(int(n)), backends, work)
              for n in a.chain.split(",") if n]
    shutil.rmtree(work, ignore_errors=True)
    cmd = " ".join(["python bench/bench_scale.py", f"--ladder {a.ladder}", f"--chain {a.chain}",
                    f"--backends {a.backends}"])
    lines = ["# Scale: compile and run time against model size", "",
             f"`{cmd}` (one run, side by side; every time a whole command in a fresh process; "
             "cold = empty compile cache, warm = the same command again (the run record's "
             "replay); compile and first = the cold run's own split from its summary line: "
             "the compile with the C build, and the integration; load average "
             f"{load0:.1f} at the start, {os.getloadavg()[0]:.1f} at the end on "
             f"{os.cpu_count()} cores).", ""]
    if ladders:
        lines += ["## RC ladders (states = size)", ""] + table(ladders, backends) + [""]
        lines += ["### Where a cold run's compile goes (its stages, `BGC_STAGE_TIMES=1`)",
                  ""] + stage_table(ladders, backends) + [""]
    if chains:
        lines += ["## Rigid rod chains (states = 2 x size)", ""] + table(chains, backends) + [""]
    if a.out:
        Path(a.out).write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
