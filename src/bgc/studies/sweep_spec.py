"""The ``sweep:`` section of a scene (bgc.studies.sweep): its entries read with located errors,
and the samples they make (grids and lists as axes, random entries as one Latin-hypercube or
random axis, combined by ``cross`` or ``zip``). The section's format is in the docstring of
:mod:`bgc.studies.sweep` and in docs/model-format.md, "Sweeps"."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from bgc.base.errors import Coord, ModelError
from bgc.base.limits import LIMITS
from bgc.base.safeio import read_text_bounded
from bgc.format.reader import Reader, check_name, require

MAX_SAMPLES = 1_000_000
GRIDS = ("linspace", "logspace", "values")
RANDOM = ("uniform", "normal", "loguniform")
COMBINE = ("cross", "zip")
SAMPLE_METHODS = ("lhs", "random")
PLOT_STATS = ("final", "max", "min", "fan")




@dataclass(frozen=True)
class Entry:
    """One swept quantity: kind 'param' or 'state', its name, its rule and arguments."""

    kind: str
    name: str
    rule: str
    args: tuple
    coord: Coord

    @property
    def label(self) -> str:
        """Its coordinate name in the results (states: x0_<name>)."""
        return self.name if self.kind == "param" else f"x0_{self.name}"


@dataclass(frozen=True)
class SweepSpec:
    entries: tuple[Entry, ...]
    combine: str = "cross"
    samples: int | None = None
    method: str = "lhs"
    seed: int = 0
    coord: Coord | None = None
    plot_outputs: tuple[str, ...] = ()
    plot_stat: str = "final"
    plot_units: dict = field(default_factory=dict)
    plot_coord: Coord | None = None


# ---------------------------------------------------------------------------------------------
# parsing


def parse_sweep(path) -> SweepSpec | None:
    """The scene file's ``sweep:`` section (None when it has none), validated with places."""
    path = str(path)
    text = read_text_bounded(path, None, "scene file", LIMITS.scene_bytes)
    r = Reader(path, text)
    root = r.compose()
    if root is None:
        raise ModelError(Coord(path, 1, 1), "the scene file is empty")
    top = r.mapping(root, "the scene")
    if "sweep" not in top:
        return None
    kn, node = top["sweep"]
    sm = r.mapping(node, "sweep")
    require(r, sm, node, ("parameters", "initial", "combine", "samples", "method", "seed",
                           "plot"), "sweep")
    entries = []
    for key, kind in (("parameters", "param"), ("initial", "state")):
        if key not in sm:
            continue
        for name, (ekn, evn) in r.mapping(sm[key][1], f"sweep {key}").items():
            entries.append(_entry(r, kind, name, ekn, evn))
    if not entries:
        raise ModelError(r.coord(node), "sweep: name at least one parameter (parameters:) or "
                                        "initial state (initial:) to sweep")
    combine = "cross"
    if "combine" in sm:
        combine = r.string(sm["combine"][1], "combine")
        if combine not in COMBINE:
            raise ModelError(r.coord(sm["combine"][1]), f"sweep combine {combine!r}: one of "
                                                        f"{', '.join(COMBINE)}")
    randoms = [e for e in entries if e.rule in RANDOM]
    samples = None
    if "samples" in sm:
        samples = r.integer(sm["samples"][1], "samples")
        if not 1 <= samples <= MAX_SAMPLES:
            raise ModelError(r.coord(sm["samples"][1]), f"sweep samples must lie in 1.."
                                                        f"{MAX_SAMPLES}")
        if not randoms:
            raise ModelError(r.coord(sm["samples"][1]), "sweep samples: no entry is random "
                                                        "(uniform, normal, loguniform)")
    elif randoms:
        raise ModelError(randoms[0].coord, f"sweep {randoms[0].name!r} is random: give the "
                                           "number of samples (sweep samples: N)")
    method = "lhs"
    if "method" in sm:
        method = r.string(sm["method"][1], "method")
        if method not in SAMPLE_METHODS:
            raise ModelError(r.coord(sm["method"][1]), f"sweep method {method!r}: one of "
                                                       f"{', '.join(SAMPLE_METHODS)}")
    seed = 0
    if "seed" in sm:
        seed = r.integer(sm["seed"][1], "seed")
        if seed < 0:
            raise ModelError(r.coord(sm["seed"][1]), "sweep seed must be a whole number >= 0")
    plot_outputs, plot_stat, units, pcoord = (), "final", {}, None
    if "plot" in sm:
        pn = sm["plot"][1]
        pcoord = r.coord(pn)
        pm = r.mapping(pn, "sweep plot")
        require(r, pm, pn, ("outputs", "stat", "units"), "sweep plot")
        if "outputs" in pm:
            plot_outputs = tuple(r.string(o, "output") for o in r.seq(pm["outputs"][1],
                                                                        "outputs"))
        if "stat" in pm:
            plot_stat = r.string(pm["stat"][1], "stat")
            if plot_stat not in PLOT_STATS:
                raise ModelError(r.coord(pm["stat"][1]), f"sweep plot stat {plot_stat!r}: one "
                                                         f"of {', '.join(PLOT_STATS)}")
        if "units" in pm:
            for un, (ukn, uvn) in r.mapping(pm["units"][1], "units").items():
                units[un] = r.string(uvn, f"unit of {un!r}")
    spec = SweepSpec(tuple(entries), combine, samples, method, seed, r.coord(kn),
                     plot_outputs, plot_stat, units, pcoord)
    n = _count(spec)
    if n > MAX_SAMPLES:
        raise ModelError(r.coord(kn), f"sweep: {n} samples, more than the limit "
                                      f"{MAX_SAMPLES}")
    return spec


def _entry(r, kind, name, kn, vn) -> Entry:
    where = r.coord(kn)
    for part in name.split("."):
        check_name(part, where, "parameter" if kind == "param" else "state",
                   allow_reserved=True)
    what = f"sweep {name!r}"
    m = r.mapping(vn, what)
    rules = [k for k in m if k in GRIDS + RANDOM]
    unknown = [k for k in m if k not in GRIDS + RANDOM]
    if unknown:
        raise ModelError(r.coord(m[unknown[0]][0]), f"{what}: unknown rule {unknown[0]!r} "
                                                    f"(one of {', '.join(GRIDS + RANDOM)})")
    if len(rules) != 1:
        raise ModelError(r.coord(vn), f"{what}: give exactly one of "
                                      f"{', '.join(GRIDS + RANDOM)}")
    rule = rules[0]
    rn = m[rule][1]
    rc = r.coord(rn)
    items = r.seq(rn, f"{what} {rule}")
    if rule == "values":
        vals = tuple(r.number(v, f"{what} value") for v in items)
        if not vals:
            raise ModelError(rc, f"{what}: values is an empty list")
        if len(vals) > MAX_SAMPLES:
            raise ModelError(rc, f"{what}: more than {MAX_SAMPLES} values")
        args = vals
    elif rule in ("linspace", "logspace"):
        if len(items) != 3:
            raise ModelError(rc, f"{what}: {rule} is [start, stop, count]")
        a, b = (r.number(v, f"{what} {rule}") for v in items[:2])
        cnt = r.integer(items[2], f"{what} {rule} count")
        if not 1 <= cnt <= MAX_SAMPLES:
            raise ModelError(r.coord(items[2]), f"{what}: the count must lie in 1..{MAX_SAMPLES}")
        if rule == "logspace" and not (a > 0 and b > 0):
            raise ModelError(rc, f"{what}: logspace needs positive start and stop (the values "
                                 "themselves, spaced evenly in log)")
        args = (a, b, cnt)
    else:
        if len(items) != 2:
            form = "[mu, sigma]" if rule == "normal" else "[low, high]"
            raise ModelError(rc, f"{what}: {rule} is {form}")
        a, b = (r.number(v, f"{what} {rule}") for v in items)
        if rule == "normal" and not b > 0:
            raise ModelError(rc, f"{what}: normal's sigma must be positive")
        if rule != "normal" and not b > a:
            raise ModelError(rc, f"{what}: {rule} needs low < high")
        if rule == "loguniform" and not a > 0:
            raise ModelError(rc, f"{what}: loguniform needs a positive lower bound")
        args = (a, b)
    for v in args:
        if not math.isfinite(v):
            raise ModelError(rc, f"{what}: values must be finite")
    return Entry(kind, name, rule, args, where)


def _axes(spec: SweepSpec):
    """The axes to combine, in order: (entries, length); the random entries form one axis at
    the place of the first of them."""
    axes, rand_done = [], False
    for e in spec.entries:
        if e.rule in RANDOM:
            if not rand_done:
                axes.append(([x for x in spec.entries if x.rule in RANDOM], spec.samples))
                rand_done = True
            continue
        n = len(e.args) if e.rule == "values" else e.args[2]
        axes.append(([e], n))
    return axes


def _count(spec: SweepSpec) -> int:
    axes = _axes(spec)
    if spec.combine == "zip":
        lens = {n for _, n in axes}
        if len(lens) > 1:
            desc = ", ".join(f"{'+'.join(e.name for e in es)}: {n}" for es, n in axes)
            raise ModelError(spec.coord, f"sweep combine zip: the axes differ in length "
                                         f"({desc})")
        return axes[0][1]
    return math.prod(n for _, n in axes)


def _grid(e: Entry) -> np.ndarray:
    if e.rule == "values":
        return np.array(e.args, dtype=float)
    a, b, n = e.args
    return np.linspace(a, b, n) if e.rule == "linspace" else np.geomspace(a, b, n)


def _random_block(entries, n, method, seed) -> np.ndarray:
    """(n, len(entries)) samples: a Latin hypercube (each variable's range cut into n equally
    likely strata, one sample in each, strata paired at random) or plain random draws, mapped
    through each distribution's inverse CDF."""
    from scipy.special import ndtri

    rng = np.random.default_rng(seed)
    d = len(entries)
    if method == "lhs":
        u = (np.stack([rng.permutation(n) for _ in range(d)], axis=1) + rng.random((n, d))) / n
    else:
        u = rng.random((n, d))
    u = np.clip(u, np.finfo(float).tiny, 1 - np.finfo(float).epsneg)
    out = np.empty((n, d))
    for k, e in enumerate(entries):
        a, b = e.args
        if e.rule == "uniform":
            out[:, k] = a + (b - a) * u[:, k]
        elif e.rule == "loguniform":
            out[:, k] = np.exp(np.log(a) + (np.log(b) - np.log(a)) * u[:, k])
        else:
            out[:, k] = a + b * ndtri(u[:, k])
    return out


def samples(spec: SweepSpec) -> dict:
    """label -> array of the swept values, one per sample (in the order of the entries)."""
    axes = _axes(spec)
    cols = []  # per axis: (entries, (len, n_entries) values)
    for es, n in axes:
        if es[0].rule in RANDOM:
            cols.append((es, _random_block(es, n, spec.method, spec.seed)))
        else:
            cols.append((es, _grid(es[0])[:, None]))
    total = _count(spec)
    if spec.combine == "zip":
        idx = [np.arange(total)] * len(cols)
    else:
        grids = np.meshgrid(*[np.arange(len(v)) for _, v in cols], indexing="ij")
        idx = [g.ravel() for g in grids]
    out = {}
    for (es, vals), ix in zip(cols, idx):
        for k, e in enumerate(es):
            out[e.label] = vals[ix, k]
    return {e.label: out[e.label] for e in spec.entries}
