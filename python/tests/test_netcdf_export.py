"""``terrabake export A --layer all -o A.nc`` read back by the NetCDF
clients users have: xarray through netCDF4-python (netCDF-C and HDF5's C
library) and through h5netcdf (h5py), and GDAL's netCDF driver. The file
is the same dataset as ``xr.open_dataset(A, engine="terrabake")`` (values,
dimensions, coordinates, attributes), with quantised horizons kept as their
u8 codes and CF's packing, chunks the asset's tiles, deflate, and GDAL's
georeferencing equal to the GeoTIFF export's. pipelines/python/test.sh runs
it in both of its environments (Debian's netCDF4 and GDAL; PyPI's netCDF4
and h5netcdf); a client that is missing is skipped."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

xr = pytest.importorskip("xarray")

import terrabake  # noqa: E402
from conftest import assert_same_dataset  # noqa: E402

BIN = os.environ.get("TERRABAKE_BIN", "target/release/terrabake")
ROOT = Path(__file__).resolve().parents[2]
DEM = ROOT / "data/srtm3_n07w006_geographic_int16.tif"



def _engines() -> list[str]:
    found = []
    for engine, modules in (("netcdf4", ["netCDF4"]), ("h5netcdf", ["h5netcdf", "h5py"])):
        try:
            for module in modules:
                __import__(module)
            found.append(engine)
        except ImportError:
            pass
    return found


ENGINES = _engines()
if not ENGINES:
    pytest.skip("neither netCDF4 nor h5netcdf is installed", allow_module_level=True)


@pytest.fixture(scope="module")
def baked(export_asset: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The shared asset (conftest.py) and every layer of its post grid exported to one NetCDF file."""
    nc = tmp_path_factory.mktemp("nc") / "srtm.nc"
    subprocess.run([BIN, "-q", "export", export_asset, "--layer", "all", "-o", nc], check=True)
    return export_asset, nc


@pytest.mark.parametrize("engine", ENGINES)
def test_xarray_opens_the_file_as_the_backend_opens_the_asset(baked: tuple[Path, Path], engine: str) -> None:
    asset, nc = baked
    with xr.open_dataset(nc, engine=engine) as stored:
        live = xr.open_dataset(asset, engine="terrabake")
        # The file also says which coordinate is the grid mapping (the
        # backend keeps that in encoding).
        assert_same_dataset(stored, live, {"grid_mapping"})
        assert stored.attrs["Conventions"] == "CF-1.8"
        # Codes kept, chunked by tiles, deflated.
        encoding = stored["horizon"].encoding
        assert encoding["dtype"] == np.uint8
        assert tuple(encoding["chunksizes"]) == (1, 128, 128)
        assert encoding.get("zlib") or encoding.get("compression") == "gzip"


def test_the_cf_grid_mapping_is_the_crs_without_its_wkt(baked: tuple[Path, Path]) -> None:
    """CF's grid_mapping_name and parameters alone (crs_wkt left out) give
    pyproj the asset's CRS: the same coordinates for the same points."""
    pyproj = pytest.importorskip("pyproj")
    _, nc = baked
    with xr.open_dataset(nc, engine=ENGINES[0]) as d:
        attrs = dict(d["spatial_ref"].attrs)
    assert attrs["grid_mapping_name"] == "latitude_longitude"
    cf = {k: v for k, v in attrs.items() if k not in ("crs_wkt", "spatial_ref", "GeoTransform", "epsg_code")}
    crs = pyproj.CRS.from_cf(cf)
    want = pyproj.CRS.from_wkt(attrs["crs_wkt"])
    assert crs.ellipsoid.semi_major_metre == want.ellipsoid.semi_major_metre
    assert abs(crs.ellipsoid.inverse_flattening - want.ellipsoid.inverse_flattening) < 1e-9


def test_netcdf4_reads_the_codes_and_their_packing(baked: tuple[Path, Path]) -> None:
    netCDF4 = pytest.importorskip("netCDF4")
    asset, nc = baked
    with netCDF4.Dataset(nc) as d:
        assert d.file_format == "NETCDF4"
        horizon = d["horizon"]
        assert horizon.dimensions == ("azimuth", "y", "x")
        horizon.set_auto_maskandscale(False)
        codes = horizon[:]
        assert codes.dtype == np.uint8
        decoded = np.where(
            codes == horizon._FillValue, np.nan, horizon.add_offset + horizon.scale_factor * codes
        ).astype(np.float32)
        np.testing.assert_array_equal(decoded, terrabake.open(asset).read("horizon"))
        assert horizon.filters()["zlib"] and horizon.chunking() == [1, 128, 128]
        assert d["height"].dtype == np.float32 and np.isnan(d["height"]._FillValue)


def test_gdal_reads_georeferencing_and_values_as_the_geotiff(baked: tuple[Path, Path], tmp_path: Path) -> None:
    gdal = pytest.importorskip("osgeo.gdal")
    gdal.UseExceptions()
    asset, nc = baked
    tif = tmp_path / "horizon.tif"
    subprocess.run([BIN, "-q", "export", asset, "--layer", "horizon", "-o", tif], check=True)
    exported = gdal.Open(str(tif))
    ds = gdal.Open(f'NETCDF:"{nc}":horizon')
    assert ds.RasterCount == exported.RasterCount == 8
    np.testing.assert_allclose(ds.GetGeoTransform(), exported.GetGeoTransform(), rtol=0, atol=1e-12)
    from osgeo import osr

    assert osr.SpatialReference(ds.GetProjection()).IsSame(osr.SpatialReference(exported.GetProjection()))
    band = ds.GetRasterBand(1)
    codes = band.ReadAsArray().astype(np.float64)
    decoded = np.where(codes == band.GetNoDataValue(), np.nan, band.GetOffset() + band.GetScale() * codes)
    np.testing.assert_allclose(decoded, exported.GetRasterBand(1).ReadAsArray(), rtol=0, atol=1e-5)


def test_many_chunks_and_a_small_tile(tmp_path: Path) -> None:
    """Heights in 16-post tiles: 5776 chunks, a three-level chunk index."""
    netCDF4 = pytest.importorskip("netCDF4")
    recipe = tmp_path / "r.toml"
    recipe.write_text("[ingest]\ntile = 16\n")
    asset = tmp_path / "a.tbake"
    subprocess.run([BIN, "-q", "bake", DEM, "-o", asset, "--recipe", recipe], check=True)
    nc = tmp_path / "a.nc"
    subprocess.run([BIN, "-q", "export", asset, "--layer", "height", "-o", nc], check=True)
    with netCDF4.Dataset(nc) as d:
        got = np.ma.filled(d["height"][:].astype(np.float32), np.nan)
    np.testing.assert_array_equal(got, terrabake.open(asset).read("height"))
