"""PNG figures of a simulation: outputs against time, 3-D paths, loci of unit vectors.

Every output array has time on its last axis. Three kinds of figure, chosen by a scene's
``plots`` list (kind, outputs, labels, title):

* ``time``: one panel per output, stacked on a shared time axis (angles that swing by 0.07 rad
  and by 1 rad stay readable side by side); vector outputs draw every component in their panel.
* ``path3d``: 3-vector outputs as curves, in a 3-D view and seen from above (X-Y), on equal
  scales, so a circle looks like a circle and the gap between two paths is visible.
* ``loci``: the tips of a rotation matrix's three columns (unit vectors), one panel each, with
  equal scales on the three axes.
"""
from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from bgc.base.errors import Coord, ModelError
from bgc.base.outfiles import write_output


def pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams.update({"figure.dpi": 110, "axes.grid": True, "grid.alpha": 0.3,
                         "font.size": 9, "axes.formatter.useoffset": False,
                         "axes.formatter.limits": (-3, 4),
                         "axes.unicode_minus": False})
    return plt


def _components(name, arr):
    """(label, series over time) for every component of an output, time on the last axis."""
    arr = np.asarray(arr)
    if arr.ndim == 1:
        return [(name, arr)]
    flat = arr.reshape(-1, arr.shape[-1])
    shape = arr.shape[:-1]
    out = []
    for k, row in enumerate(flat):
        idx = np.unravel_index(k, shape)
        out.append((f"{name}[{','.join(map(str, idx))}]", row))
    return out


def plain_text(text) -> str:
    """Text from a model or scene shown as it is written: matplotlib would read ``$...$`` as
    mathtext (and fail on a malformed formula), so every dollar sign is escaped."""
    return str(text).replace("$", r"\$")


def _label(labels, k, default):
    return plain_text(labels[k] if k < len(labels) else default)


def _with_unit(label, unit):
    return f"{plain_text(label)} [{plain_text(unit)}]" if unit else plain_text(label)


def plot_time(t, y, names, path, title="", labels=(), units=None):
    plt = pyplot()
    fig = figure_time(t, y, names, title, labels, units)
    fig.savefig(path, format="png")
    plt.close(fig)


def figure_time(t, y, names, title="", labels=(), units=None):
    """The time figure (not yet saved): one panel per output, each labelled with its unit
    (``units``: the module's OUTPUT_UNITS, declared or inferred from the checked dimensions),
    time in s."""
    plt = pyplot()
    fig, axes = plt.subplots(len(names), 1, sharex=True, squeeze=False,
                             figsize=(7.5, 1.2 + 1.75 * len(names)))
    for k, (name, ax) in enumerate(zip(names, axes[:, 0])):
        comps = _components(name, y[name])
        for lab, series in comps:
            ax.plot(t, series, lw=1.4, label=lab)
        ax.set_ylabel(_with_unit(_label(labels, k, name), (units or {}).get(name, "")))
        if len(comps) > 1:
            ax.legend(loc="best", fontsize=7, ncol=min(len(comps), 3))
    axes[-1, 0].set_xlabel("t [s]")
    fig.suptitle(plain_text(title or ", ".join(names)))
    fig.tight_layout()
    return fig


def _equal_3d(ax, pts):
    """Equal scales on the three axes of a 3-D plot around the points (3, N)."""
    lo, hi = pts.min(axis=1), pts.max(axis=1)
    mid = (lo + hi) / 2  # (a path that hardly moves still gets a readable range)
    half = max(float(np.max(hi - lo)) / 2, 1e-3 * float(np.max(np.abs(mid))), 1e-12)
    ax.set_xlim(mid[0] - half, mid[0] + half)
    ax.set_ylim(mid[1] - half, mid[1] + half)
    ax.set_zlim(mid[2] - half, mid[2] + half)
    ax.set_box_aspect((1, 1, 1))
    from matplotlib.ticker import MaxNLocator

    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
        axis.set_major_locator(MaxNLocator(4))


_STYLES = ["--", ":", "-", "-."]


def figure_path3d(t, y, names, title="", labels=(), units=None):
    """The path3d figure (not yet saved): a 3-D view and the view from above. Earlier paths
    are drawn over later ones (the last, usually the actual path, is the widest and lies
    underneath, half transparent), so a path that follows another closely stays visible."""
    plt = pyplot()
    fig = plt.figure(figsize=(11.5, 5.4))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    top = fig.add_subplot(1, 2, 2)
    for k, name in enumerate(names):
        a = np.asarray(y[name]).reshape(3, -1)
        last = k == len(names) - 1
        kw = dict(lw=3.0 if last else 1.4, alpha=0.55 if last else 1.0,
                  zorder=len(names) - k + 1, label=_label(labels, k, name))
        line, = ax.plot(a[0], a[1], a[2], _STYLES[k % 4], **kw)
        top.plot(a[0], a[1], _STYLES[k % 4], color=line.get_color(), **kw)
        top.plot(a[0, :1], a[1, :1], "o", ms=4, color=line.get_color(), zorder=len(names) + 2)
    allpts = np.concatenate([np.asarray(y[n]).reshape(3, -1) for n in names], axis=1)
    _equal_3d(ax, allpts)
    u = {(units or {}).get(n, "") for n in names}
    u = u.pop() if len(u) == 1 else ""  # one unit for all paths: on the axes
    u = u or "unit of the outputs"
    _axes_3d(ax, u)
    ax.set_title("3-D view")
    top.set_aspect("equal", adjustable="datalim")
    top.set_xlabel(_with_unit("X0", u))
    top.set_ylabel(_with_unit("Y0", u))
    top.set_title("seen from above (dots: start)")
    top.legend(loc="best", fontsize=8)  # on the flat view: no 3-D line hides an entry
    fig.suptitle(plain_text(title or "path"))
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 0.94))
    return fig


def _axes_3d(ax, unit):
    """X0, Y0, Z0 with the unit, the labels kept inside the figure (padded, smaller ticks)."""
    ax.set_xlabel(_with_unit("X0", unit), labelpad=8)
    ax.set_ylabel(_with_unit("Y0", unit), labelpad=8)
    ax.set_zlabel(_with_unit("Z0", unit), labelpad=8)
    ax.tick_params(labelsize=7)
    ax.set_box_aspect((1, 1, 1), zoom=0.85)  # room for the z label inside the panel


def plot_path3d(t, y, names, path, title="", labels=(), units=None):
    plt = pyplot()
    fig = figure_path3d(t, y, names, title, labels, units)
    fig.savefig(path, format="png")
    plt.close(fig)


def figure_loci(t, y, names, title="", labels=(), units=None):
    """The loci figure (not yet saved): the tips of the three columns of a rotation matrix
    (unit vectors: dimensionless, "[-]" unless the output has a unit)."""
    plt = pyplot()
    (name,) = names[:1]
    R = np.asarray(y[name])
    fig = plt.figure(figsize=(13, 5.0))
    cols = labels or ("i", "j", "k")
    unit = (units or {}).get(name, "") or "-"
    for c in range(3):
        ax = fig.add_subplot(1, 3, c + 1, projection="3d")
        v = R[:, c, :]
        ax.plot(v[0], v[1], v[2], lw=1.4)
        ax.scatter([v[0, 0]], [v[1, 0]], [v[2, 0]], color="green", s=14, label="start")
        ax.scatter([v[0, -1]], [v[1, -1]], [v[2, -1]], color="red", s=14, label="end")
        _equal_3d(ax, v)
        _axes_3d(ax, unit)
        ax.set_title(plain_text(f"unit vector {cols[c]}\n(column {c + 1} of {name})"), fontsize=9)
        ax.legend(fontsize=7, loc="upper left")
    fig.suptitle(plain_text(title or f"loci of the unit vectors of {name}"))
    fig.subplots_adjust(left=0.02, right=0.96, bottom=0.04, top=0.80, wspace=0.15)
    return fig


def plot_loci(t, y, names, path, title="", labels=(), units=None):
    """Loci of the columns of a rotation matrix output (unit vectors)."""
    plt = pyplot()
    fig = figure_loci(t, y, names, title, labels, units)
    fig.savefig(path, format="png")
    plt.close(fig)


#: What each kind of figure needs of its outputs' shapes (without the time axis).
_NEEDS = {"path3d": ((3,), "a 3-vector"), "loci": ((3, 3), "a 3x3 matrix (a rotation)")}


def check_plots(scene, output_shapes: dict) -> None:
    """Every plot of the scene can be drawn from the module's outputs: a located error (the
    plot's place in the scene) otherwise, before anything is simulated or written."""
    for pl in scene.plots:
        if pl.kind not in ("time", *_NEEDS):
            raise ModelError(pl.coord, f"plot: unknown kind {pl.kind!r} (time, path3d, loci)")
        if not pl.outputs:
            raise ModelError(pl.coord, "plot: names no outputs")
        if pl.kind == "loci" and len(pl.outputs) != 1:
            raise ModelError(pl.coord, "plot: a loci plot shows one output (a 3x3 rotation)")
        need = _NEEDS.get(pl.kind)
        for o in pl.outputs:
            shape = tuple(output_shapes.get(o, ()))
            if need is not None and shape != need[0]:
                got = "a scalar" if not shape else "x".join(map(str, shape))
                raise ModelError(pl.coord, f"plot: a {pl.kind} plot needs {need[1]} for each "
                                           f"output; output {o!r} is {got}")


def _name(outdir: Path, fname: str) -> Path:
    """outdir/fname, where fname must be a plain file name (scene and output names are)."""
    if Path(fname).name != fname or fname.startswith("."):
        raise ModelError(None, f"plot file name {fname!r} is not a plain file name")
    return outdir / fname


def _png(fn, *args, **kw) -> bytes:
    buf = io.BytesIO()
    fn(*args[:3], buf, *args[3:], **kw)
    return buf.getvalue()


def render_plots(scene, t, y, units=None) -> list[tuple[str, bytes]]:
    """(file name, PNG bytes) of each plot of the scene (or one per output when it names
    none), drawn in memory: nothing is written until every figure has been drawn, and every
    file name is checked before the first is drawn.
    ``units``: output name -> unit for the axes (the module's OUTPUT_UNITS)."""
    if not scene.plots:
        names = _plain_names(scene, [f"{scene.name}_{name}.png" for name in y])
        return [(fname, _png(plot_time, t, y, [name], units=units))
                for fname, name in zip(names, y)]
    check_plots(scene, {k: np.shape(v)[:-1] for k, v in y.items()})
    fns = {"time": plot_time, "path3d": plot_path3d, "loci": plot_loci}
    names = _plain_names(scene, [f"{scene.name}_{k + 1}_{pl.kind}.png"
                                 for k, pl in enumerate(scene.plots)])
    return [(fname, _png(fns[pl.kind], t, y, list(pl.outputs), pl.title, pl.labels,
                         units=units))
            for fname, pl in zip(names, scene.plots)]


def _plain_names(scene, fnames: list[str]) -> list[str]:
    """The plots' file names, each a plain file name (no folder, not hidden), else one
    located error at the scene, before anything is drawn or written: a scene file's name
    (its stem names the plots unless the scene says ``name:``) such as '.hidden.yaml'."""
    for fname in fnames:
        if Path(fname).name != fname or fname.startswith("."):
            where = Coord(str(getattr(scene, "file", "") or scene.name), 1, 1)
            raise ModelError(where, f"plot file name {fname!r} is not a plain file name; give "
                                    "the scene a name (name: ...)")
    return fnames


def write_plots(scene, t, y, outdir, inputs=None, rendered=None, units=None) -> list[Path]:
    """The scene's plots as PNGs in ``outdir`` (created if missing), each through the checked
    writer (bgc.base.outfiles). ``rendered``: the figures of :func:`render_plots`, if drawn."""
    # lazy: the compile path, which a warm run never loads
    from bgc.base.outdirs import out_folder

    figures = render_plots(scene, t, y, units) if rendered is None else rendered
    outdir = out_folder(outdir, "--plot")  # a folder, not a link to one
    return [write_output(_name(outdir, fname), data, inputs, "plot")
            for fname, data in figures]
