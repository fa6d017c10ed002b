"""``terrabake export A --layer all -o A.zarr`` read back by zarr-python
(>= 3) and xarray: the same dataset as ``xr.open_dataset(A,
engine="terrabake")`` (values, dimensions, coordinates, attributes),
quantised horizons kept as their u8 codes with CF's packing, chunks the
asset's tiles, and rioxarray's georeferencing equal to the GeoTIFF
export's. pipelines/python/test.sh runs this in an environment of its own
(zarr 3 needs a newer numpy than Debian's); elsewhere it is skipped."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

zarr = pytest.importorskip("zarr")
xr = pytest.importorskip("xarray")
if int(zarr.__version__.split(".")[0]) < 3:
    pytest.skip("Zarr v3 needs zarr-python 3", allow_module_level=True)

import terrabake  # noqa: E402
from conftest import assert_same_dataset  # noqa: E402

BIN = os.environ.get("TERRABAKE_BIN", "target/release/terrabake")


@pytest.fixture(scope="module")
def baked(export_asset: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The shared asset (conftest.py) and every layer of its post grid exported to a Zarr store."""
    store = tmp_path_factory.mktemp("zarr") / "srtm.zarr"
    subprocess.run([BIN, "-q", "export", export_asset, "--layer", "all", "-o", store], check=True)
    return export_asset, store


def test_zarr_python_reads_codes_chunked_by_tiles(baked: tuple[Path, Path]) -> None:
    asset, store = baked
    group = zarr.open_group(store, mode="r")
    horizon = group["horizon"]
    assert horizon.dtype == np.uint8 and horizon.chunks == (1, 128, 128)
    assert horizon.metadata.dimension_names == ("azimuth", "y", "x")
    attrs = horizon.attrs
    decoded = np.where(
        horizon[:] == attrs["_FillValue"], np.nan, attrs["add_offset"] + attrs["scale_factor"] * horizon[:]
    ).astype(np.float32)
    np.testing.assert_array_equal(decoded, terrabake.open(asset).read("horizon"))
    assert group["height"].dtype == np.float32 and group.attrs["proj:code"] == "EPSG:4326"


def test_xarray_opens_the_store_as_the_backend_opens_the_asset(baked: tuple[Path, Path]) -> None:
    asset, store = baked
    # Consolidated metadata: no warning about reading every array's.
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        stored = xr.open_zarr(store)
    live = xr.open_dataset(asset, engine="terrabake")
    # The store also says which coordinate is the grid mapping (the backend
    # keeps that in encoding) and GeoZarr's spatial dimensions.
    assert_same_dataset(stored, live, {"grid_mapping", "spatial:dimensions"})


def test_georeferencing_is_the_geotiff_exports(baked: tuple[Path, Path], tmp_path: Path) -> None:
    rioxarray = pytest.importorskip("rioxarray")
    asset, store = baked
    tif = tmp_path / "svf.tif"
    subprocess.run([BIN, "-q", "export", asset, "--layer", "svf", "-o", tif], check=True)
    exported = rioxarray.open_rasterio(tif, masked=True).squeeze("band", drop=True)
    svf = xr.open_zarr(store)["svf"]
    assert svf.rio.crs == exported.rio.crs
    np.testing.assert_allclose(svf.rio.bounds(), exported.rio.bounds(), rtol=0, atol=1e-9)
    np.testing.assert_allclose(tuple(svf.rio.transform()), tuple(exported.rio.transform()), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(svf.values, exported.values.astype(np.float32))
    # And back out through rioxarray: the same raster again.
    again = tmp_path / "again.tif"
    svf.rio.to_raster(again)
    np.testing.assert_array_equal(
        rioxarray.open_rasterio(again, masked=True).squeeze("band", drop=True).values, svf.values
    )
