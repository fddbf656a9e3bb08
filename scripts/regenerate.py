"""Regenerate every golden module: generated/<name>.py from each model in models/.

Run `python scripts/regenerate.py` after a reviewed change to bgc's code generation, then
review `git diff generated/` before committing.
"""
from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "src"))

from bgc.compiler import compile_file, write_atomic  # noqa: E402


def main() -> None:
    for model in sorted((ROOT / "models").glob("*.yaml")):
        c = compile_file(model)
        out = ROOT / "generated" / f"{c.model.name}.py"
        write_atomic(out, c.source)
        print(f"{model.relative_to(ROOT)} -> {out.relative_to(ROOT)} "
              f"({len(c.equations.states)} states)")


if __name__ == "__main__":
    main()
