"""``xr.open_dataset(asset, engine="terrabake")`` against the asset's own
reader and against the GeoTIFF exports through rioxarray: lazy (nothing
read until asked, one window per selection), the same values, azimuths
and georeferencing, and dask chunks by the asset's tiles."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

import terrabake

xr = pytest.importorskip("xarray")
import terrabake.xarray_backend  # noqa: E402  (the module the entry point names)

BIN = os.environ.get("TERRABAKE_BIN", "target/release/terrabake")
ROOT = Path(__file__).resolve().parents[2]

RECIPE = """
[ingest]
tile = 128
[[stage]]
name = "horizons"
sectors = 8
max_distance = 3000
[[stage]]
name = "sky"
"""


@pytest.fixture(scope="module")
def asset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The bundled SRTM tile (geographic, int16 with nodata), 8 bounded
    line directions in u8 codes and the sky layers."""
    tmp = tmp_path_factory.mktemp("xr")
    recipe = tmp / "r.toml"
    recipe.write_text(RECIPE)
    out = tmp / "srtm.tbake"
    subprocess.run(
        [BIN, "-q", "bake", ROOT / "data/srtm3_n07w006_geographic_int16.tif", "-o", out, "--recipe", recipe],
        check=True,
    )
    return out


def layer_array(ds, name: str):
    """The backend's array under the variable's lazy wrappers."""
    data = ds[name].variable._data
    while not isinstance(data, terrabake.xarray_backend.LayerArray):
        data = data.array
    return data


def test_open_dataset_is_lazy_and_reads_one_window_per_selection(asset: Path) -> None:
    ds = xr.open_dataset(asset, engine="terrabake")
    assert {"height", "horizon", "svf", "svf_cosine"} <= set(ds.data_vars)
    horizon = layer_array(ds, "horizon")
    assert horizon.reads == 0 and layer_array(ds, "height").reads == 0
    got = ds["horizon"].isel(azimuth=3, y=slice(10, 20), x=slice(5, 30)).values
    assert horizon.reads == 1
    whole = terrabake.open(asset).read("horizon")
    np.testing.assert_array_equal(got, whole[3, 10:20, 5:30])
    # Steps and single posts: the same numbers as numpy's. (Not negative
    # steps: Debian's xarray composes them wrongly in every lazy backend
    # before a backend sees them.)
    picked = ds["horizon"].isel(azimuth=slice(1, None, 2), y=slice(10, 50, 7), x=40).values
    np.testing.assert_array_equal(picked, whole[1::2, 10:50:7, 40])
    assert ds["horizon"].attrs["units"] == "degree" and ds["horizon"].attrs["method"] == "line"


def test_azimuths_are_the_recorded_band_azimuths(asset: Path) -> None:
    ds = xr.open_dataset(asset, engine="terrabake")
    recorded = terrabake.open(asset).band_azimuths("horizon")
    assert ds["horizon"].dims == ("azimuth", "y", "x")
    np.testing.assert_array_equal(ds["azimuth"].values, recorded)
    assert ds["svf"].dims == ("y", "x")


def test_values_and_georeferencing_equal_the_geotiff_export(asset: Path, tmp_path: Path) -> None:
    rioxarray = pytest.importorskip("rioxarray")
    tif = tmp_path / "horizon.tif"
    subprocess.run([BIN, "-q", "export", asset, "--layer", "horizon", "-o", tif], check=True)
    exported = rioxarray.open_rasterio(tif, masked=True)
    ds = xr.open_dataset(asset, engine="terrabake")
    np.testing.assert_array_equal(ds["horizon"].values, exported.values.astype(np.float32))
    assert ds["horizon"].rio.crs == exported.rio.crs
    np.testing.assert_allclose(ds["horizon"].rio.bounds(), exported.rio.bounds(), rtol=0, atol=1e-9)
    np.testing.assert_allclose(
        tuple(ds["horizon"].rio.transform()), tuple(exported.rio.transform()), rtol=0, atol=1e-12
    )
    assert np.isnan(ds["height"].encoding["_FillValue"])


def test_chunks_follow_the_tiles_and_compute_the_same(asset: Path) -> None:
    pytest.importorskip("dask")
    ds = xr.open_dataset(asset, engine="terrabake", chunks={})
    chunks = ds["horizon"].chunks
    assert chunks[0] == (8,) and set(chunks[1][:-1]) == {128} and set(chunks[2][:-1]) == {128}
    np.testing.assert_array_equal(ds["svf"].compute().values, terrabake.open(asset).read("svf"))


def test_layers_pick_a_subset_and_an_unknown_layer_is_named(asset: Path) -> None:
    ds = xr.open_dataset(asset, engine="terrabake", layers=["svf"])
    assert list(ds.data_vars) == ["svf"] and "azimuth" not in ds.coords
    with pytest.raises(ValueError, match="no layer nope"):
        xr.open_dataset(asset, engine="terrabake", layers=["nope"])
    backend = terrabake.xarray_backend.TerrabakeBackendEntrypoint()
    assert backend.guess_can_open(asset) and not backend.guess_can_open(asset.parent)


def test_a_window_outside_the_layer_is_a_value_error(asset: Path) -> None:
    opened = terrabake.open(asset)
    with pytest.raises(ValueError, match="outside layer svf"):
        opened.read_window("svf", 0, (0, 1), 1200, 0, 5, 5)
    with pytest.raises(ValueError, match="outside layer horizon"):
        opened.read_window("horizon", 0, (0, 9), 0, 0, 5, 5)
    assert opened.read_window("horizon", 0, (2, 5), 7, 9, 3, 4).shape == (3, 3, 4)
