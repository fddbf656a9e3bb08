"""The reports of a work-precision study (bgc.studies.accuracy): the runs as CSV, a markdown
summary (the cheapest run reaching each error, every run, the Jacobian comparison) and the
work-precision plots; every file through bgc's one checked writer."""
from __future__ import annotations

import csv
import io
import math
from dataclasses import replace
from pathlib import Path

from bgc.base.outdirs import out_folder
from bgc.base.outfiles import prepare_folder, write_output
from bgc.run.plots import pyplot
from bgc.studies.runs import JAC_MODES, Run, Study


def md_cell(text: str) -> str:
    """Text for one markdown table cell: its pipes escaped (messages quote |eigenvalue|) and
    line breaks folded, so that the row keeps its columns."""
    return " ".join(str(text).split()).replace("|", "\\|")



def _fmt(v, spec=".2e"):
    if isinstance(v, str):
        return v
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return ""
    return format(v, spec)


def write_csv(st: Study, path, inputs=None):
    outs = st.setup.outputs
    cols = ["kind", "method", "jacobian", "rtol", "atol", "status", "message", "wall_s",
            "n_repeats", "walls_s", "nsteps", "nfev", "njev", "nlu", "err", "err_output",
            "err_abs_max", "final_err", "final_err_state"] + [f"err_abs_{o}" for o in outs]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    rows = []
    for ref in st.refs:
        rows.append(Run(ref.method, ref.rtol, ref.atol, "analytic", "ok", "reference",
                        ref.wall, (ref.wall,), ref.stats["nfev"], ref.stats["njev"],
                        ref.stats["nlu"], ref.stats["nsteps"], kind="reference"))
    rows[-1] = replace(rows[-1], message="reference (errors: against the first)",
                       **{k: st.agreement[k] for k in ("err", "err_output", "err_abs",
                                                       "err_abs_max", "final_err",
                                                       "final_err_state")})
    for r in rows + st.runs + st.jac_runs:
        w.writerow([r.kind, r.method, r.jac, f"{r.rtol:g}", f"{r.atol:g}", r.status, r.message,
                    _fmt(r.wall, ".6g"), len(r.walls), " ".join(f"{x:.4g}" for x in r.walls),
                    r.nsteps, r.nfev, r.njev, r.nlu, _fmt(r.err, ".6e"), r.err_output,
                    _fmt(r.err_abs_max, ".6e"), _fmt(r.final_err, ".6e"), r.final_err_state]
                   + [_fmt(r.err_abs.get(o, math.nan), ".6e") for o in outs])
    _write(path, buf.getvalue(), inputs)


def _write(path, data, inputs=None):
    """Every file of the study goes through bgc's one checked writer; ``inputs`` (a
    bgc.base.outfiles.Inputs: the scene, the model, its imports) are never replaced."""
    write_output(path, data, inputs, "accuracy output")


def cheapest(runs, target):
    ok = [r for r in runs if r.status == "ok" and r.err <= target]
    return min(ok, key=lambda r: r.wall) if ok else None


def skipped_lines(st: Study) -> list[str]:
    """What the study left out and why, one line per sweep that stopped early (a method over
    its tolerances; for the Jacobian comparison, a method in one Jacobian mode), then the
    notes on the references and on runs that were not repeated."""
    groups: dict = {}
    for r in list(st.runs) + list(st.jac_runs):
        if r.status == "skipped":
            key = (r.kind, r.method, r.jac if r.kind == "jacobian" else "", r.message)
            groups.setdefault(key, []).append(r.rtol)
    out = []
    for (kind, method, jac, msg), tols in groups.items():
        what = f"{method} ({jac} Jacobian, the Jacobian comparison)" if kind == "jacobian" \
            else method
        span = (f"rtol {max(tols):.0e}" if len(tols) == 1
                else f"rtol {max(tols):.0e} to {min(tols):.0e} ({len(tols)} runs)")
        out.append(f"{what}: {span} {msg}")
    s = st.settings
    for note in (s.get("ref_note"), s.get("check_note")):
        if note:
            out.append(f"references: {note}")
    lr = s.get("long_run", math.inf)
    once = [r for r in list(st.runs) + list(st.jac_runs)
            if r.status == "ok" and len(r.walls) == 1 and r.wall > lr and s["repeats"] > 1]
    if once:
        out.append(f"repeats: {len(once)} runs longer than {lr:g} s ran once, not "
                   f"{s['repeats']} times")
    return out


def write_markdown(st: Study, path, images=(), inputs=None):
    s, se = st.settings, st.setup
    a = st.agreement
    L = []
    L.append(f"# Work-precision study: `{se.name}`\n")
    L.append(f"Scene `{se.scene.file}`, model `{Path(se.scene.model_path).name}`, "
             f"{se.module.N_STATES} states; t = {se.t_span[0]:g}..{se.t_span[1]:g} s"
             + (" (shortened from the scene's "
                f"{se.scene.t_span[1]:g} s)" if se.t_span[1] < se.scene.t_span[1] else "")
             + f", errors sampled at {len(se.t_eval)} points; breakpoints "
             f"{list(se.breakpoints) or 'none'}.\n")
    L.append(f"* Tolerances: rtol as listed, **atol = rtol x {s['atol_scale']:g}** "
             f"(the scene's atol/rtol ratio unless `--atol-scale` was given).")
    L.append(f"* Stiffness index max|eig J| (t0 and along a pilot run) x span = "
             f"{st.stiffness_index:.3g}: "
             f"{'stiff' if st.stiff else 'not stiff'}.")
    L.append(f"* Reference: {s['ref_methods'][0]} at rtol {s['ref_rtol']:g}, atol "
             f"{s['ref_atol']:g}, analytic Jacobian ({st.refs[0].wall:.1f} s); checked with "
             f"{st.refs[1].method} at rtol {st.refs[1].rtol:g}, atol {st.refs[1].atol:g} "
             f"({st.refs[1].wall:.1f} s)." + (f" Note: {s['check_note']}." if s.get(
                 "check_note") else ""))
    L.append(f"* **Reference agreement: {a['err']:.2e}** (overall output error, largest in "
             f"`{a['err_output']}`), final state {a['final_err']:.2e}. Errors near or below "
             "this are not resolved.")
    L.append("* Error (dimensionless): max over the outputs of max_t |y - y_ref| / "
             "(max_t |y_ref| + atol scale); the max abs error per output, in its units, is "
             "in the CSV (`err_abs_*`). Final-state error: max_i |x_i(T) - x_ref,i(T)| / "
             "(max_t |x_ref,i| + atol scale).")
    L.append(f"* Wall time: median of up to {s['repeats']} runs within a {s['budget']:g} s "
             "budget per (method, tolerance), each in a forked child with a hard limit"
             + (f"; a run over {s['long_run']:g} s runs once" if math.isfinite(
                 s.get("long_run", math.inf)) else "")
             + (f"; each sweep over the tolerances stops once it has taken "
                f"{s['sweep_budget']:.3g} s" if math.isfinite(
                 s.get("sweep_budget") or math.inf) else "")
             + (f"; all runs together within {s['study_budget']:g} s" if math.isfinite(
                 s.get("study_budget", math.inf)) else "") + "; "
             "'steps' counts accepted steps; rhs counts include finite-difference "
             "columns; 'Jac' counts Jacobian "
             "evaluations (analytic or finite-difference).\n")
    skipped = skipped_lines(st)
    if skipped:
        L.append("## What was skipped, and why\n")
        L += [f"* {md_cell(line)}" for line in skipped]
        L.append("")
    L.append("## Cheapest run reaching an error\n")
    L.append("| error <= | method | rtol | error | wall [s] | steps | rhs | Jac |")
    L.append("|---|---|---|---|---|---|---|---|")
    for target in (1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8):
        if target < a["err"]:
            continue
        r = cheapest(st.runs, target)
        if r is None:
            L.append(f"| {target:.0e} | none | | | | | | |")
        else:
            L.append(f"| {target:.0e} | {r.method} | {r.rtol:.0e} | {r.err:.2e} | "
                     f"{r.wall:.3g} | {r.nsteps} | {r.nfev} | {r.njev} |")
    L.append("")
    L.append("## All runs (analytic Jacobian for the implicit methods)\n")
    L.append("| method | rtol | atol | status | error | worst output | max abs error "
             "| final-state error | wall [s] (runs) | steps | rhs | Jac | LU |")
    L.append("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in st.runs:
        if r.status == "ok":
            L.append(f"| {r.method} | {r.rtol:.0e} | {r.atol:.0e} | ok | {r.err:.2e} | "
                     f"{r.err_output} | {r.err_abs[r.err_output]:.2e} | {r.final_err:.2e} | "
                     f"{r.wall:.3g} ({len(r.walls)}) | {r.nsteps} | {r.nfev} | {r.njev} | "
                     f"{r.nlu} |")
        else:
            L.append(f"| {r.method} | {r.rtol:.0e} | {r.atol:.0e} | **{r.status}** | "
                     f"{md_cell(r.message)} | | | | | | | | |")
    L.append("")
    if st.jac_runs:
        L.append("## Analytic Jacobian against finite differences\n")
        L.append("Sparse FD: `simulate(jac=False)`, scipy's grouped differences over "
                 "JAC_SPARSITY; dense FD: the same without the sparsity pattern (one rhs per "
                 "state per Jacobian). Ratios are FD / analytic, measured back to back.\n")
        L.append("| method | rtol | Jacobian | status | error | wall [s] | wall ratio | steps "
                 "| rhs | Jac | rhs ratio | LU |")
        L.append("|---|---|---|---|---|---|---|---|---|---|---|---|")
        base = {}
        for r in st.jac_runs:
            if r.jac == "analytic":
                base[(r.method, r.rtol)] = r
            b = base.get((r.method, r.rtol))
            if r.status != "ok":
                L.append(f"| {r.method} | {r.rtol:.0e} | {r.jac} | **{r.status}** | "
                         f"{md_cell(r.message)} | | | | | | | |")
                continue
            ok = b is not None and b.status == "ok"
            wr = f"{r.wall / b.wall:.2f}" if ok else ""
            fr = f"{r.nfev / b.nfev:.2f}" if ok and b.nfev else ""
            L.append(f"| {r.method} | {r.rtol:.0e} | {r.jac} | ok | {r.err:.2e} | "
                     f"{r.wall:.3g} ({len(r.walls)}) | {wr} | {r.nsteps} | {r.nfev} | {r.njev} | "
                     f"{fr} | "
                     f"{r.nlu} |")
        L.append("")
    for img in images:
        L.append(f"![{Path(img).stem}]({Path(img).name})\n")
    _write(path, "\n".join(L), inputs)


_MARK = {"RK45": "o", "RK23": "^", "DOP853": "s", "Radau": "D", "BDF": "v", "LSODA": "P",
         "Rodas4": "X"}


def _finish(plt, fig, ax, agree, xlabel, title, path, inputs=None):
    """Log-log axes of error against cost, the reference's resolution as a floor; saved."""
    ax.axhline(max(agree, 1e-300), color="k", ls=":", lw=1,
               label=f"reference agreement {agree:.1e}")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("max output error (relative to peak)")
    ax.set_title(title)
    ax.legend(fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    _write(path, buf.getvalue(), inputs)
    return path


def plot_study(st: Study, out_dir, inputs=None) -> list:
    plt = pyplot()
    out_dir = prepare_folder(out_dir, "--out")
    files = []
    agree = st.agreement["err"]
    for xkey, xlabel, suffix in (("wall", "wall time [s] (median)", "wp_time"),
                                 ("nfev", "rhs evaluations", "wp_rhs")):
        fig, ax = plt.subplots(figsize=(7.2, 4.8))
        for m in st.settings["methods"]:
            rs = [r for r in st.runs if r.method == m and r.status == "ok"]
            bad = [r for r in st.runs if r.method == m and r.status != "ok"]
            lab = m + (f" ({len(bad)} over budget/failed)" if bad else "")
            if not rs:
                ax.plot([], [], marker=_MARK.get(m, "o"), ls="-", label=lab + ": no result")
                continue
            xs = [getattr(r, xkey) for r in rs]
            ys = [max(r.err, 1e-300) for r in rs]
            line, = ax.plot(xs, ys, marker=_MARK.get(m, "o"), ms=5, lw=1.4, label=lab)
            for r, x_, y_ in zip(rs, xs, ys):
                if r.rtol in (rs[0].rtol, rs[-1].rtol):
                    ax.annotate(f"{r.rtol:.0e}", (x_, y_), textcoords="offset points",
                                xytext=(4, 3), fontsize=7, color=line.get_color())
        files.append(_finish(plt, fig, ax, agree, xlabel,
                             f"{st.setup.name}: work-precision, t = {st.setup.t_span[0]:g}.."
                             f"{st.setup.t_span[1]:g} s (labels: rtol)",
                             out_dir / f"{st.setup.name}_{suffix}.png", inputs))
    if st.jac_runs:
        fig, ax = plt.subplots(figsize=(7.2, 4.8))
        styles = {"analytic": "-", "sparse-fd": "--", "dense-fd": ":"}
        colors = {}
        for m in st.settings["jac_methods"]:
            for mode in JAC_MODES:
                rs = [r for r in st.jac_runs if r.method == m and r.jac == mode
                      and r.status == "ok"]
                if not rs:
                    continue
                kw = {"color": colors[m]} if m in colors else {}
                line, = ax.plot([r.wall for r in rs], [max(r.err, 1e-300) for r in rs],
                                marker=_MARK.get(m, "o"), ls=styles[mode], lw=1.4, ms=5,
                                label=f"{m}, {mode}", **kw)
                colors.setdefault(m, line.get_color())
        files.append(_finish(plt, fig, ax, agree, "wall time [s] (median)",
                             f"{st.setup.name}: analytic Jacobian vs finite differences (rtol "
                             f"{', '.join(f'{t:.0e}' for t in st.settings['jac_tols'])})",
                             out_dir / f"{st.setup.name}_jacobian.png", inputs))
    return files


def write_all(st: Study, out_dir, inputs=None) -> list:
    out_dir = out_folder(out_dir, "--out")  # a folder, not a link to one
    imgs = plot_study(st, out_dir, inputs)
    csvf = out_dir / f"{st.setup.name}_runs.csv"
    md = out_dir / f"{st.setup.name}_accuracy.md"
    write_csv(st, csvf, inputs)
    write_markdown(st, md, imgs, inputs)
    return [csvf, md] + imgs


# --------------------------------------------------------------------------------------------
# parameter sweeps (the 3R2S's penalty stiffness)
