"""terrabake: terrain precomputation for Python.

Read baked assets as numpy arrays (``terrabake.open``), compute horizons
and sky-view factors of numpy DEMs without files (``terrabake.horizons``,
``terrabake.sky_view_factor``), and bake DEMs into assets
(``terrabake.bake``). Every value comes from the same Rust code as the
``terrabake`` command line, so both give the same numbers.

Conventions: azimuths are compass degrees, clockwise from north; horizon
angles are degrees above the horizontal; NaN is nodata; arrays are
(band, row, column) with row 0 the northernmost.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ._native import (
    Asset,
    TerrabakeError,
    __version__,
    bake,
    horizons,
    open,
    sky_view_factor,
)

__all__ = [
    "Asset",
    "TerrabakeError",
    "__version__",
    "bake",
    "horizons",
    "open",
    "sky_view_factor",
    "to_xarray",
]


def to_xarray(asset: Asset, name: str, level: int = 0) -> Any:
    """Layer ``name`` at ``level`` of ``asset`` as an ``xarray.DataArray``.

    Dims are ``(band, y, x)``. ``x`` and ``y`` are the pixel centres in the
    asset's CRS (post indices when it has no georeferencing). ``band`` holds
    each band's compass azimuth for directional layers (horizons) and the
    band index otherwise. The attributes carry the units, the method, the
    layer's description, the CRS (``crs``, WKT or ``EPSG:n``) and GDAL's
    ``transform``.
    """
    try:
        import xarray as xr
    except ImportError as e:  # pragma: no cover - exercised without xarray
        raise ImportError("to_xarray needs xarray: pip install xarray") from e
    values = asset.read(name, level)
    bands, rows, cols = values.shape
    transform = asset.transform
    scale = float(2**level)
    if transform is None:
        x = np.arange(cols) * scale
        y = np.arange(rows) * scale
    else:
        t0, t1, _, t3, _, t5 = transform
        x = t0 + (np.arange(cols) + 0.5) * t1 * scale
        y = t3 + (np.arange(rows) + 0.5) * t5 * scale
    azimuths = asset.band_azimuths(name) if level == 0 else []
    band = np.asarray(azimuths, dtype=np.float64) if len(azimuths) == bands else np.arange(bands)
    attrs = dict(asset.attributes(name, level))
    attrs["band_descriptions"] = list(attrs.get("band_descriptions", []))
    if asset.crs is not None:
        attrs["crs"] = asset.crs
    if transform is not None:
        attrs["transform"] = tuple(transform)
    if len(azimuths) == bands:
        attrs["band"] = "compass azimuth, degrees clockwise from north"
    return xr.DataArray(
        values,
        dims=("band", "y", "x"),
        coords={"band": band, "y": y, "x": x},
        name=name,
        attrs=attrs,
    )
