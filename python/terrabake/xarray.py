"""terrabake over xarray DataArrays held as dask arrays.

:func:`horizons` maps the bounded line stage over a DEM's chunks with
``dask.array``'s overlap: each chunk is computed with a halo of the
stage's declared reach (the posts within ``max_distance``, and one more),
then trimmed, so a DEM far larger than a worker's memory is baked chunk by
chunk, in parallel on whatever cluster runs the dask graph, and equals the
CLI's bake of the same DEM (``terrabake horizons --max-distance``): a
post's bounded sight lines see nothing beyond the halo. Projected grids
only (a geographic grid's east-west spacing changes by row, which a chunk
alone does not know): reproject first, or bake the file with the CLI.
"""

from __future__ import annotations

import math
import typing as _typing

import numpy as np

import xarray as xr

from . import DEFAULT_REFRACTION, _cell_size_of, _georeferencing, _native, _prepared


def reach(max_distance: float, cell_size: _typing.Tuple[float, float]) -> int:
    """The posts around a post that its bounded sight lines read, as the
    horizons stage declares them: those within ``max_distance`` of it at
    the finer spacing, and one more for the surface between."""
    return math.floor(max_distance / min(cell_size)) + 1


def horizons(
    da: xr.DataArray,
    sectors: int = 16,
    max_distance: _typing.Optional[float] = None,
    *,
    cell_size: _typing.Any = None,
    curvature: _typing.Optional[bool] = None,
    refraction: float = DEFAULT_REFRACTION,
) -> xr.DataArray:
    """Bounded line horizons of a (dask-backed) DEM, chunk by chunk.

    ``da`` is heights in metres, dims (y, x), row 0 the northernmost; its
    chunks must each be at least :func:`reach` posts across. ``max_distance``
    (metres) is required: it is what bounds a chunk's halo. ``cell_size``,
    ``curvature`` and ``refraction`` are :func:`terrabake.horizons`'s, the
    cell size and the curvature rule taken from the georeferencing where
    not given. Returns a lazy DataArray ``horizon`` with dims (azimuth, y,
    x), degrees, the azimuth coordinate the bands' compass azimuths.
    """
    import dask.array as dsa

    if max_distance is None or not max_distance > 0:
        raise ValueError(
            f"max_distance={max_distance!r}: give metres; the chunks' halo is the posts within it"
        )
    if da.ndim != 2:
        raise ValueError(f"da: expected heights (y, x), got dims {da.dims}")
    crs, transform, nodata = _georeferencing(da)
    if cell_size is None:
        cell_size = _cell_size_of(transform, crs)
    size = (float(cell_size), float(cell_size)) if np.isscalar(cell_size) else tuple(map(float, cell_size))
    curved = bool(curvature) if curvature is not None else (crs is not None or transform is not None)
    depth = reach(max_distance, size)
    data = da.data if isinstance(da.data, dsa.Array) else dsa.from_array(da.values, chunks=da.shape)
    small = [c for chunks in data.chunks for c in chunks if c < depth]
    if small and len(data.chunks[0]) * len(data.chunks[1]) > 1:
        raise ValueError(
            f"da: chunks of {min(small)} posts are narrower than the halo of {depth} posts "
            f"that max_distance={max_distance} m needs; rechunk to at least {depth}"
        )
    _, azimuths = _native.horizons(np.zeros((3, 3)), size, sectors, "line", max_distance, curved, refraction, None)

    def block(z: np.ndarray) -> np.ndarray:
        values, _, _ = _prepared(z, size, nodata, None, None, curved)
        angles, _ = _native.horizons(values, size, sectors, "line", max_distance, curved, refraction, None)
        return angles

    halo = dsa.overlap.overlap(data, depth={0: depth, 1: depth}, boundary="none")
    angles = halo.map_blocks(block, dtype=np.float32, new_axis=0, chunks=((sectors,), *halo.chunks))
    angles = dsa.overlap.trim_internal(angles, {0: 0, 1: depth, 2: depth}, boundary="none")
    coords = {name: da.coords[name] for name in da.coords if set(da.coords[name].dims) <= set(da.dims)}
    coords["azimuth"] = xr.Variable(
        "azimuth",
        np.asarray(azimuths, dtype=np.float64),
        attrs={"units": "degree", "long_name": "compass azimuth, clockwise from north"},
    )
    attrs = {
        "units": "deg",
        "long_name": "horizon elevation angle",
        "method": "line",
        "max_distance": float(max_distance),
        "curvature": str(curved).lower(),
        "refraction": float(refraction),
    }
    return xr.DataArray(angles, dims=("azimuth", *da.dims), coords=coords, name="horizon", attrs=attrs)
