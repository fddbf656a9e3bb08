"""Where the CPU of one `bgc compile MODEL -o OUT` goes, stage by stage, each round a fresh
process per checkout (issue 27).

    python bench/bench_compile_split.py [--model models/3r2s.yaml] [--repeats 3] \
        [--before /tmp/before/src]

Each round runs this file with ``--child`` in a new interpreter (its own empty compile cache),
for this checkout and, alternating, for ``--before``'s src folder. The child measures its own
CPU (user + sys): importing the libraries a compile needs, bgc's modules, the driver's compile
(`bgc.run.driver.compile_file`) and its parts (parse, graph, causality, equations with the
Jacobian's forward sweep apart, lowering with the linearisation's B, C, D apart, printing with the module's check apart), the start check (`check_module_start`: the module loaded and its
rhs called, as `bgc compile` does) and the write. Prints every round and the medians.
"""
from __future__ import annotations

import argparse
import json
import resource
import statistics
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

import alternate  # bench/, beside this script: the before/after harness


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def child(model: str, out: str) -> dict:
    times = {}
    t = _cpu()
    import click  # noqa: F401
    import jinja2  # noqa: F401
    import networkx  # noqa: F401
    import numpy  # noqa: F401
    import symengine  # noqa: F401
    import sympy  # noqa: F401
    import yaml  # noqa: F401
    times["libraries"] = _cpu() - t
    t = _cpu()
    import bgc.core.equations as equations
    from bgc.backends.numpy import printer
    from bgc.lower import ir
    from bgc.run import driver, runner
    times["bgc modules"] = _cpu() - t
    spent: dict = {}

    def timed(owner, name: str, label: str):  # (each looked up at call time by its caller)
        real = getattr(owner, name)

        def wrapper(*a, **k):
            t0 = _cpu()
            try:
                return real(*a, **k)
            finally:
                spent[label] = spent.get(label, 0.0) + _cpu() - t0
        setattr(owner, name, wrapper)
    for owner, name, label in ((driver, "parse", "parse"), (driver, "graph_of", "graph"),
                               (driver, "causality_of", "causality"),
                               (equations, "derive", "equations"),
                               (equations, "jacobian", "of it the Jacobian"),
                               (ir, "lower", "lower"), (ir, "lower_linear", "of it B, C, D"),
                               (printer, "render", "print"),
                               (printer, "check_skeleton", "of it the check")):
        timed(owner, name, label)
    t = _cpu()
    c = driver.compile_file(model)
    times["compile"] = _cpu() - t
    for label in ("parse", "graph", "causality", "equations", "of it the Jacobian", "lower",
                  "of it B, C, D", "print", "of it the check"):
        times["  " + label] = spent.get(label, 0.0)
    t = _cpu()
    runner.check_module_start(c)
    times["start check"] = _cpu() - t
    t = _cpu()
    Path(out).write_text(c.source, encoding="utf-8")
    times["write"] = _cpu() - t
    times["whole process"] = _cpu()
    return times


def main() -> None:
    ap = alternate.parser(__doc__, repeats=3)
    ap.add_argument("--out", default=None, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        print(json.dumps(child(a.model, a.out)))
        return
    srcs = alternate.checkouts(a.before)
    with tempfile.TemporaryDirectory() as d:
        rows = alternate.rounds(srcs, a.repeats, lambda src: alternate.child(
            __file__, src, ["--model", a.model, "--out", str(Path(d) / "m.py")]))
    print(f"\nCPU seconds, median of {a.repeats} ({Path(a.model).name}):")
    keys = list(rows["after"][0])
    print("| stage | " + " | ".join(srcs) + " |\n|---|" + "---|" * len(srcs))
    for k in keys:
        print(f"| {k} | " + " | ".join(f"{statistics.median(t[k] for t in rows[lb]):.3f}"
                                       for lb in srcs) + " |")


if __name__ == "__main__":
    main()
