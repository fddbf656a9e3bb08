"""Regenerate every golden module: generated/<name>.py from each model in models/, and the C
sources of a few small models under generated/c/<name>/.

Run `python scripts/regenerate.py` after a reviewed change to bgc's code generation, then
review `git diff generated/` before committing. `python scripts/regenerate.py fourbar_rigid ...`
regenerates only the models of those file stems (models/<stem>.yaml).
"""
from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "src"))

from bgc.base.outfiles import write_output  # noqa: E402
from bgc.run.driver import compile_file  # noqa: E402

#: models whose generated C sources are golden files too (small: the C printer's reference)
C_GOLDEN = ("msd", "dc_motor")


def main() -> None:
    only = set(sys.argv[1:])
    for model in sorted((ROOT / "models").glob("*.yaml")):
        if only and model.stem not in only:
            continue
        c = compile_file(model)
        out = ROOT / "generated" / f"{c.model.name}.py"
        write_output(out, c.source)
        print(f"{model.relative_to(ROOT)} -> {out.relative_to(ROOT)} "
              f"({len(c.equations.states)} states)")
        if model.stem in C_GOLDEN:
            from bgc.backends.load import c_files

            files, _ = c_files(c)
            for name, text in files.items():
                write_output(ROOT / "generated" / "c" / c.model.name / name, text)
            print(f"  C sources -> generated/c/{c.model.name}/ ({', '.join(sorted(files))})")


if __name__ == "__main__":
    main()
