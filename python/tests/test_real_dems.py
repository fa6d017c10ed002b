"""Every command on the DEMs users have, not only on the project's own.

GDAL makes, from a crop of the bundled SRTM tile, the variants that real
DEMs come in: the georeferencing moved to 0, 45, 57, 70 and 80 degrees
north and south; warped to polar stereographic (north and south) and to a
non-UTM projection; written south-up; as int16, uint16, float32 and
float64; with nodata as -32768, -9999, NaN, exact and rounded -FLT_MAX
tags, a GDAL mask band (internal and in a .msk file) and none; as a point
and an area raster; and a whole SRTMHGT tile at 57 N, which once crashed
the planner. Every command runs on each (ingest, pyramid, cones, horizons
by every method, sky, render, viewshed, total-viewshed, profile, every
export, plan, bake --budget, check, the Python functions): none may fail
or panic; the georeferencing and the nodata are GDAL's reading of the
source; a planned bake meets its budget at check's own sampling.
"""

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

import terrabake

gdal = pytest.importorskip("osgeo.gdal", reason="GDAL's Python bindings (python3-gdal)")
osr = pytest.importorskip("osgeo.osr")
gdal.UseExceptions()

BIN = os.environ.get("TERRABAKE_BIN", "target/release/terrabake")
ROOT = Path(__file__).resolve().parents[2]
SRTM = ROOT / "data/srtm3_n07w006_geographic_int16.tif"
# 160 x 120 posts of the tile's steepest quarter.
CROP = (620, 80, 160, 120)
FLT_MAX = float(np.finfo(np.float32).max)


def run(*args: object, ok: bool = True) -> subprocess.CompletedProcess:
    done = subprocess.run([BIN, "--quiet", *map(str, args)], capture_output=True, text=True)
    assert "panicked" not in done.stderr, done.stderr
    if ok:
        assert done.returncode == 0, f"{args}: {done.stderr}"
    return done


def srs(code: int) -> str:
    s = osr.SpatialReference()
    s.ImportFromEPSG(code)
    return s.ExportToWkt()


def write(path: Path, z: np.ndarray, gt: tuple, wkt: str, dtype: int, nodata: object = None,
          point: bool = True, mask: object = None, internal_mask: bool = True) -> Path:
    """`z` (north-up) written as `gt` says: south-up when gt[5] > 0."""
    gdal.SetConfigOption("GDAL_TIFF_INTERNAL_MASK", "YES" if internal_mask else "NO")
    ds = gdal.GetDriverByName("GTiff").Create(str(path), z.shape[1], z.shape[0], 1, dtype,
                                              options=["TILED=YES", "BLOCKXSIZE=64", "BLOCKYSIZE=64"])
    ds.SetGeoTransform(gt)
    ds.SetProjection(wkt)
    if point:
        ds.SetMetadataItem("AREA_OR_POINT", "Point")
    band = ds.GetRasterBand(1)
    if nodata is not None:
        band.SetNoDataValue(nodata)
    band.WriteArray(z[::-1] if gt[5] > 0 else z)
    if mask is not None:
        ds.CreateMaskBand(gdal.GMF_PER_DATASET)
        band.GetMaskBand().WriteArray(np.where(mask[::-1] if gt[5] > 0 else mask, 0, 255).astype(np.uint8))
    ds = None
    gdal.SetConfigOption("GDAL_TIFF_INTERNAL_MASK", None)
    return path


def north_up(path: Path) -> tuple:
    """GDAL's reading of a raster: heights (float64, NaN where GDAL masks
    them) north-up, the north-up geotransform, and its CRS."""
    ds = gdal.Open(str(path))
    band = ds.GetRasterBand(1)
    z = band.ReadAsArray().astype(np.float64)
    z[band.GetMaskBand().ReadAsArray() == 0] = np.nan
    gt = list(ds.GetGeoTransform())
    if gt[5] > 0:
        z, gt[3], gt[5] = z[::-1], gt[3] + gt[5] * ds.RasterYSize, -gt[5]
    if gt[1] < 0:
        z, gt[0], gt[1] = z[:, ::-1], gt[0] + gt[1] * ds.RasterXSize, -gt[1]
    wkt = ds.GetProjection()
    ds = None
    return z, tuple(gt), wkt


def variants(tmp: Path) -> dict:
    src = gdal.Open(str(SRTM))
    z = src.GetRasterBand(1).ReadAsArray(*CROP).astype(np.float64)
    src = None
    h, w = z.shape
    step = 1 / 1200
    holes = np.zeros(z.shape, dtype=bool)
    holes[30:38, 40:70] = True
    holes[0, :12] = True  # on the edge too

    def at(lat: float, lon: float = 11.0, south_up: bool = False) -> tuple:
        """A grid whose north-west post is at (lon, lat), point georeferencing."""
        north = lat + 0.5 * step
        if south_up:
            return (lon - 0.5 * step, step, 0.0, north - h * step, 0.0, step)
        return (lon - 0.5 * step, step, 0.0, north, 0.0, -step)

    out = {}
    g = srs(4326)
    for lat in (0, 45, 57, 70, 80):
        for sign, hemisphere in ((1, "N"), (-1, "S")):
            north = sign * lat + (h * step if sign < 0 else 0.0)
            if lat == 0 and sign < 0:
                continue
            name = f"lat{lat}{hemisphere}"
            out[name] = write(tmp / f"{name}.tif", np.round(z), at(north), g, gdal.GDT_Int16, -32768)
    out["south_up"] = write(tmp / "south_up.tif", np.round(z), at(57.5, south_up=True), g,
                            gdal.GDT_Int16, -32768)
    holed = np.where(holes, -32768, np.round(z))
    out["int16_-32768"] = write(tmp / "i16.tif", holed, at(45.5), g, gdal.GDT_Int16, -32768)
    out["uint16_none"] = write(tmp / "u16.tif", np.round(z), at(45.5), g, gdal.GDT_UInt16)
    out["float32_-9999_area"] = write(tmp / "f32.tif", np.where(holes, -9999, z + 0.25), at(45.5), g,
                                      gdal.GDT_Float32, -9999, point=False)
    out["float64_nan"] = write(tmp / "f64.tif", np.where(holes, np.nan, z + 0.125), at(45.5), g,
                               gdal.GDT_Float64, float("nan"))
    out["float32_flt_max"] = write(tmp / "fmax.tif", np.where(holes, -FLT_MAX, z), at(45.5), g,
                                   gdal.GDT_Float32, -FLT_MAX)
    out["float32_rounded_flt_max"] = write(tmp / "fmax7.tif", np.where(holes, -FLT_MAX, z), at(45.5),
                                           g, gdal.GDT_Float32, -3.402823e38)
    out["mask_internal"] = write(tmp / "mask_in.tif", z, at(45.5), g, gdal.GDT_Float32, mask=holes)
    out["mask_external"] = write(tmp / "mask_ex.tif", z, at(45.5), g, gdal.GDT_Float32, mask=holes,
                                 internal_mask=False)
    # Projections: polar stereographic north and south, and Lambert's
    # equal-area Europe (no UTM zone), warped as users warp them.
    for name, base, code in (("polar_north", "lat70N", 3413), ("polar_south", "lat80S", 3031),
                             ("laea_europe", "lat45N", 3035)):
        path = tmp / f"{name}.tif"
        gdal.Warp(str(path), str(out[base]), dstSRS=f"EPSG:{code}", xRes=90, yRes=90,
                  outputType=gdal.GDT_Float32, dstNodata=-9999, resampleAlg="bilinear")
        out[name] = path
    # A whole SRTMHGT tile at 57 N (the planner's crash).
    full = tmp / "n57.tif"
    gdal.Translate(str(full), str(SRTM), outputBounds=[11 - 0.5 * step, 58 + 0.5 * step,
                                                        12 + 0.5 * step, 57 - 0.5 * step])
    out["hgt_N57E011"] = tmp / "N57E011.hgt"
    gdal.Translate(str(out["hgt_N57E011"]), str(full), format="SRTMHGT")
    return out


@pytest.fixture(scope="module")
def dems(tmp_path_factory: pytest.TempPathFactory) -> dict:
    return variants(tmp_path_factory.mktemp("real-dems"))


NAMES = ["lat0N", "lat45N", "lat45S", "lat57N", "lat57S", "lat70N", "lat70S", "lat80N", "lat80S",
         "south_up", "int16_-32768", "uint16_none", "float32_-9999_area", "float64_nan",
         "float32_flt_max", "float32_rounded_flt_max", "mask_internal", "mask_external",
         "polar_north", "polar_south", "laea_europe", "hgt_N57E011"]


@pytest.mark.parametrize("name", NAMES)
def test_every_command_on_a_real_dem_variant(dems: dict, name: str, tmp_path: Path) -> None:
    src = dems[name]
    asset = tmp_path / "a.tbake"
    run("ingest", src, "-o", asset)

    # Georeferencing and nodata: GDAL's reading of the source, north-up.
    run("export", asset, "--layer", "height", "-o", tmp_path / "h.tif")
    want, want_gt, want_wkt = north_up(src)
    got, got_gt, got_wkt = north_up(tmp_path / "h.tif")
    assert got_gt == pytest.approx(want_gt, rel=1e-12, abs=1e-9)
    a, b = osr.SpatialReference(want_wkt), osr.SpatialReference(got_wkt)
    assert a.IsSame(b), (want_wkt, got_wkt)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    np.testing.assert_array_equal(got, want.astype(np.float32))

    # Every stage and every reader.
    small = name != "hgt_N57E011"
    if small:
        run("pyramid", asset)
        run("cones", asset, "--slices", "auto")
        for method in ("sector", "sampled", "line"):
            run("horizons", asset, "--method", method, "--sectors", "8")
        run("sky", asset)
        run("total-viewshed", asset, "--directions", "8", "--max-distance", "1500")
        h, w = want.shape
        at = f"{w // 2},{h // 2}"
        run("render", asset, "--view", "3", "--size", "48x32", "--method", "parametric", "-o", tmp_path / "view.png")
        run("render", asset, "--shade", "sun:250,15", "-o", tmp_path / "sun.png")
        run("viewshed", asset, "--observer", at, "--crs", "grid", "-o", tmp_path / "v.tif")
        for fmt in ("csv", "json", "pvgis"):
            run("profile", asset, "--at", at, "--crs", "grid", "--format", fmt,
                "-o", tmp_path / f"p.{fmt}")
        for layer, out in (("svf", "svf.tif"), ("horizon", "hz.exr"), ("height", "relief.png"),
                           ("total_viewshed", "tv.png")):
            run("export", asset, "--layer", layer, "-o", tmp_path / out)
        run("export", asset, "--layer", "horizon", "--for", "grass", "-o", tmp_path / "grass")
        for program, out in (("unity", "t.raw"), ("unreal", "t.png"), ("godot", "t.exr")):
            run("export", asset, "--for", program, "-o", tmp_path / out)
        run("verify", asset)

        # The Python side reads the same asset and places it where GDAL does.
        opened = terrabake.open(asset)
        np.testing.assert_array_equal(opened.read("height"), want.astype(np.float32), strict=False)
        pytest.importorskip("rioxarray")
        da = opened.to_xarray("svf")
        west, south, east, north = da.rio.bounds()
        gt = want_gt
        assert (west, north) == pytest.approx((gt[0], gt[3]), abs=1e-9)
        assert (east, south) == pytest.approx((gt[0] + gt[1] * w, gt[3] + gt[5] * h), abs=1e-9)

    # Planned: plan, bake to the budget, and check meets it.
    budget = ["--budget", "horizon=1", "--needs", "horizons,svf"]
    run("plan", src, *budget)
    planned = tmp_path / "planned.tbake"
    run("bake", src, "-o", planned, *budget)
    check = run("check", planned, "--samples", "60", ok=False)
    assert check.returncode == 0 and "EXCEEDED" not in check.stdout, check.stdout + check.stderr
    assert "met" in check.stdout


def test_a_rotated_geotransform_is_refused_by_name(tmp_path: Path) -> None:
    z = np.arange(64 * 48, dtype=np.float64).reshape(48, 64)
    path = write(tmp_path / "rotated.tif", z, (11.0, 0.001, 0.0002, 57.0, 0.0002, -0.001), srs(4326),
                 gdal.GDT_Float32)
    done = run("ingest", path, "-o", tmp_path / "r.tbake", ok=False)
    assert done.returncode == 1
    assert "rotated.tif" in done.stderr and "rotated or sheared" in done.stderr
    assert not (tmp_path / "r.tbake").exists()


def test_check_reports_the_dems_edge_apart(dems: dict, tmp_path: Path) -> None:
    # A bake's check never blends the "nothing ahead" marker with a real
    # angle (once 80-91 degrees): at the edge the samples are counted apart.
    asset = tmp_path / "a.tbake"
    run("ingest", dems["lat57N"], "-o", asset)
    run("horizons", asset, "--sectors", "8")
    report = json.loads(run("check", asset, "--samples", "300", "--json", "--no-record").stdout)
    h = report["horizons"]
    assert h["edge_samples"] > 0 and h["edge_posts"] > 0
    assert h["horizon_max_deg"] < 20.0, h
