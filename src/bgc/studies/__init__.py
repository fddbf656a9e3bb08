"""The studies layer: what runs many simulations. ``accuracy`` (work-precision studies) and
``sweep`` (parameter sweeps on Dask, results in xarray/Zarr)."""
