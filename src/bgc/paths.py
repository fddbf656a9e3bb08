"""Where bgc's templates live (a leaf module: importing it imports nothing heavy)."""
from __future__ import annotations

from pathlib import Path


def templates_dir() -> Path:
    """templates/ of the source tree, else the installed package's copy (bgc.templates)."""
    here = Path(__file__).resolve().parent
    repo_templates = here.parent.parent / "templates"
    if (repo_templates / "numpy" / "module.py.j2").is_file():
        return repo_templates
    from importlib import resources  # (costs a warm run 8 ms: only when installed)

    return Path(str(resources.files("bgc.templates")))
