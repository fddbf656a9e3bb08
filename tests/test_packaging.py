"""What a wheel ships: every template file (numpy and C backends, the C runtime, FMU export)
must be matched by pyproject.toml's package-data patterns, read as setuptools reads them
(globs relative to the package folder). A template missing from the wheel breaks only
installed copies (an editable install reads the checkout), so the check is done here."""
from __future__ import annotations

import glob
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

tomllib = pytest.importorskip("tomllib") if sys.version_info >= (3, 11) else None


def _shipped(package: str, folder: Path) -> set[str]:
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    pats = cfg["tool"]["setuptools"]["package-data"][package]
    out = set()
    for pat in pats:
        out |= {p for p in glob.glob(pat, root_dir=folder) if (folder / p).is_file()}
    return out


@pytest.mark.skipif(tomllib is None, reason="tomllib needs Python 3.11")
def test_every_template_is_package_data():
    folder = ROOT / "templates"
    files = {str(p.relative_to(folder)) for p in folder.rglob("*")
             if p.is_file() and "__pycache__" not in p.parts and p.name != "__init__.py"}
    assert files, "no templates found"
    missing = sorted(files - _shipped("bgc.templates", folder))
    assert not missing, f"templates not shipped in the wheel: {missing}"


@pytest.mark.skipif(tomllib is None, reason="tomllib needs Python 3.11")
def test_every_example_is_package_data():
    for package, folder in (("bgc.examples", ROOT / "models"),
                            ("bgc.examples.scenes", ROOT / "models" / "scenes")):
        files = {p.name for p in folder.iterdir() if p.is_file()}
        missing = sorted(files - _shipped(package, folder))
        assert not missing, f"{package}: not shipped: {missing}"


@pytest.mark.skipif(tomllib is None, reason="tomllib needs Python 3.11")
def test_the_component_library_is_package_data():
    folder = ROOT / "src" / "bgc" / "format"
    files = {str(p.relative_to(folder)) for p in (folder / "library").iterdir() if p.is_file()}
    assert files, "no library files found"
    missing = sorted(files - _shipped("bgc.format", folder))
    assert not missing, f"library files not shipped in the wheel: {missing}"
