"""What the array exports' tests (test_zarr_export.py,
test_netcdf_export.py) share: the bundled SRTM tile baked once per session
with a layer of each kind an export meets."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

BIN = os.environ.get("TERRABAKE_BIN", "target/release/terrabake")
ROOT = Path(__file__).resolve().parents[2]

# Heights zstd, horizons in u8 codes, the solar stage's months (a band
# dimension that is not azimuths).
EXPORT_RECIPE = """
[ingest]
tile = 128
codec = "zstd"
[[stage]]
name = "horizons"
sectors = 8
max_distance = 3000
encoding = "u8"
[[stage]]
name = "sky"
[[stage]]
name = "solar"
days = "1-59"
monthly = true
step_minutes = 60
"""


@pytest.fixture(scope="session")
def export_asset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The bundled SRTM tile (geographic, int16 with nodata) baked with
    EXPORT_RECIPE."""
    tmp = tmp_path_factory.mktemp("export_asset")
    recipe = tmp / "r.toml"
    recipe.write_text(EXPORT_RECIPE)
    asset = tmp / "srtm.tbake"
    dem = ROOT / "data/srtm3_n07w006_geographic_int16.tif"
    subprocess.run([BIN, "-q", "bake", dem, "-o", asset, "--recipe", recipe], check=True)
    return asset


def assert_same_dataset(stored, live, extra_attrs: set[str]) -> None:
    """An export opened by xarray (`stored`) is the asset opened with
    ``engine="terrabake"`` (`live`): the same variables, dimensions, values,
    attributes (but `extra_attrs`, which only the export carries) and
    coordinates."""
    import numpy as np

    assert set(stored.data_vars) == set(live.data_vars)
    assert {"height", "horizon", "svf", "solar_global"} <= set(stored.data_vars)
    for name in live.data_vars:
        got, want = stored[name], live[name]
        assert got.dims == want.dims, name
        # CF unpacks the u8 codes in float64 (in float32 in Debian's xarray,
        # a few 1e-6 apart); the asset decodes to float32.
        if "scale_factor" in got.encoding and got.dtype == np.float32:
            np.testing.assert_allclose(got.values, want.values, rtol=0, atol=3e-5, err_msg=name)
        else:
            np.testing.assert_array_equal(got.values.astype(np.float32), want.values, err_msg=name)
        got_attrs = {k: v for k, v in got.attrs.items() if k not in extra_attrs}
        want_attrs = dict(want.attrs)
        # NetCDF gives a list attribute back as an array or a list.
        for attrs in (got_attrs, want_attrs):
            for k, v in attrs.items():
                if isinstance(v, (list, tuple, np.ndarray)):
                    attrs[k] = [str(x) for x in v]
        assert got_attrs == want_attrs, name
    for coord in ("x", "y", "azimuth", "solar_global_band"):
        np.testing.assert_array_equal(stored[coord].values, live[coord].values, err_msg=coord)
    for key in ("crs_wkt", "GeoTransform"):
        assert stored["spatial_ref"].attrs[key] == live["spatial_ref"].attrs[key]
