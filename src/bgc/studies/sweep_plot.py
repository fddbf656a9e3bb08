"""The overview plots of a sweep's results (bgc.studies.sweep): each chosen output against
each swept quantity (a statistic per sample, or the fan of every run over time)."""
from __future__ import annotations

import numpy as np

from bgc.base.outdirs import out_folder, write_in
from bgc.run.plots import plain_text, pyplot


def plot_sweep(prep, ds, out_dir) -> list:
    """PNGs: each chosen output's final value (or max/min) against each swept quantity, or a
    fan of its trajectories (stat: fan). Failed instances are left out."""
    import io


    plt = pyplot()
    out_dir = out_folder(out_dir, "--plot")  # a folder, not a link to one
    spec = prep.spec
    outs = spec.plot_outputs or prep.outputs[:3]
    ok = ds["status"].values == 0
    files = []

    def ylab(o, comp):
        u = spec.plot_units.get(o)
        return plain_text(f"{comp} [{u}]" if u
                          else f"{comp} [units not given: sweep plot units]")

    def xlab(label):
        pid = prep.params.get(label)
        u = prep.param_units.get(pid, "") if pid else ""
        return plain_text(f"{label} [{u}]" if u else (f"{label} [as the state]" if pid is None
                                                       else f"{label} [-]"))

    for o in outs:
        arr = ds[o].values  # (S, *shape, T)
        comps = arr.reshape(arr.shape[0], -1, arr.shape[-1])
        names = [o] if comps.shape[1] == 1 else [f"{o}[{j}]" for j in range(comps.shape[1])]
        if spec.plot_stat == "fan":
            fig, ax = plt.subplots(figsize=(7.2, 4.4))
            t = ds["time"].values
            for j, nm in enumerate(names[:3]):
                for s in np.nonzero(ok)[0]:
                    ax.plot(t, comps[s, j], lw=0.7, alpha=0.5,
                            color=f"C{j}", label=nm if s == np.nonzero(ok)[0][0] else None)
            ax.set_xlabel("time [s]")
            ax.set_ylabel(ylab(o, o))
            ax.set_title(plain_text(f"{prep.scene_name}: {o}, {int(ok.sum())} instances"))
            ax.legend(fontsize=8)
        else:
            labels = list(prep.values)
            fig, axes = plt.subplots(1, len(labels), squeeze=False,
                                     figsize=(3.6 * len(labels) + 1, 3.8))
            red = {"final": lambda v: v[..., -1], "max": lambda v: np.max(v, axis=-1),
                   "min": lambda v: np.min(v, axis=-1)}[spec.plot_stat]
            vals = red(comps)
            for ax, label in zip(axes[0], labels):
                x = ds[label].values
                for j, nm in enumerate(names[:6]):
                    ax.plot(x[ok], vals[ok, j], "o", ms=3.5, alpha=0.7, label=nm)
                if (~ok).any():
                    for xv in x[~ok]:
                        ax.axvline(xv, color="r", lw=0.6, alpha=0.4)
                ax.set_xlabel(xlab(label))
                ax.set_ylabel(ylab(o, f"{spec.plot_stat} {o}"))
                if len(names) > 1:
                    ax.legend(fontsize=7)
            fig.suptitle(plain_text(f"{prep.scene_name}: {spec.plot_stat} {o} against the swept "
                                "values" + (" (red: failed instances)" if (~ok).any() else "")))
        fig.tight_layout()
        buf = io.BytesIO()
        fig.savefig(buf, format="png")
        plt.close(fig)
        files.append(write_in(out_dir, f"{prep.scene_name}_sweep_{o}.png", buf.getvalue(),
                              getattr(prep, "inputs", None), "--plot"))
    return files
