"""The Zarr store of a sweep's results (bgc.studies.sweep): one dataset with a row per sample,
created with lazy placeholders and filled chunk by chunk (a region write, then the chunk's
completion flag), its attributes holding the hash of everything the results depend on so that
a store made for another sweep is refused. ``prep`` below is a
:class:`bgc.studies.sweep.Prepared`."""
from __future__ import annotations

import json
import warnings

import numpy as np

from bgc.base.errors import ModelError
from bgc.base.outdirs import mark_folder, remove_marked
from bgc.studies.sweep_folder import STORE_KIND, _zarr_entries, _zarr_own, check_store

# The store's folder holds bgc's marker file (bgc.base.outdirs.MARKER); Zarr 3 warns about it
# (not one of its objects) each time it lists the folder: seven lines on every sweep's stderr.
warnings.filterwarnings("ignore", message=r"Object at \.bgc-output is not recognized")

STATS = ("nfev", "njev", "nlu", "nsteps")
MESSAGE_WIDTH = 240  # characters of a failure message kept in the store


def chunk_bounds(n: int, chunk: int) -> list[tuple[int, int]]:
    return [(a, min(a + chunk, n)) for a in range(0, n, chunk)]


def _skeleton(prep, chunk: int, digest: str):
    """The dataset with lazy placeholders (written as metadata only) and the coordinates."""
    import dask.array as da
    import xarray as xr

    n = prep.n
    nt = int(round(abs(prep.t_span[1] - prep.t_span[0]) / prep.dt)) + 1
    t = np.linspace(prep.t_span[0], prep.t_span[1], nt)
    data = {}
    for o in prep.outputs:
        shp = prep.output_shapes[o]
        dims = ("sample",) + tuple(f"{o}_dim{k}" for k in range(len(shp))) + ("time",)
        data[o] = (dims, da.full((n,) + shp + (nt,), np.nan, chunks=(chunk,) + shp + (nt,)))
    for k in STATS:
        data[k] = ("sample", da.zeros(n, dtype=np.int64, chunks=chunk))
    data["status"] = ("sample", da.full(n, -1, dtype=np.int8, chunks=chunk))
    data["message"] = ("sample", da.full(n, "", dtype=f"<U{MESSAGE_WIDTH}", chunks=chunk))
    data["batch"] = ("sample", da.zeros(n, dtype=np.int32, chunks=chunk))
    data["chunk_wall"] = ("sample", da.full(n, np.nan, chunks=chunk))
    nc = len(chunk_bounds(n, chunk))
    data["chunk_done"] = ("chunk", np.zeros(nc, dtype=bool))
    coords = {"time": ("time", t, {"units": "s"}), "sample": np.arange(n)}
    for label, v in prep.values.items():
        unit = prep.param_units.get(prep.params.get(label, ""), "")
        coords[label] = ("sample", v, {"units": unit} if unit else {})
    ds = xr.Dataset(data, coords=coords)
    ds["status"].attrs["meaning"] = "-1 not run, 0 ok, 1 failed (see message)"
    ds["batch"].attrs["meaning"] = ("instances integrated together (their solver statistics "
                                    "are the batch's)")
    ds.attrs.update({"bgc_sweep_hash": digest, "scene": prep.scene_name, "chunk": chunk,
                     "backend": prep.backend,
                     "method": prep.method, "rtol": prep.rtol, "atol": prep.atol,
                     "swept": json.dumps(list(prep.values))})
    return ds


class SweepMismatch(ModelError):
    """The store holds another sweep's results."""


def open_or_create(prep, out, chunk: int, restart: bool = False) -> list[bool]:
    """The store at out, created if missing; its completion record (one flag per chunk).

    The store is a folder bgc marks as its own (bgc.base.outdirs.MARKER); ``restart`` empties
    only such a folder, and in it only the store's own entries (the Zarr metadata files and
    array folders): never a folder bgc did not make, nor anything else in it
    (bgc.studies.sweep_folder)."""
    import xarray as xr

    digest = prep.digest(chunk)
    out = check_store(out)
    inputs = getattr(prep, "inputs", None)
    if out.exists() and not restart and _zarr_entries(out):
        try:
            old = xr.open_zarr(out, consolidated=None)
            h = old.attrs.get("bgc_sweep_hash")
            done = [bool(v) for v in old["chunk_done"].values] if "chunk_done" in old else None
        except Exception as exc:  # noqa: BLE001
            raise ModelError(None, f"{out} exists and is not a readable sweep store ({exc}); "
                                   "remove it or pass --restart") from None
        if h != digest:
            raise SweepMismatch(None, f"{out} holds the results of another sweep (the scene, "
                                      "its sweep, the model or --chunk changed): pass --restart "
                                      "to discard them, or write to a new --out")
        return done
    if out.exists():
        remove_marked(out, STORE_KIND, _zarr_own, inputs, "--out")
    mark_folder(out, STORE_KIND, inputs, "--out")
    _skeleton(prep, chunk, digest).to_zarr(out, compute=False, mode="a", zarr_format=2,
                                           consolidated=True)
    return [False] * len(chunk_bounds(prep.n, chunk))


def write_chunk(out, res: dict, k: int, prep):
    import xarray as xr

    a, b = res["a"], res["b"]
    data = {}
    for o in prep.outputs:
        shp = prep.output_shapes[o]
        dims = ("sample",) + tuple(f"{o}_dim{j}" for j in range(len(shp))) + ("time",)
        data[o] = (dims, res["y"][o])
    for s in STATS:
        data[s] = ("sample", res["stats"][s])
    data["status"] = ("sample", res["status"])
    data["message"] = ("sample", res["message"])
    data["batch"] = ("sample", res["batch"])
    data["chunk_wall"] = ("sample", np.full(b - a, res["wall"]))
    xr.Dataset(data).to_zarr(out, region={"sample": slice(a, b)}, consolidated=False)
    # the completion record last: a chunk counts as done only once its data are written
    xr.Dataset({"chunk_done": ("chunk", np.array([True]))}).to_zarr(
        out, region={"chunk": slice(k, k + 1)}, consolidated=False)


def consolidate(out):
    import zarr

    zarr.consolidate_metadata(str(out))


def open_results(out):
    """The results as an xarray Dataset (loaded lazily from the store)."""
    import xarray as xr

    return xr.open_zarr(out, consolidated=None)
