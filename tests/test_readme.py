"""Every `bgc` command line of the README runs, as written, in a fresh copy of the repository
(issue 21: `bgc compile models/msd.yaml --target c -o msd_c/` from a fresh clone handed the C
compiler a relative path it resolved in another folder).

The command lines are read from README.md's ```sh blocks when the tests are collected (the
README changes; nothing is hard-coded here). Lines that are only comments are skipped, and so
are the few that cannot run here by their nature: a placeholder in capitals (SCENE), a running
Dask scheduler (tcp://), the set-up lines (venv, pip, pytest). Each runs with the repository
copy as its working folder, a private compile cache, and must exit 0 without a traceback."""
from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BGC = Path(sys.executable).with_name("bgc")


def readme_commands(text: str) -> list[str]:
    """The `bgc ...` command lines of the ```sh blocks, comments stripped."""
    out, in_sh = [], False
    for line in text.splitlines():
        s = line.strip()
        if s.startswith("```"):
            in_sh = s in ("```sh", "```bash", "```shell") and not in_sh
            continue
        if not in_sh or not s or s.startswith("#"):
            continue
        words = shlex.split(s, comments=True)
        if not words or words[0] != "bgc":
            continue
        if any(re.fullmatch(r"[A-Z][A-Z_]+", w) for w in words) or any("://" in w for w in words):
            continue  # a placeholder, or a running Dask scheduler
        out.append(shlex.join(words))
    return out


COMMANDS = readme_commands((ROOT / "README.md").read_text(encoding="utf-8"))


def test_the_readme_has_commands():
    assert len(COMMANDS) >= 5
    assert any("--target c" in c for c in COMMANDS)


@pytest.fixture
def fresh_copy(tmp_path):
    """The repository's tracked files (as in this working tree) in a new folder: what a fresh
    clone holds, without the generated outputs or caches of this checkout. One per command:
    two README lines may write the same output with other options (a sweep's --chunk)."""
    files = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True,
                           check=True).stdout.decode().split("\0")
    dest = tmp_path / "clone"
    for rel in filter(None, files):
        src = ROOT / rel
        if src.is_file():
            (dest / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / rel)
    return dest


def _c_compiler() -> bool:
    return shutil.which(os.environ.get("CC", "cc").split()[0] or "cc") is not None


@pytest.mark.slow
@pytest.mark.parametrize("command", COMMANDS)
def test_readme_command_runs(command, fresh_copy, tmp_path):
    if ("--target c" in command or "--backend c" in command or "export" in command) \
            and not _c_compiler():
        pytest.skip("no C compiler")
    if re.search(r"\.(svg|png|pdf)\b", command) and " graph " in f" {command} " \
            and shutil.which("dot") is None:
        pytest.skip("no Graphviz 'dot' program (bgc graph says so for .svg)")
    env = dict(os.environ, PYTHONPATH=str(fresh_copy / "src"), MPLBACKEND="Agg",
               BGC_CACHE_DIR=str(tmp_path / "cache"))
    words = shlex.split(command)
    r = subprocess.run([str(BGC), *words[1:]], cwd=fresh_copy, env=env, capture_output=True,
                       text=True, timeout=900)
    assert r.returncode == 0, f"{command}: exit {r.returncode}\n{r.stderr[-3000:]}"
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr
