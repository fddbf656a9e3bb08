"""Issue 27, the command's imports: each command imports what it runs, no more. Listing the
commands (`bgc --help`) imports none of the libraries a compile needs, `bgc check` none of
the printers, templates or integrators; `bgc --help` lists the heavy commands (accuracy,
sweep) by summaries that are their own help's."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import click

ROOT = Path(__file__).resolve().parent.parent

_PROBE = r"""
import json, sys
from bgc.cli.launch import main
try:
    main(sys.argv[1:])
except SystemExit:
    pass
print(json.dumps(sorted(sys.modules)), file=sys.stderr)
"""


def _modules(tmp_path, *args) -> tuple[subprocess.CompletedProcess, set[str]]:
    env = {**os.environ, "BGC_CACHE_DIR": str(tmp_path / "cache")}
    r = subprocess.run([sys.executable, "-c", _PROBE, *args], capture_output=True, text=True,
                       env=env, timeout=600, cwd=ROOT, check=False)
    return r, set(json.loads(r.stderr.strip().splitlines()[-1]))


def _loaded(mods: set[str], names) -> list[str]:
    return sorted(n for n in names if n in mods)


def test_help_imports_no_library_a_compile_needs(tmp_path):
    r, mods = _modules(tmp_path, "--help")
    assert "accuracy" in r.stdout and "sweep" in r.stdout and "simulate" in r.stdout
    assert _loaded(mods, ["sympy", "numpy", "networkx", "jinja2", "symengine", "yaml", "scipy",
                          "matplotlib", "bgc.run.driver", "bgc.run.record",
                          "bgc.studies.accuracy", "bgc.studies.sweep", "bgc.format.scene",
                          "bgc.format.parse"]) == []


def test_check_imports_no_printer_template_or_integrator(tmp_path):
    r, mods = _modules(tmp_path, "check", str(ROOT / "models" / "msd.yaml"))
    assert r.returncode == 0 and "states (2 scalars)" in r.stdout, r.stdout
    assert _loaded(mods, ["jinja2", "scipy", "matplotlib", "sympy.printing.c",
                          "bgc.backends.numpy.printer", "bgc.backends.c.printer", "bgc.lower.ir",
                          "bgc.studies.accuracy"]) == []


def test_the_listed_summaries_are_the_commands_own():
    from bgc.cli import commands

    for name, (register, summary) in commands._LAZY.items():
        if name not in commands.main.commands:
            register()
        real = commands.main.commands[name]
        for limit in (45, 60, 200):
            assert click.Command(name, help=summary).get_short_help_str(limit) == \
                real.get_short_help_str(limit)


def test_the_closed_loops_start_check_loads_numpy_only_when_it_runs():
    """bgc.core.assembly (imported by every derivation) defers numpy to the closed loops'
    numerics; `bgc check` still loads numpy through symengine, whose extension imports it."""
    code = "import sys, bgc.core.assembly; print('numpy' in sys.modules)"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=600, cwd=ROOT, check=True)
    assert r.stdout.strip() == "False"
