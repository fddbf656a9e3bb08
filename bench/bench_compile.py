"""Symbolic compile time against model size: it must grow linearly.

    python bench/bench_compile.py [--quick] [--repeats 3]

Two families of generated models, each compiled (parse -> graph -> causality -> equations ->
numpy module, CPU seconds, the median of ``--repeats``) at several sizes, side by side in one
run:

* **mass chain**: N masses in a row, each tied to the previous one (the first to a wall) by
  a spring and a damper, a force on the last: 2N states, all scalar bonds.
* **link chain**: N spatial rigid links of the 3R2S (its ``link`` component: translational
  and rotational inertia, rotation matrix, multibonds of cardinality 3, state-dependent MTF
  moduli) joined end to end by its viscoelastic ``tcoupling``, the first to the ground: 21N
  states.

Then the 3R2S itself (models/3r2s.yaml). The report gives CPU seconds per state at each size:
a linear compiler keeps that column flat.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from bgc.format.parse import parse_file  # noqa: E402
from bgc.run.driver import compile_model  # noqa: E402


def mass_chain(n: int) -> dict:
    params = {"m": 1.0, "k": 100.0, "c": 0.5, "F0": 1.0}
    el = {"force": {"type": "Se", "effort": "F0"}}
    bonds = []
    for i in range(n):
        el[f"v{i}"] = {"type": "1"}
        el[f"m{i}"] = {"type": "I", "inertia": "m"}
        bonds.append([f"v{i}", f"m{i}"])
        el[f"s{i}"] = {"type": "1"}  # relative velocity v_i - v_{i-1} (or v_0 - wall)
        el[f"k{i}"] = {"type": "C", "stiffness": "k"}
        el[f"c{i}"] = {"type": "R", "resistance": "c"}
        bonds += [[f"s{i}", f"k{i}"], [f"s{i}", f"c{i}"]]
        if i == 0:
            bonds.append([f"v{i}", f"s{i}"])
        else:
            el[f"f{i}"] = {"type": "0"}  # the force between neighbours
            bonds += [[f"v{i}", f"f{i}"], [f"f{i}", f"v{i - 1}"], [f"f{i}", f"s{i}"]]
    bonds.append(["force", f"v{n - 1}"])
    return {"bgc": 1, "name": f"mass_chain_{n}", "parameters": params, "elements": el,
            "bonds": bonds, "outputs": {"x_last": f"q(k{n - 1})"}}


def link_chain(n: int) -> dict:
    base = yaml.safe_load((ROOT / "tests" / "data" / "3r2s_before_library.yaml").read_text())
    comps = {k: base["components"][k] for k in ("link", "tcoupling")}
    el = {"ground": {"type": "Sf", "flow": "[0, 0, 0]"}}
    params = {"d": {"value": 0.05, "unit": "m"}}  # the links' length: rC0's unit
    bonds = []
    for i in range(n):
        el[f"link{i}"] = {"type": "link", "m": 0.5, "l": "d", "rC0": f"[{i + 0.5} * d, 0, 0]"}
        el[f"j{i}"] = {"type": "tcoupling", "k": 1.0e6, "r": 10.0}
        bonds.append({"from": "ground" if i == 0 else f"link{i - 1}.P", "to": f"j{i}.a", "n": 3})
        bonds.append({"from": f"j{i}.b", "to": f"link{i}.Q", "n": 3})
    el["tip_load"] = {"type": "Se", "effort": "[0, 0, 0]"}  # a free end: no force on it
    bonds.append({"from": "tip_load", "to": f"link{n - 1}.P", "n": 3})
    return {"bgc": 1, "name": f"link_chain_{n}", "parameters": params, "components": comps,
            "elements": el,
            "bonds": bonds, "outputs": {"tip": f"f(link{n - 1}.P)"}}


def cpu_compile(path: Path, repeats: int) -> tuple[float, int]:
    times, n = [], 0
    for _ in range(repeats):
        t0 = time.process_time()
        c = compile_model(parse_file(path))
        times.append(time.process_time() - t0)
        n = len(c.equations.states)
    return statistics.median(times), n


_FRESH = r"""
import json, sys, time
t0 = time.process_time()
from bgc.run.driver import compile_model
from bgc.format.parse import parse_file
t1 = time.process_time()
c = compile_model(parse_file(sys.argv[1]))
print(json.dumps([t1 - t0, time.process_time() - t1, len(c.equations.states)]))
"""


def fresh_compile(path: Path, repeats: int) -> tuple[float, float, int]:
    """(imports, compile, states): CPU seconds in a fresh interpreter (sympy's caches cold, as
    for a user's `bgc compile`), the best of ``repeats``."""
    import json
    import os
    import subprocess

    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    runs = [json.loads(subprocess.run([sys.executable, "-c", _FRESH, str(path)], check=True,
                                      env=env, capture_output=True, text=True).stdout)
            for _ in range(repeats)]
    return min(r[0] for r in runs), min(r[1] for r in runs), runs[0][2]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="smaller sizes")
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    chains = (50, 100, 200) if a.quick else (100, 200, 400, 800)
    links = (2, 4, 8) if a.quick else (2, 4, 8, 16)
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for fam, sizes, make in (("mass chain", chains, mass_chain),
                                 ("link chain", links, link_chain)):
            for n in sizes:
                p = Path(d) / f"{fam.replace(' ', '_')}_{n}.yaml"
                p.write_text(yaml.safe_dump(make(n), sort_keys=False))
                t, ns = cpu_compile(p, a.repeats)
                rows.append((fam, n, ns, t))
                print(f"{fam:10s} N={n:4d} states={ns:5d} cpu={t:7.3f} s  "
                      f"{1e3 * t / ns:6.2f} ms/state", flush=True)
    imp, t, ns = fresh_compile(ROOT / "models" / "3r2s.yaml", a.repeats)
    print(f"3R2S (models/3r2s.yaml) states={ns} cpu={t:.3f} s in a fresh interpreter "
          f"(best of {a.repeats}; + {imp:.3f} s importing the libraries)")


if __name__ == "__main__":
    main()
