"""PNG figures of a simulation: outputs against time, 3-D paths, loci of unit vectors."""
from __future__ import annotations

from pathlib import Path

import numpy as np


def _mpl():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams.update({"figure.dpi": 110, "axes.grid": True, "grid.alpha": 0.3,
                         "font.size": 9})
    return plt


def _components(name, arr):
    """(label, series over time) for every component of an output, time on the last axis."""
    if arr.ndim == 1:
        return [(name, arr)]
    flat = arr.reshape(-1, arr.shape[-1])
    shape = arr.shape[:-1]
    out = []
    for k, row in enumerate(flat):
        idx = np.unravel_index(k, shape)
        out.append((f"{name}[{','.join(map(str, idx))}]", row))
    return out


def plot_time(t, y, names, path, title="", labels=()):
    plt = _mpl()
    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    k = 0
    for name in names:
        for lab, series in _components(name, y[name]):
            ax.plot(t, series, lw=1.4, label=labels[k] if k < len(labels) else lab)
            k += 1
    ax.set_xlabel("t [s]")
    ax.set_title(title or ", ".join(names))
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_path3d(t, y, names, path, title="", labels=()):
    plt = _mpl()
    fig = plt.figure(figsize=(6.5, 5.5))
    ax = fig.add_subplot(projection="3d")
    styles = ["--", ":", "-", "-."]
    for k, name in enumerate(names):
        a = y[name]
        ax.plot(a[0], a[1], a[2], styles[k % 4], lw=1.6 if k == len(names) - 1 else 1.2,
                label=labels[k] if k < len(labels) else name)
    ax.set_xlabel("X0 [m]")
    ax.set_ylabel("Y0 [m]")
    ax.set_zlabel("Z0 [m]")
    ax.set_title(title or "path")
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_loci(t, y, names, path, title="", labels=()):
    """Loci of the columns of a rotation matrix output (unit vectors)."""
    plt = _mpl()
    (name,) = names[:1]
    R = y[name]
    fig = plt.figure(figsize=(11, 3.8))
    cols = labels or ("i", "j", "k")
    for c in range(3):
        ax = fig.add_subplot(1, 3, c + 1, projection="3d")
        v = R[:, c, :]
        ax.plot(v[0], v[1], v[2], lw=1.4)
        ax.scatter([v[0, 0]], [v[1, 0]], [v[2, 0]], color="green", s=12, label="start")
        ax.scatter([v[0, -1]], [v[1, -1]], [v[2, -1]], color="red", s=12, label="end")
        ax.set_title(f"{name}: unit vector {cols[c]}")
        ax.legend(fontsize=7)
    fig.suptitle(title or f"loci of the unit vectors of {name}")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def write_plots(scene, t, y, outdir) -> list[Path]:
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    written = []
    plots = scene.plots
    if not plots:
        for name in y:
            p = outdir / f"{scene.name}_{name}.png"
            plot_time(t, y, [name], p)
            written.append(p)
        return written
    fns = {"time": plot_time, "path3d": plot_path3d, "loci": plot_loci}
    for k, pl in enumerate(plots):
        p = outdir / f"{scene.name}_{k + 1}_{pl.kind}.png"
        fns[pl.kind](t, y, list(pl.outputs), p, pl.title, pl.labels)
        written.append(p)
    return written
