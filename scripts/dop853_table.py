"""Write templates/c/runtime/bgc_dop853_tab.h: the coefficients of Dormand and Prince's
explicit Runge-Kutta method of order 8 with embedded 5th- and 3rd-order error estimates and a
7th-order dense output (DOP853: Hairer, Norsett and Wanner, Solving ODEs I, sec. II.10).

The numbers are the published method's; they are taken from scipy (a dependency of bgc), which
tabulates them, so that the C runtime and scipy's DOP853 integrate with the same method. Run
from the repository's root; the header is committed, and tests/test_c_dop853.py checks that it
still matches.
"""
from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "templates" / "c" / "runtime" / "bgc_dop853_tab.h"


def _row(values) -> str:
    return "{" + ", ".join(repr(float(v)) for v in values) + "}"


def header() -> str:
    from scipy.integrate._ivp import dop853_coefficients as k

    lines = ["/* DOP853's coefficients (Dormand & Prince; Hairer, Norsett & Wanner, Solving ODEs I,",
             " * sec. II.10): written by scripts/dop853_table.py, do not edit. A: stage matrix of",
             " * the 12 stages and the 3 extra stages of the dense output; B: weights; C: nodes;",
             " * E3, E5: the 3rd- and 5th-order error estimators (13 terms, the last the rhs at the",
             " * step's end); D: the dense output's coefficients of the stages (4 x 16). */",
             f"#define DOP_STAGES {k.N_STAGES}", f"#define DOP_STAGES_EXT {k.N_STAGES_EXTENDED}",
             f"static const double DOP_A[{k.N_STAGES_EXTENDED}][{k.N_STAGES_EXTENDED}] = {{"]
    lines += [f"    {_row(r)}," for r in k.A]
    lines += ["};", f"static const double DOP_B[{k.N_STAGES}] = {_row(k.B)};",
              f"static const double DOP_C[{k.N_STAGES_EXTENDED}] = {_row(k.C)};",
              f"static const double DOP_E3[{k.N_STAGES + 1}] = {_row(k.E3)};",
              f"static const double DOP_E5[{k.N_STAGES + 1}] = {_row(k.E5)};",
              f"static const double DOP_D[4][{k.N_STAGES_EXTENDED}] = {{"]
    lines += [f"    {_row(r)}," for r in k.D]
    lines += ["};", ""]
    return "\n".join(lines)


if __name__ == "__main__":
    text = header()
    if "--check" in sys.argv:
        sys.exit(0 if OUT.read_text() == text else 1)
    OUT.write_text(text)
    print(f"wrote {OUT}")
