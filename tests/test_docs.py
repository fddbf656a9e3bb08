"""The documentation stays true to the repository: the README is a user's guide of at most
20 kB, every relative link in README.md and docs/ leads to a file (and heading) that exists,
and docs/architecture.md names every module of src/bgc and nothing that does not exist."""
from __future__ import annotations

import ast
import importlib.util
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SRC = ROOT / "src"
README = ROOT / "README.md"
ARCH = ROOT / "docs" / "architecture.md"
PAGES = [README, *sorted((ROOT / "docs").rglob("*.md"))]

LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
FENCE = re.compile(r"^\s*(```|~~~)")
TICKED = re.compile(r"`(bgc(?:\.[A-Za-z_]\w*)*)[`(]")


def prose(text: str) -> str:
    """The text outside fenced code blocks (a '#' comment in a code block is no heading, a
    link-like string in one is no link)."""
    out, fenced = [], False
    for line in text.splitlines():
        if FENCE.match(line):
            fenced = not fenced
            continue
        if not fenced:
            out.append(line)
    return "\n".join(out)


def slugs(md: Path) -> set[str]:
    """The anchors GitHub gives a page's headings: lower case, punctuation dropped, spaces
    to hyphens, a repeated slug numbered."""
    seen: dict[str, int] = {}
    out = set()
    for line in prose(md.read_text(encoding="utf-8")).splitlines():
        m = re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if not m:
            continue
        s = re.sub(r"[^\w\- ]", "", m.group(1).strip().lower()).replace(" ", "-")
        n = seen.get(s, 0)
        seen[s] = n + 1
        out.add(s if n == 0 else f"{s}-{n}")
    return out


def broken_links(md: Path) -> list[str]:
    bad = []
    for target in LINK.findall(prose(md.read_text(encoding="utf-8"))):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto:
            continue
        path, _, anchor = target.partition("#")
        dest = (md.parent / path).resolve() if path else md
        if not dest.exists():
            bad.append(f"{md.relative_to(ROOT)}: {target} (no such file)")
        elif anchor and dest.suffix == ".md" and anchor not in slugs(dest):
            bad.append(f"{md.relative_to(ROOT)}: {target} (no such heading)")
    return bad


def modules() -> dict[str, Path]:
    """Every module of src/bgc by its dotted name (a package by its own name)."""
    out = {}
    for p in sorted((SRC / "bgc").rglob("*.py")):
        name = ".".join(p.relative_to(SRC).with_suffix("").parts)
        out[name.removesuffix(".__init__")] = p
    return out


def shipped_packages() -> set[str]:
    """Packages mapped from elsewhere in pyproject.toml (bgc.templates is templates/, ...)."""
    text = (ROOT / "pyproject.toml").read_text(encoding="utf-8")
    return set(re.findall(r"\"(bgc\.[\w.]+)\"\s*=", text))


def top_level_names(path: Path) -> dict[str, ast.AST]:
    out = {}
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            out[node.name] = node
        elif isinstance(node, ast.Assign):
            for t in node.targets:
                for n in ast.walk(t):
                    if isinstance(n, ast.Name):
                        out[n.id] = node
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            out[node.target.id] = node
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            for a in node.names:
                out[(a.asname or a.name).split(".")[0]] = node
    return out


def resolves(name: str, mods: dict[str, Path], shipped: set[str]) -> bool:
    """Whether a dotted name is a module of bgc, a shipped package, or a name defined at the
    top of a module (a class's own attributes included). ``bgc.X`` also finds what the
    package's lazy ``__getattr__`` hands over from bgc.api."""
    if name in mods or name in shipped:
        return True
    parts = name.split(".")
    for i in range(len(parts) - 1, 0, -1):
        mod = ".".join(parts[:i])
        if mod in shipped:
            return True  # data files: not Python names
        if mod not in mods:
            continue
        rest = parts[i:]
        names = top_level_names(mods[mod])
        if mod == "bgc" and rest[0] not in names:
            names = top_level_names(mods["bgc.api"]) if rest[0] in _lazy_api(mods) else names
        node = names.get(rest[0])
        if node is None:
            return False
        if len(rest) > 1 and isinstance(node, ast.ClassDef):
            inner = {n.name for n in node.body if isinstance(n, (ast.FunctionDef, ast.ClassDef))}
            inner |= {t.id for n in node.body if isinstance(n, ast.AnnAssign)
                      for t in [n.target] if isinstance(t, ast.Name)}
            return rest[1] in inner
        return True
    return False


def _lazy_api(mods) -> set[str]:
    """The names bgc/__init__.py forwards to bgc.api on first use (its ``_API`` tuple)."""
    for node in ast.parse(mods["bgc"].read_text(encoding="utf-8")).body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", "") == "_API"
                                                for t in node.targets):
            return set(ast.literal_eval(node.value))
    return set()


def named(md: Path) -> set[str]:
    return set(TICKED.findall(md.read_text(encoding="utf-8")))


def test_readme_is_a_short_guide():
    size = len(README.read_bytes())
    assert size <= 20_000, f"README.md is {size} bytes: move detail to docs/"
    text = README.read_text(encoding="utf-8")
    # the two set-up commands that CI (.ci/run) relies on
    assert ".venv/bin/python -m pytest -n 2" in text
    assert ".venv/bin/pip install -e \".[test]\"" in text


@pytest.mark.parametrize("md", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_lead_somewhere(md):
    bad = broken_links(md)
    assert not bad, "broken links:\n" + "\n".join(bad)


def test_the_link_checker_finds_broken_links(tmp_path):
    (tmp_path / "there.md").write_text("# A heading: with punctuation\n")
    page = tmp_path / "page.md"
    page.write_text("[ok](there.md) [ok](there.md#a-heading-with-punctuation) "
                    "[gone](missing.md) [bad anchor](there.md#nope) [web](https://x.org/y)\n"
                    "```\n[in code](also-missing.md)\n```\n")
    global ROOT
    saved, ROOT = ROOT, tmp_path
    try:
        bad = broken_links(page)
    finally:
        ROOT = saved
    assert bad == ["page.md: missing.md (no such file)", "page.md: there.md#nope (no such heading)"]


def test_architecture_names_every_module():
    missing = sorted(set(modules()) - named(ARCH))
    assert not missing, "docs/architecture.md does not name: " + ", ".join(missing)


@pytest.mark.parametrize("md", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_bgc_name_in_the_docs_exists(md):
    mods, shipped = modules(), shipped_packages()
    bad = sorted(n for n in named(md) if not resolves(n, mods, shipped))
    assert not bad, f"{md.relative_to(ROOT)} names what does not exist: " + ", ".join(bad)


def test_the_name_check_refuses_old_and_invented_names():
    mods, shipped = modules(), shipped_packages()
    for good in ("bgc.run.driver", "bgc.LAYERS", "bgc.compile", "bgc.lower.ir.lower",
                 "bgc.templates", "bgc.api.CompiledModel"):
        assert resolves(good, mods, shipped), good
    for old in ("bgc.emit", "bgc.compiler", "bgc.cbuild", "bgc.run.driver.no_such_stage",
                "bgc.nothing"):
        assert not resolves(old, mods, shipped), old


def test_source_paths_in_the_docs_exist():
    bad = []
    for md in PAGES:
        for p in re.findall(r"(?<![\w/])((?:src|templates|bench|tests|models|scripts)/[\w./<>*-]*[\w>*])",
                            md.read_text(encoding="utf-8")):
            if "*" not in p and "<" not in p and not (ROOT / p).exists():
                bad.append(f"{md.relative_to(ROOT)}: {p}")
    assert not bad, "paths that do not exist:\n" + "\n".join(bad)


def readme_commands() -> list[str]:
    """Every `bgc ...` command line of the README's shell blocks (the set-up line's last
    command included, run as `bgc`)."""
    text = README.read_text(encoding="utf-8")
    out = []
    for block in re.findall(r"```sh\n(.*?)```", text, flags=re.DOTALL):
        for line in block.strip().splitlines():
            line = line.split("&&")[-1].strip().removeprefix(".venv/bin/")
            if line.startswith("bgc "):
                out.append(line)
    return out


SLOW = ("bgc accuracy", "bgc sweep", "3r2s")  # a minute each on a loaded machine


def _needs(line: str):
    """Why a README command cannot run here (a C compiler, FMPy, Dask), or None."""
    cc = shlex.split(os.environ.get("CC", "cc"))[:1]
    if ("--target c" in line or "export" in line) and not (cc and shutil.which(cc[0])):
        return "no C compiler"
    if "export" in line and importlib.util.find_spec("fmpy") is None:
        return "FMPy is not installed"
    if "sweep" in line and importlib.util.find_spec("dask") is None:
        return "Dask is not installed"
    return None


def run_by_test_readme(line: str) -> bool:
    """Whether tests/test_readme.py runs this line as written (in a fresh copy of the whole
    repository, with a private cache: the same check, stricter); such a line is not run twice."""
    from test_readme import COMMANDS  # (tests/ is on the path, as for conftest)

    return shlex.join(shlex.split(line, comments=True)) in COMMANDS


def test_every_readme_command_is_run_here_or_by_test_readme():
    """The split below loses no line: each README command runs in one of the two files, and
    the set-up line's own `bgc` command (test_readme.py skips the set-up lines) runs here."""
    lines = readme_commands()
    here = [c for c in lines if not run_by_test_readme(c)]
    assert lines and lines[0] in here and "3r2s_circle" in lines[0]
    assert len(lines) - len(here) >= 10  # the tour's commands, in test_readme.py


@pytest.mark.parametrize("line", [pytest.param(c, marks=[pytest.mark.slow] if any(
    s in c for s in SLOW) else []) for c in readme_commands() if not run_by_test_readme(c)])
def test_readme_command_runs(line, tmp_path):
    """Each command line of the README that tests/test_readme.py does not run (the set-up
    line's main job), as written, from a fresh folder that holds the repository's models (a
    fresh clone's root): exit status 0, no traceback."""
    why = _needs(line)
    if why:
        pytest.skip(why)
    (tmp_path / "models").symlink_to(ROOT / "models")
    env = dict(os.environ, PYTHONPATH=str(SRC) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    r = subprocess.run([sys.executable, "-m", "bgc", *shlex.split(line)[1:]], cwd=tmp_path,
                       env=env, capture_output=True, text=True, timeout=600,
                       stdin=subprocess.DEVNULL, check=False)
    assert r.returncode == 0, f"{line}: exit {r.returncode}\n{r.stderr[-2000:]}"
    assert "Traceback" not in r.stderr


def test_readme_lists_every_command():
    """The tour shows each command of `bgc --help` with an example."""
    lines = readme_commands()
    for cmd in ("compile", "check", "graph", "simulate", "explain", "equations", "linearize",
                "accuracy", "sweep", "export", "examples", "cache"):
        assert any(c.split()[1] == cmd for c in lines), f"no example of bgc {cmd}"


def test_readme_python_example_runs():
    block = re.findall(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), re.DOTALL)[0]
    env = dict(os.environ, PYTHONPATH=str(SRC) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    r = subprocess.run([sys.executable, "-c", block], cwd=ROOT, env=env, capture_output=True,
                       text=True, timeout=600, check=False)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split("\n")[:2] == ["0.05", "('mass.p', 'spring.q')"]


if __name__ == "__main__":  # a quick look: python tests/test_docs.py
    sys.exit(pytest.main([__file__, "-q"]))
