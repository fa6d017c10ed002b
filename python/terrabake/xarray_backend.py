"""xarray's ``engine="terrabake"``: an asset opened lazily.

``xr.open_dataset("dem.tbake", engine="terrabake")`` gives one variable
per layer at ``level`` (0 by default; ``layers=[...]`` picks some), each a
lazily indexed :class:`LayerArray`: opening reads the manifest and nothing
else, and each selection reads the window it covers from the mapped tiles,
decoded as ``Asset.read`` decodes (quantised codes to values, nodata to
NaN). ``chunks={}`` gives dask arrays chunked by the asset's tiles.

Directional layers (horizons and their distances) have an ``azimuth``
dimension holding the recorded band azimuths, degrees clockwise from north
(``azimuth_<layer>`` where two layers' azimuths differ); other layers of
several bands (the solar stage's months) a ``<layer>_band`` dimension.
``x``, ``y`` and ``spatial_ref`` are :func:`terrabake.to_xarray`'s, so
rioxarray's ``.rio.crs``, ``.rio.bounds()`` and ``.rio.to_raster()`` see
the asset's georeferencing. The attributes are those the Zarr and NetCDF
exports (``terrabake export --layer all -o X.zarr`` or ``-o X.nc``) write,
from the same Rust code: an export and the asset it came from open as the
same dataset. The
entry point is declared in the package's metadata
(``[project.entry-points."xarray.backends"]``).
"""

from __future__ import annotations

import json
import os
import typing as _typing

import numpy as np
from xarray.backends import BackendArray, BackendEntrypoint
from xarray.core import indexing

import xarray as xr

from . import Asset, _grid_coords
from . import open as _open

#: The file that makes a directory an asset.
MANIFEST = "manifest.tba"


class LayerArray(BackendArray):
    """Layer ``name`` at ``level``: (bands, rows, columns), or (rows,
    columns) for one band, float32, read a window per selection."""

    def __init__(self, asset: Asset, name: str, level: int, bands: int, rows: int, cols: int):
        self.asset, self.name, self.level = asset, name, level
        self.several = bands > 1
        self.shape = (bands, rows, cols) if self.several else (rows, cols)
        self.dtype = np.dtype(np.float32)
        #: Windows read so far: what the tests hold laziness to.
        self.reads = 0

    def __getitem__(self, key: indexing.ExplicitIndexer) -> np.ndarray:
        return indexing.explicit_indexing_adapter(
            key, self.shape, indexing.IndexingSupport.BASIC, self._read
        )

    def _read(self, key: tuple) -> np.ndarray:
        key = tuple(key) if self.several else (0, *tuple(key))
        full = (self.shape[0] if self.several else 1, *self.shape[-2:])
        picks = []
        for k, n in zip(key, full):
            picks.append(range(*k.indices(n)) if isinstance(k, slice) else range(k, k + 1))
        out_shape = tuple(len(p) for p, k in zip(picks, key) if isinstance(k, slice))
        if any(len(p) == 0 for p in picks):
            return np.empty(out_shape, dtype=self.dtype)
        lo = [min(p) for p in picks]
        hi = [max(p) + 1 for p in picks]
        window = self.asset.read_window(
            self.name, self.level, (lo[0], hi[0]), lo[1], lo[2], hi[1] - lo[1], hi[2] - lo[2]
        )
        self.reads += 1
        index = [np.asarray(p) - l for p, l in zip(picks, lo)]
        out = window[np.ix_(*index)]
        return out.reshape(out_shape)


class TerrabakeBackendEntrypoint(BackendEntrypoint):
    """Opens a terrabake asset directory as an ``xarray.Dataset``."""

    description = "terrabake assets (.tbake directories), lazily, one variable per layer"
    open_dataset_parameters = ("filename_or_obj", "drop_variables", "layers", "level")

    def guess_can_open(self, filename_or_obj: _typing.Any) -> bool:
        try:
            path = os.fspath(filename_or_obj)
        except TypeError:
            return False
        return os.path.isfile(os.path.join(path, MANIFEST))

    def open_dataset(  # type: ignore[override]
        self,
        filename_or_obj: _typing.Any,
        *,
        drop_variables: _typing.Optional[_typing.Iterable[str]] = None,
        layers: _typing.Optional[_typing.Iterable[str]] = None,
        level: int = 0,
    ) -> xr.Dataset:
        asset = _open(os.fspath(filename_or_obj))
        entries = [entry for entry in asset.layers if entry["level"] == level]
        if layers is not None:
            wanted = list(layers)
            known = {entry["name"] for entry in entries}
            missing = [name for name in wanted if name not in known]
            if missing:
                raise ValueError(
                    f"{asset.path}: no layer {', '.join(missing)} at level {level} "
                    f"(it has {', '.join(sorted(known))})"
                )
            entries = [entry for entry in entries if entry["name"] in wanted]
        dropped = set(drop_variables or ())
        entries = [entry for entry in entries if entry["name"] not in dropped]
        if not entries:
            raise ValueError(f"{asset.path}: no layer to open at level {level}")
        rows, cols = entries[0]["height"], entries[0]["width"]
        coords = _grid_coords(asset, level, rows, cols)
        # One azimuth dimension where every directional layer shares it.
        directional = [e for e in entries if e["bands"] > 1 and len(e["band_azimuths"]) == e["bands"]]
        shared = len({tuple(e["band_azimuths"]) for e in directional}) == 1
        variables = {}
        for entry in entries:
            name, bands = entry["name"], entry["bands"]
            # The Zarr export's attributes; the values come decoded, so the
            # packing of quantised codes is not theirs.
            attrs = json.loads(asset.cf_attributes(name, level))
            for packing in ("scale_factor", "add_offset", "_FillValue"):
                attrs.pop(packing, None)
            dims: _typing.Tuple[str, ...] = ("y", "x")
            if bands > 1:
                if entry in directional:
                    band_dim = "azimuth" if shared else f"azimuth_{name}"
                    coords[band_dim] = xr.Variable(
                        band_dim,
                        np.asarray(entry["band_azimuths"], dtype=np.float64),
                        attrs={"units": "degree", "long_name": "compass azimuth, clockwise from north"},
                    )
                else:
                    band_dim = f"{name}_band"
                    coords[band_dim] = np.arange(bands)
                dims = (band_dim, "y", "x")
            data = indexing.LazilyIndexedArray(
                LayerArray(asset, name, level, bands, entry["height"], entry["width"])
            )
            tile = entry["tile_size"]
            encoding: dict = {
                "preferred_chunks": {**dict.fromkeys(dims[:-2], bands), "y": tile, "x": tile},
                "_FillValue": np.nan,
            }
            if "spatial_ref" in coords:
                encoding["grid_mapping"] = "spatial_ref"
            variables[name] = xr.Variable(dims, data, attrs=attrs, encoding=encoding)
        ds = xr.Dataset(variables, coords=coords)
        ds.attrs["source"] = str(asset.path)
        ds.attrs["Conventions"] = "CF-1.8"
        return ds
