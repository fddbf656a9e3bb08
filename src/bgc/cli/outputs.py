"""Folder outputs of the command line, through the checked writer (bgc.base.outdirs)."""
from __future__ import annotations

import io

import numpy as np

from bgc.base.outdirs import check_in, out_folder, write_in
from bgc.base.reach import run_inputs
from bgc.linear import bode_plot


def check_linear(out, mod, pairs, target, sc) -> dict:
    """Every refusal of :func:`write_linear` before anything is computed: the plan of what it
    writes (folder, inputs, file names)."""
    ins = run_inputs(sc.model_path, target) if sc is not None else run_inputs(target)
    name = getattr(mod, "__name__", "model").removeprefix("bgc_generated_")
    pngs = [(i, o, f"bode_{i}_{o}.png".replace("[", "_").replace("]", "")) for i, o in pairs]
    d = out_folder(out, "--out", create=False)
    for rel in [f"{name}_linear.npz"] + [png for _, _, png in pngs]:
        check_in(d, rel, ins, "--out")
    return {"out": out, "ins": ins, "npz": f"{name}_linear.npz", "pngs": pngs}


def write_linear(plan: dict, mod, lin, t, x, prog):
    """NAME_linear.npz and the Bode PNGs into the folder of ``plan`` (:func:`check_linear`),
    through the checked writer (never over an input of the run, a link or anything but a
    regular file; atomic)."""
    ins = plan["ins"]
    d = out_folder(plan["out"], "--out")
    data = io.BytesIO()
    np.savez(data, A=lin[0], B=lin[1], C=lin[2], D=lin[3], t=t, x=x,
             states=np.array(mod.STATE_NAMES), inputs=np.array(mod.INPUT_LABELS, dtype=str),
             outputs=np.array(mod.OUTPUT_LABELS), eigenvalues=np.linalg.eigvals(lin[0]))
    prog(f"wrote {write_in(d, plan['npz'], data.getvalue(), ins, '--out')}")
    iu, ou = dict(getattr(mod, "INPUT_UNITS", {})), dict(getattr(mod, "OUTPUT_UNITS", {}))
    for i_name, o_name, png in plan["pngs"]:
        buf = io.BytesIO()
        bode_plot(buf, lin, mod.INPUT_LABELS.index(i_name), mod.OUTPUT_LABELS.index(o_name),
                  i_name, o_name, iu.get(i_name.split("[")[0], ""),
                  ou.get(o_name.split("[")[0], ""), f_range=plan.get("f_range"))
        prog(f"wrote {write_in(d, png, buf.getvalue(), ins, '--out')}")
