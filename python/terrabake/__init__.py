"""terrabake: terrain precomputation for Python.

Read baked assets as numpy arrays (``terrabake.open``) or xarray
DataArrays with rioxarray's georeferencing (``terrabake.to_xarray``),
compute horizons and sky-view factors of numpy or xarray DEMs without
files (``terrabake.horizons``, ``terrabake.sky_view_factor``), bake
DEMs into assets (``terrabake.bake``), and turn an asset's horizons into
sunlight: irradiation and sun hours over days (``terrabake.solar``) and
HORAYZON's direct-shortwave correction factor (``terrabake.direct_correction``). Every value comes from the same
Rust code as the ``terrabake`` command line, with the same defaults, so
both give the same numbers.

Conventions: azimuths are compass degrees, clockwise from north; horizon
angles are degrees above the horizontal; NaN is nodata; arrays are
(row, column), with row 0 the northernmost, and (band, row, column) for
layers of several bands. Every failure raises ``terrabake.Error`` (a
subclass of ``Exception``) with the command line's message, or
``ValueError`` for an argument that is wrong before any work starts.
``terrabake.Error`` has a subclass a kind of failure: ``AssetError`` (the
asset missing or damaged), ``SourceError`` (the DEM unreadable or
refused), ``ParameterError`` (a stage parameter or budget refused) and
``ResourceError`` (not enough memory or disk); anything else is
``terrabake.Error`` itself.
"""

import typing as _typing

from . import _native
from ._native import (
    Asset,
    AssetError,
    Error,
    ParameterError,
    ResourceError,
    SourceError,
    TerrabakeError,
    __version__,
    open,
)

__all__ = [
    "Asset",
    "AssetError",
    "Error",
    "ParameterError",
    "ResourceError",
    "SourceError",
    "TerrabakeError",
    "__version__",
    "bake",
    "direct_correction",
    "horizons",
    "open",
    "profile",
    "sky_view_factor",
    "solar",
    "to_xarray",
]

#: The names :func:`solar` returns, and the layers they are read from.
_SOLAR_LAYERS = {
    "global": "solar_global",
    "beam": "solar_beam",
    "diffuse": "solar_diffuse",
    "reflected": "solar_reflected",
    "sun_hours": "sun_hours",
}

def __getattr__(name: str) -> _typing.Any:
    """``terrabake.xarray`` (dask-backed DataArrays) on first use, so that
    ``import terrabake`` needs neither xarray nor dask."""
    if name == "xarray":
        import importlib

        return importlib.import_module(".xarray", __name__)
    raise AttributeError(f"module 'terrabake' has no attribute {name!r}")


#: The atmosphere's refraction coefficient the command line assumes.
DEFAULT_REFRACTION = 0.13


def _prepared(
    dem: _typing.Any,
    cell_size: _typing.Any,
    nodata: _typing.Optional[float],
    crs: _typing.Any,
    transform: _typing.Any,
    curvature: _typing.Optional[bool],
) -> _typing.Tuple[_typing.Any, _typing.Tuple[float, float], bool]:
    """The heights as a C-contiguous float32/float64 array with NaN for
    nodata, the cell size in metres, and the curvature switch, from a
    numpy array, a masked array or an xarray DataArray."""
    import numpy as np

    if type(dem).__name__ == "DataArray" and hasattr(dem, "dims"):
        crs, transform, nodata = _georeferencing(dem, crs, transform, nodata)
        dem = dem.values
    if isinstance(dem, np.ma.MaskedArray):
        mask = np.ma.getmaskarray(dem)
        values = np.ma.getdata(dem)
    else:
        mask = None
        values = np.asarray(dem)
    if values.dtype.kind not in "iuf":
        raise ValueError(f"dem: expected numbers (int, uint or float heights), got dtype {values.dtype}")
    if values.dtype.kind in "iu" or values.dtype.itemsize < 4:
        values = values.astype(np.float32)
    elif mask is not None or nodata is not None:
        values = values.copy()
    if nodata is not None and not np.isnan(nodata):
        values[values == values.dtype.type(nodata)] = np.nan
    if mask is not None:
        values[mask] = np.nan
    values = np.ascontiguousarray(values)

    if cell_size is None:
        cell_size = _cell_size_of(transform, crs)
    if np.isscalar(cell_size):
        cell_size = (float(cell_size), float(cell_size))  # type: ignore[arg-type]
    try:
        dx, dy = (float(v) for v in cell_size)
    except (TypeError, ValueError):
        raise ValueError(f"cell_size: {cell_size!r} is neither metres nor a pair (dx, dy) of metres") from None
    if curvature is None:
        # The command line's rule: curvature on when the grid is on the earth.
        curvature = crs is not None or transform is not None
    return values, (dx, dy), bool(curvature)


def _georeferencing(
    da: _typing.Any, crs: _typing.Any = None, transform: _typing.Any = None, nodata: _typing.Any = None
) -> _typing.Tuple[_typing.Any, _typing.Any, _typing.Any]:
    """(crs, transform, nodata) of a DataArray where not given, without
    reading its values: rioxarray's where it is installed, else the
    ``spatial_ref`` coordinate, and the ``_FillValue`` or ``nodata``
    attribute."""
    rio = getattr(da, "rio", None) if _has_rioxarray() else None
    if rio is not None:
        crs = crs if crs is not None else rio.crs
        if transform is None and rio.crs is not None:
            transform = tuple(rio.transform().to_gdal())
        if nodata is None and rio.nodata is not None:
            nodata = rio.nodata
    if transform is None and "spatial_ref" in da.coords:
        text = da.coords["spatial_ref"].attrs.get("GeoTransform")
        if text:
            transform = tuple(float(v) for v in str(text).split())
        crs = crs if crs is not None else da.coords["spatial_ref"].attrs.get("crs_wkt")
    if nodata is None:
        nodata = da.attrs.get("_FillValue", da.attrs.get("nodata"))
    return crs, transform, nodata


def _has_rioxarray() -> bool:
    try:
        import rioxarray  # noqa: F401
    except ImportError:
        return False
    return True


def _cell_size_of(transform: _typing.Any, crs: _typing.Any) -> _typing.Tuple[float, float]:
    """The cell size in metres of a projected grid's transform."""
    if transform is None:
        raise ValueError(
            "cell_size: needed (metres, or (dx, dy)) for a DEM without a transform; "
            "an xarray DataArray with rioxarray's georeferencing gives it"
        )
    t = tuple(float(v) for v in transform)
    if t[2] != 0.0 or t[4] != 0.0:
        raise ValueError(f"transform: {t} is rotated; terrabake reads north-up grids")
    if crs is not None:
        try:
            import pyproj

            if pyproj.CRS.from_user_input(crs).is_geographic:
                raise ValueError(
                    "cell_size: the grid is geographic (degrees); give the cell size in metres, "
                    "or bake the GeoTIFF with terrabake.bake, which follows the meridians' convergence"
                )
        except ImportError:
            pass
    return abs(t[1]), abs(t[5])


def horizons(
    dem: _typing.Any,
    cell_size: _typing.Any = None,
    sectors: int = 16,
    method: str = "line",
    max_distance: _typing.Optional[float] = None,
    curvature: _typing.Optional[bool] = None,
    refraction: float = DEFAULT_REFRACTION,
    progress: _typing.Optional[_typing.Callable[[int, int], _typing.Any]] = None,
    *,
    nodata: _typing.Optional[float] = None,
    crs: _typing.Any = None,
    transform: _typing.Any = None,
) -> _typing.Tuple[_typing.Any, _typing.Any]:
    """Horizon angles of a DEM held in memory, as ``terrabake horizons`` computes them.

    Parameters
    ----------
    dem
        Heights in metres, (rows, columns), row 0 the northernmost: a numpy
        array of any integer or float dtype (NaN is nodata), a masked array
        (masked posts are nodata), or an xarray DataArray (its rioxarray
        CRS, transform and nodata are used).
    cell_size
        The post spacing in metres: one number for square cells or
        ``(dx, dy)``. Optional when ``transform`` (or the DataArray) gives a
        projected grid.
    sectors
        How many directions (bands), evenly spaced from north.
    method
        ``"line"`` (exact sight lines, the default), ``"sector"``
        (Stewart's wedges) or ``"sampled"`` (a baseline).
    max_distance
        Metres beyond which terrain is not searched; None: to the edge.
    curvature
        Whether the earth's curvature (with refraction) lowers distant
        terrain. None: the command line's rule, on when the DEM is
        georeferenced (``crs`` or ``transform`` given, or a DataArray with
        a CRS), off for a bare array.
    refraction
        The atmosphere's refraction coefficient (0.13: the standard
        atmosphere), used with curvature.
    progress
        ``progress(done, total)``, called as bands complete.
    nodata
        A height that means nodata (for integer DEMs, e.g. -32768).
    crs, transform
        The DEM's georeferencing (any CRS pyproj reads; GDAL's six numbers).

    Returns
    -------
    (angles, band_azimuths)
        ``angles``: float32 degrees above the horizontal, shape (sectors,
        rows, columns), NaN at nodata posts, -90 where nothing of the DEM
        lies ahead. ``band_azimuths``: each band's compass azimuth, degrees.
    """
    values, size, curved = _prepared(dem, cell_size, nodata, crs, transform, curvature)
    return _native.horizons(values, size, sectors, method, max_distance, curved, refraction, progress)


def sky_view_factor(
    dem: _typing.Any,
    cell_size: _typing.Any = None,
    sectors: int = 16,
    method: str = "line",
    max_distance: _typing.Optional[float] = None,
    curvature: _typing.Optional[bool] = None,
    refraction: float = DEFAULT_REFRACTION,
    progress: _typing.Optional[_typing.Callable[[int, int], _typing.Any]] = None,
    *,
    nodata: _typing.Optional[float] = None,
    crs: _typing.Any = None,
    transform: _typing.Any = None,
) -> _typing.Any:
    """The sky-view factor (over the horizontal, Zakšek's) of a DEM held in
    memory, from its horizons, as the ``sky`` stage computes it.

    Takes the parameters of :func:`horizons`, with the same defaults.
    Returns float32 (rows, columns) in 0..1, NaN at nodata posts.
    """
    values, size, curved = _prepared(dem, cell_size, nodata, crs, transform, curvature)
    return _native.sky_view_factor(values, size, sectors, method, max_distance, curved, refraction, progress)


def bake(
    src: _typing.Any,
    out: _typing.Any,
    recipe: _typing.Any = None,
    budget: _typing.Optional[str] = None,
    needs: _typing.Optional[str] = None,
    progress: _typing.Optional[_typing.Callable[[str, int, int], _typing.Any]] = None,
    *,
    parts: _typing.Optional[int] = None,
    client: _typing.Any = None,
) -> str:
    """Bakes the DEM file ``src`` into the asset ``out``, as ``terrabake bake``.

    With a ``recipe`` file, or planned from a ``budget`` (``"horizon=0.5"``,
    the CLI's ``--budget`` syntax) and ``needs`` (``"horizons,svf"``).
    ``progress(stage, done, total)`` is called as each stage is committed;
    an exception it raises stops the bake there (what is committed stays,
    and the same call resumes from it).

    ``parts=N`` (with a recipe) cuts the bake into N parts, as ``terrabake
    bake --parts N --part I`` does, and assembles them after; with a
    ``dask.distributed`` ``client`` each part is a task on its cluster (any
    the user has: a ``LocalCluster``, Slurm through dask-jobqueue,
    Kubernetes; the workers must see ``src``, ``recipe`` and ``out`` at the
    same paths) and the assemble a task after them, else the parts run here
    one after the other. The result equals one machine's bake bit for bit.
    ``progress`` is for one machine's bake; a cluster's is on its client.

    Returns the stages' records as JSON.
    """
    if parts is None:
        if client is not None:
            raise ValueError("client: give parts=N to cut the bake into tasks")
        return _native.bake(src, out, recipe, budget, needs, progress)
    if recipe is None or budget is not None:
        raise ValueError("parts: a partitioned bake takes a recipe, not a budget")
    if progress is not None:
        raise ValueError("progress: a partitioned bake reports through its client, not a callback")
    if not isinstance(parts, int) or parts < 1:
        raise ValueError(f"parts={parts!r}: give a whole number of parts, 1 or more")
    import os

    src, out, recipe = os.fspath(src), os.fspath(out), os.fspath(recipe)
    if client is None:
        for i in range(parts):
            _native.bake_part(src, out, recipe, i, parts)
        return _native.assemble(out)
    tasks = [client.submit(_native.bake_part, src, out, recipe, i, parts, pure=False) for i in range(parts)]
    client.gather(tasks)
    return client.submit(_native.assemble, out, pure=False).result()


def profile(
    asset: _typing.Any,
    points: _typing.Sequence[_typing.Tuple[float, float]],
    *,
    crs: str = "native",
    step: float = 1.0,
    max_distance: _typing.Optional[float] = None,
    curvature: _typing.Optional[bool] = None,
    refraction: float = DEFAULT_REFRACTION,
    form: str = "pvlib",
) -> _typing.List[_typing.Any]:
    """The horizon profile around each point, as ``terrabake profile`` computes one.

    Each azimuth's horizon is the exact sight line from the post nearest
    the point (not interpolated between stored bands), read from the
    asset's heights; the DEM is read once for all the points.

    Parameters
    ----------
    asset
        An :class:`Asset` or the path of an asset directory.
    points
        ``(x, y)`` pairs in ``crs``: ``"native"`` (the DEM's CRS), ``"lonlat"``
        (WGS 84 degrees, on geographic and WGS 84 UTM grids) or ``"grid"``
        (column, row).
    step
        Degrees between azimuths, from north clockwise.
    max_distance, curvature, refraction
        The sight lines' bound (metres, None: the DEM's edge) and the earth's
        curvature (None: on when the DEM is georeferenced), as the CLI's.
    form
        ``"pvlib"``: per point a ``pandas.Series`` of horizon elevation
        angles (degrees) indexed by azimuth (degrees clockwise from north),
        as ``pvlib.iotools.get_pvgis_horizon`` returns one (a dict of two
        arrays, ``azimuth`` and ``horizon``, without pandas). ``"pvgis"``:
        per point the 48 heights PVGIS's ``userhorizon`` takes (every 7.5
        degrees from north clockwise, negative angles as 0; ``step`` is
        then 7.5). ``"arrays"``: per point a dict of ``post``, ``azimuth``,
        ``horizon`` (-90 where nothing lies ahead) and ``distance``
        (metres, NaN there).
    """
    if form not in ("pvlib", "pvgis", "arrays"):
        raise ValueError(f"form={form!r}: give pvlib, pvgis or arrays")
    if form == "pvgis":
        step = 7.5
    pairs = [(float(x), float(y)) for x, y in points]
    found = _native.profiles(_path_of(asset), pairs, crs, step, max_distance, curvature, refraction)
    out: _typing.List[_typing.Any] = []
    for post, azimuth, horizon, distance in found:
        if form == "arrays":
            out.append({"post": post, "azimuth": azimuth, "horizon": horizon, "distance": distance})
        elif form == "pvgis":
            out.append([max(0.0, round(float(h), 2)) for h in horizon])
        else:
            try:
                import pandas as pd
            except ImportError:
                out.append({"azimuth": azimuth, "horizon": horizon})
                continue
            series = pd.Series(horizon.astype("float64"), index=pd.Index(azimuth, name="horizon_azimuth"))
            series.name = "horizon_elevation"
            out.append(series)
    return out


def _path_of(asset: _typing.Any) -> str:
    import os

    return os.fspath(asset.path if isinstance(asset, Asset) else asset)


def solar(
    asset: _typing.Any,
    days: _typing.Union[int, str] = "year",
    *,
    monthly: bool = False,
    step: float = 15.0,
    linke: float = 3.0,
    linke_monthly: _typing.Optional[_typing.Sequence[float]] = None,
    albedo: float = 0.2,
    lat: _typing.Optional[float] = None,
    lon: _typing.Optional[float] = None,
    between: _typing.Optional[_typing.Tuple[float, float]] = None,
    calendar_year: _typing.Optional[int] = None,
    force: bool = False,
) -> _typing.Dict[str, _typing.Any]:
    """Clear-sky irradiation and sun hours from an asset's horizons, as ``terrabake solar``.

    Bakes the ``solar`` stage into the asset (and the ``sky`` stage first
    where the asset has no ``svf_cosine``; the horizons must be baked), then
    returns its layers. The model is GRASS r.sun's (docs/SOLAR.md).

    Parameters
    ----------
    asset
        An :class:`Asset` or the path of an asset directory.
    days
        A day of the year (``172``), a range (``"80-100"``) or ``"year"``;
        the values are the mean day over them.
    monthly
        One band per month the days touch instead of one for the period.
    step
        Minutes between sun positions.
    linke, linke_monthly
        The Linke turbidity factor, or twelve of them, January first.
    albedo
        Ground albedo for the reflected part.
    lat, lon
        Degrees; needed only where the asset's CRS is neither geographic
        nor WGS 84 UTM.
    between
        ``(from, to)`` hours of local solar time: only the steps within.
    calendar_year
        The year the days are of (default 2026).
    force
        Recompute even where the asset's solar layers are up to date.

    Returns
    -------
    dict
        ``global``, ``beam``, ``diffuse``, ``reflected`` (Wh/m^2 per day)
        and ``sun_hours`` (hours per day): float32 (rows, columns), or
        (months, rows, columns) with ``monthly``; NaN at nodata posts.
    """
    import json

    params: _typing.Dict[str, _typing.Any] = {
        "days": str(days),
        "monthly": monthly,
        "step_minutes": step,
        "linke": linke,
        "albedo": albedo,
    }
    if linke_monthly is not None:
        params["linke_monthly"] = [float(t) for t in linke_monthly]
    if lat is not None:
        params["latitude"] = lat
    if lon is not None:
        params["longitude"] = lon
    if between is not None:
        params["between"] = [float(between[0]), float(between[1])]
    if calendar_year is not None:
        params["calendar_year"] = calendar_year
    path = _path_of(asset)
    _native.solar(path, json.dumps(params), force)
    baked = open(path)
    return {short: baked.read(layer) for short, layer in _SOLAR_LAYERS.items()}


def direct_correction(
    asset: _typing.Any,
    suns: _typing.Sequence[_typing.Tuple[float, float]],
    *,
    per_horizontal_area: bool = False,
) -> _typing.Any:
    """HORAYZON's terrain correction factor for direct shortwave, one plane per sun position.

    ``suns`` are ``(azimuth, elevation)`` pairs in degrees, the azimuth
    true, clockwise from north. Each plane holds, per post, the direct
    irradiance on its surface over that on a flat open plane: 0 where the
    sun is below the stored horizon or behind the surface, else
    ``n . s / sin(elevation)`` (capped at 25, the elevation held at 0.5
    degrees, as HORAYZON does). ``per_horizontal_area`` multiplies by
    HORAYZON's surface enlargement factor ``1 / cos(slope)``. Returns
    float32 (suns, rows, columns), NaN at nodata posts; the same values
    ``terrabake solar --sun`` writes.
    """
    pairs = [(float(az), float(el)) for az, el in suns]
    return _native.direct_correction(_path_of(asset), pairs, per_horizontal_area)


def to_xarray(asset: Asset, name: str, level: int = 0) -> _typing.Any:
    """Layer ``name`` at ``level`` of ``asset`` as an ``xarray.DataArray``.

    Dims are ``(y, x)`` for a layer of one band and ``(band, y, x)``
    otherwise. ``x`` and ``y`` are the pixel centres in the asset's CRS
    (post indices when it has no georeferencing). ``band`` holds each
    band's compass azimuth for directional layers (horizons) and the band
    index otherwise. Georeferencing follows rioxarray and GDAL: a
    ``spatial_ref`` coordinate carries ``crs_wkt`` and ``GeoTransform``
    (GDAL's order), and ``_FillValue`` is NaN, so ``da.rio.crs``,
    ``da.rio.bounds()`` and ``da.rio.to_raster()`` work unchanged. The
    other attributes carry the units, the method, the layer's description
    and each band's description.
    """
    try:
        import numpy as np
        import xarray as xr
    except ImportError as e:  # pragma: no cover - exercised without xarray
        raise ImportError("to_xarray needs xarray: pip install xarray") from e
    values = asset.read(name, level)
    rows, cols = values.shape[-2:]
    coords = _grid_coords(asset, level, rows, cols)
    attrs = dict(asset.attributes(name, level))
    attrs["band_descriptions"] = list(attrs.get("band_descriptions", []))
    attrs["_FillValue"] = np.nan
    dims: _typing.Tuple[str, ...] = ("y", "x")
    if values.ndim == 3:
        bands = values.shape[0]
        azimuths = asset.band_azimuths(name) if level == 0 else []
        directional = len(azimuths) == bands
        coords["band"] = np.asarray(azimuths, dtype=np.float64) if directional else np.arange(bands)
        if directional:
            attrs["band"] = "compass azimuth, degrees clockwise from north"
        dims = ("band", "y", "x")
    da = xr.DataArray(values, dims=dims, coords=coords, name=name, attrs=attrs)
    if "spatial_ref" in coords:
        da.encoding["grid_mapping"] = "spatial_ref"
    return da


def _grid_coords(asset: Asset, level: int, rows: int, cols: int) -> dict:
    """``x`` and ``y`` at the pixel centres of level ``level`` in the
    asset's CRS (post indices without georeferencing), and rioxarray's and
    CF's ``spatial_ref`` (``crs_wkt``, GDAL's ``GeoTransform``) where the
    asset is georeferenced: what :func:`to_xarray` and the xarray backend
    both give."""
    import numpy as np
    import xarray as xr

    transform = asset.transform
    scale = float(2**level)
    coords: dict = {}
    if transform is None:
        coords["x"] = np.arange(cols) * scale
        coords["y"] = np.arange(rows) * scale
        return coords
    t0, t1, _, t3, _, t5 = transform
    t1, t5 = t1 * scale, t5 * scale
    coords["x"] = t0 + (np.arange(cols) + 0.5) * t1
    coords["y"] = t3 + (np.arange(rows) + 0.5) * t5
    wkt = _wkt(asset.crs)
    spatial_ref = {"GeoTransform": " ".join(repr(float(v)) for v in (t0, t1, 0.0, t3, 0.0, t5))}
    if wkt is not None:
        spatial_ref.update(crs_wkt=wkt, spatial_ref=wkt)
    coords["spatial_ref"] = xr.Variable((), 0, attrs=spatial_ref)
    return coords


def _wkt(crs: _typing.Optional[str]) -> _typing.Optional[str]:
    """WKT of the asset's CRS: as stored, or from pyproj for ``EPSG:n``."""
    if crs is None or not crs.startswith("EPSG:"):
        return crs
    try:
        import pyproj
    except ImportError:
        return None
    return str(pyproj.CRS.from_user_input(crs).to_wkt())
