"""The Python package against the command line: the same numbers, or a
clear error. Assets are baked by the CLI (TERRABAKE_BIN, the release
binary `make test` built); the package must read and recompute them
exactly."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

import terrabake

BIN = os.environ.get("TERRABAKE_BIN", "target/release/terrabake")
ROOT = Path(__file__).resolve().parents[2]


def cli(*args: str) -> str:
    return subprocess.run(
        [BIN, "--quiet", *map(str, args)], check=True, capture_output=True, text=True
    ).stdout


RECIPE = """
description = "python tests"
[ingest]
tile = 32
[[stage]]
name = "horizons"
sectors = {sectors}
method = "{method}"
encoding = "f32"
curvature = {curvature}
[[stage]]
name = "sky"
"""


def baked(tmp: Path, method: str, curvature: bool = False, sectors: int = 16) -> Path:
    dem = tmp / "dem.tif"
    if not dem.exists():
        cli("synth", "fractal", "--size", "72x56", "--seed", "5", "-o", dem)
    recipe = tmp / f"{method}.toml"
    recipe.write_text(
        RECIPE.format(method=method, curvature=str(curvature).lower(), sectors=sectors)
    )
    out = tmp / f"{method}-{curvature}.tbake"
    cli("bake", dem, "-o", out, "--recipe", recipe)
    return out


@pytest.fixture(scope="module")
def tmp(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("tb")


@pytest.fixture(scope="module")
def line_asset(tmp: Path) -> terrabake.Asset:
    return terrabake.open(baked(tmp, "line"))


def cell_size(asset: terrabake.Asset) -> tuple[float, float]:
    m = json.loads(asset.manifest_json())
    return (m["cell_size"]["dx"], m["cell_size"]["dy"])


def test_read_gives_bands_first_float32_and_the_layers(line_asset: terrabake.Asset) -> None:
    z = line_asset.read("height")
    # One band: (rows, columns), as horizons() takes it.
    assert z.dtype == np.float32 and z.shape == (56, 72)
    hz = line_asset.read("horizon")
    assert hz.shape == (16, 56, 72)
    names = {(layer["name"], layer["level"]) for layer in line_asset.layers}
    assert {("height", 0), ("horizon", 0), ("svf", 0)} <= names
    az = line_asset.band_azimuths("horizon")
    assert len(az) == 16 and az == sorted(az) and az[0] == 0.0
    # Line bands sit on grid directions: not every one on a multiple of 22.5.
    assert any(abs(a - 22.5 * i) > 1e-9 for i, a in enumerate(az))
    assert line_asset.shape == (56, 72)
    assert len(line_asset.transform) == 6


def test_tiles_are_read_only_views_of_the_mapping(line_asset: terrabake.Asset) -> None:
    t = line_asset.tile("height", 0, 1, 1)
    assert t.shape == (32, 32) and t.dtype == np.float32
    assert not t.flags.writeable and not t.flags.owndata
    with pytest.raises(ValueError):
        t[0, 0] = 1.0
    # The same memory twice: no copy was made.
    again = line_asset.tile("height", 0, 1, 1)
    assert t.__array_interface__["data"][0] == again.__array_interface__["data"][0]
    z = line_asset.read("height")
    np.testing.assert_array_equal(t[:24, :32], z[32:56, 32:64])
    with pytest.raises(ValueError, match="outside layer"):
        line_asset.tile("height", 0, 9, 0)


def test_a_tile_keeps_the_asset_alive(tmp: Path) -> None:
    asset = terrabake.open(baked(tmp, "line"))
    t = asset.tile("height", 0, 0, 0)
    expected = t.copy()
    del asset
    import gc

    gc.collect()
    np.testing.assert_array_equal(t, expected)


@pytest.mark.parametrize("method", ["line", "sector"])
@pytest.mark.parametrize("curvature", [False, True])
def test_horizons_equal_the_cli_exactly(tmp: Path, method: str, curvature: bool) -> None:
    asset = terrabake.open(baked(tmp, method, curvature))
    z = asset.read("height")
    angles, az = terrabake.horizons(
        z, cell_size(asset), sectors=16, method=method, curvature=curvature
    )
    assert angles.dtype == np.float32 and angles.shape == (16, 56, 72)
    np.testing.assert_array_equal(az, asset.band_azimuths("horizon"))
    np.testing.assert_array_equal(angles, asset.read("horizon"))
    svf = terrabake.sky_view_factor(
        z, cell_size(asset), sectors=16, method=method, curvature=curvature
    )
    np.testing.assert_array_equal(svf, asset.read("svf"))


def test_float64_dems_and_progress(line_asset: terrabake.Asset) -> None:
    z = line_asset.read("height")
    calls: list[tuple[int, int]] = []
    angles, _ = terrabake.horizons(
        z.astype(np.float64), cell_size(line_asset), progress=lambda d, n: calls.append((d, n))
    )
    assert calls == [(i, 16) for i in range(1, 17)]
    np.testing.assert_array_equal(angles, line_asset.read("horizon"))

    def stop(done: int, total: int) -> None:
        if done == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        terrabake.horizons(z, (30.0, 30.0), progress=stop)


def test_the_gil_is_released_while_rust_works() -> None:
    z = np.random.default_rng(1).random((400, 400), dtype=np.float32) * 100
    ticks = 0
    done = threading.Event()

    def work() -> None:
        terrabake.horizons(z, (10.0, 10.0), sectors=32)
        done.set()

    thread = threading.Thread(target=work)
    thread.start()
    while not done.is_set():
        ticks += 1
        done.wait(0.001)
    thread.join()
    assert ticks > 5, "the main thread never ran while horizons worked"


@pytest.mark.parametrize(
    "dem, message",
    [
        (np.zeros((8, 8), dtype=np.complex64), "expected numbers"),
        (np.zeros((2, 8, 8), dtype=np.float32), "2-D"),
        (np.zeros((0, 8), dtype=np.float32), "at least 2 x 2"),
        (np.full((8, 8), np.nan, dtype=np.float32), "every post is NaN"),
        (np.array([["a", "b"], ["c", "d"]]), "expected numbers"),
    ],
)
def test_bad_arrays_are_value_errors(dem: object, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        terrabake.horizons(dem, (30.0, 30.0))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=message):
        terrabake.sky_view_factor(dem, (30.0, 30.0))  # type: ignore[arg-type]


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"cell_size": (0.0, 30.0)}, "cell_size"),
        ({"cell_size": (30.0, float("nan"))}, "cell_size"),
        ({"sectors": 2}, "sectors"),
        ({"method": "ray"}, "method"),
        ({"max_distance": -5.0}, "max_distance"),
        ({"progress": 3}, "progress"),
    ],
)
def test_bad_options_are_value_errors(kwargs: dict, message: str) -> None:
    args = {"cell_size": (30.0, 30.0), **kwargs}
    with pytest.raises(ValueError, match=message):
        terrabake.horizons(np.ones((8, 8), dtype=np.float32), **args)


def test_a_dem_past_memory_is_refused_before_any_work() -> None:
    # 4096 bands of 20000^2 angles (6.5 TB) fit no machine; np.empty does
    # not touch its 1.6 GB, and the refusal comes before the copy.
    try:
        dem = np.empty((20_000, 20_000), dtype=np.float32)
    except MemoryError:
        pytest.skip("this machine will not even reserve 1.6 GB of address space")
    with pytest.raises(terrabake.ResourceError, match="needs about .* of memory"):
        terrabake.horizons(dem, (30.0, 30.0), sectors=4096)


def test_errors_carry_the_cli_message_and_their_kind(tmp: Path) -> None:
    with pytest.raises(terrabake.AssetError, match="no-such.tbake"):
        terrabake.open(tmp / "no-such.tbake")
    bad = tmp / "bad.tif"
    bad.write_bytes(b"II*\x00garbage")
    with pytest.raises(terrabake.SourceError, match="bad.tif"):
        terrabake.bake(bad, tmp / "bad.tbake")
    assert not (tmp / "bad.tbake" / "manifest.tba").exists()
    # A stage parameter a recipe gives that the stage refuses.
    recipe = tmp / "two.toml"
    recipe.write_text('[[stage]]\nname = "horizons"\nsectors = 2\n')
    baked(tmp, "line")
    with pytest.raises(terrabake.ParameterError, match="sectors = 2"):
        terrabake.bake(tmp / "dem.tif", tmp / "two.tbake", recipe=recipe)
    for kind in (terrabake.AssetError, terrabake.SourceError, terrabake.ParameterError, terrabake.ResourceError):
        assert issubclass(kind, terrabake.Error)


def test_bake_from_python_equals_the_cli(tmp: Path, line_asset: terrabake.Asset) -> None:
    recipe = tmp / "from-python.toml"
    recipe.write_text(RECIPE.format(method="line", curvature="false", sectors=16))
    out = tmp / "from-python.tbake"
    outcomes = json.loads(terrabake.bake(tmp / "dem.tif", out, recipe=recipe))
    assert [o["stage"] for o in outcomes][:1] == ["ingest"]
    ours = terrabake.open(out)
    np.testing.assert_array_equal(ours.read("horizon"), line_asset.read("horizon"))
    terrabake.bake(tmp / "dem.tif", tmp / "planned.tbake", budget="horizon=1.0")
    planned = terrabake.open(tmp / "planned.tbake")
    assert any(layer["name"] == "svf" for layer in planned.layers)
    with pytest.raises(ValueError, match="budget"):
        terrabake.bake(tmp / "dem.tif", tmp / "x.tbake", budget="horizon")


def test_bake_reports_each_stage_and_stops_when_told(tmp: Path) -> None:
    recipe = tmp / "stages.toml"
    recipe.write_text(RECIPE.format(method="line", curvature="false", sectors=8))
    seen: list[tuple[str, int, int]] = []
    terrabake.bake(tmp / "dem.tif", tmp / "staged.tbake", recipe=recipe,
                   progress=lambda stage, done, total: seen.append((stage, done, total)))
    assert seen == [("ingest", 1, 3), ("horizons", 2, 3), ("sky", 3, 3)]

    class Stop(Exception):
        pass

    def stop(stage: str, done: int, total: int) -> None:
        if stage == "horizons":
            raise Stop(stage)

    out = tmp / "stopped.tbake"
    with pytest.raises(Stop):
        terrabake.bake(tmp / "dem.tif", out, recipe=recipe, progress=stop)
    # What was committed stays: the heights and the horizons, not the sky.
    names = {layer["name"] for layer in terrabake.open(out).layers}
    assert "horizon" in names and "svf" not in names
    # The same call resumes and finishes.
    terrabake.bake(tmp / "dem.tif", out, recipe=recipe)
    assert "svf" in {layer["name"] for layer in terrabake.open(out).layers}
    with pytest.raises(ValueError, match="progress"):
        terrabake.bake(tmp / "dem.tif", out, recipe=recipe, progress=3)


def test_to_xarray_names_azimuths_and_units(line_asset: terrabake.Asset) -> None:
    xr = pytest.importorskip("xarray")
    da = line_asset.to_xarray("horizon")
    assert isinstance(da, xr.DataArray)
    assert da.dims == ("band", "y", "x")
    np.testing.assert_array_equal(da["band"].values, line_asset.band_azimuths("horizon"))
    assert da.attrs["units"] == "deg" and da.attrs["method"] == "line"
    t = line_asset.transform
    assert da["x"].values[0] == pytest.approx(t[0] + 0.5 * t[1])


def test_a_panic_is_an_error_and_the_bake_it_broke_is_removed(tmp: Path) -> None:
    # A panic injected at the bake's fifth durable step (after the ingest
    # created the asset): terrabake.Error, an Exception, and no asset left.
    out = tmp / "panicked.tbake"
    code = (
        "import sys, terrabake\n"
        "try:\n"
        f"    terrabake.bake({str(tmp / 'dem.tif')!r}, {str(out)!r}, budget='horizon=1')\n"
        "except Exception as e:\n"
        "    print(type(e).__name__, isinstance(e, terrabake.Error), e)\n"
    )
    env = {**os.environ, "TERRABAKE_PANIC_AT": "5"}
    run = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert run.stdout.startswith("Error True bake: an internal error"), run.stdout
    assert "TERRABAKE_PANIC_AT=5" in run.stdout
    assert not out.exists()


def test_the_numpy_api_takes_what_users_have(line_asset: terrabake.Asset) -> None:
    z = line_asset.read("height")
    size = cell_size(line_asset)
    want, _ = terrabake.horizons(z, size, sectors=8)
    # Integer heights (SRTM's int16), float64, and a scalar cell size.
    square, _ = terrabake.horizons(z, size[0], sectors=8)
    np.testing.assert_array_equal(square, terrabake.horizons(z, (size[0], size[0]), sectors=8)[0])
    for dtype in (np.int16, np.uint16, np.int32, np.float64):
        ints = np.round(z).astype(dtype)
        got, _ = terrabake.horizons(ints, size, sectors=8)
        exact, _ = terrabake.horizons(np.round(z).astype(np.float32), size, sectors=8)
        np.testing.assert_array_equal(got, exact)
    # Nodata: a masked array, a NaN, and an integer sentinel are the same holes.
    holes = np.zeros(z.shape, dtype=bool)
    holes[10:14, 20:30] = True
    masked, _ = terrabake.horizons(np.ma.masked_array(z, holes), size, sectors=8)
    nan = z.copy()
    nan[holes] = np.nan
    np.testing.assert_array_equal(masked, terrabake.horizons(nan, size, sectors=8)[0])
    assert np.isnan(masked[:, holes]).all() and not np.isnan(masked[:, ~holes]).any()
    sentinel = np.round(z).astype(np.int16)
    sentinel[holes] = -32768
    np.testing.assert_array_equal(
        terrabake.horizons(sentinel, size, sectors=8, nodata=-32768)[0],
        terrabake.horizons(np.where(holes, np.nan, np.round(z)).astype(np.float32), size, sectors=8)[0],
    )
    # The command line's curvature rule: off for a bare array, on once the
    # grid is georeferenced.
    flat, _ = terrabake.horizons(z, size, sectors=8, curvature=False)
    np.testing.assert_array_equal(want, flat)
    curved, _ = terrabake.horizons(z, size, sectors=8, curvature=True)
    georeferenced, _ = terrabake.horizons(z, size, sectors=8, transform=line_asset.transform)
    np.testing.assert_array_equal(georeferenced, curved)


def test_the_python_surface_is_documented_and_clean() -> None:
    import inspect

    # Submodules (the xarray backend, once xarray has loaded it) aside.
    public = {
        n
        for n in dir(terrabake)
        if not n.startswith("_") and not inspect.ismodule(getattr(terrabake, n))
    }
    assert public == set(terrabake.__all__) - {"__version__"} | {"DEFAULT_REFRACTION"}, public
    assert issubclass(terrabake.Error, Exception) and terrabake.TerrabakeError is terrabake.Error
    for fn in (terrabake.horizons, terrabake.sky_view_factor):
        sig = inspect.signature(fn)
        assert sig.parameters["refraction"].default == 0.13
        assert sig.parameters["curvature"].default is None
    doc = terrabake.horizons.__doc__ or ""
    for name in inspect.signature(terrabake.horizons).parameters:
        assert name in doc, f"horizons' docstring says nothing of {name}"
    stubs = (Path(terrabake.__file__).parent / "_native.pyi").read_text()
    assert "class Error(Exception)" in stubs and "TerrabakeError = Error" in stubs


def test_to_xarray_round_trips_through_rioxarray_and_gdal(tmp: Path) -> None:
    rioxarray = pytest.importorskip("rioxarray")
    out = tmp / "geo.tbake"
    cli("ingest", ROOT / "data/srtm3_n07w006_geographic_int16.tif", "-o", out)
    asset = terrabake.open(out)
    da = asset.to_xarray("height")
    assert da.dims == ("y", "x") and "transform" not in da.attrs
    assert da.rio.crs.to_epsg() == 4326
    # The tile spans 6.0004 W .. 4.9996 W, 6.9996 N .. 8.0004 N (SRTM posts
    # sit on whole degrees; their pixels reach half a post beyond).
    west, south, east, north = da.rio.bounds()
    half = 0.5 / 1200
    assert (west, south, east, north) == pytest.approx((-6 - half, 7 - half, -5 + half, 8 + half), abs=1e-9)
    assert tuple(da.rio.transform().to_gdal()) == pytest.approx(asset.transform, abs=1e-12)
    tif = tmp / "from-xarray.tif"
    da.rio.to_raster(tif)
    info = json.loads(subprocess.run(["gdalinfo", "-json", str(tif)], check=True,
                                     capture_output=True, text=True).stdout)
    assert info["geoTransform"] == pytest.approx(list(asset.transform), abs=1e-12)
    assert "4326" in json.dumps(info["coordinateSystem"])
    back = rioxarray.open_rasterio(tif).squeeze("band", drop=True)
    np.testing.assert_array_equal(back.values, asset.read("height"))
    # And into horizons(): the DataArray's georeferencing turns curvature on.
    crop = da.isel(y=slice(0, 40), x=slice(0, 50)).rio.reproject("EPSG:32630")
    size = tuple(abs(v) for v in crop.rio.resolution())
    angles, _ = terrabake.horizons(crop, sectors=8)
    curved, _ = terrabake.horizons(crop.values, size, sectors=8, curvature=True)
    np.testing.assert_array_equal(angles, curved)


# GDAL: the exported COGs pass its validator and read back the asset's values.
gdal = pytest.importorskip("osgeo.gdal", reason="GDAL's Python bindings (python3-gdal)")


@pytest.mark.parametrize("layer", ["horizon", "svf", "height"])
@pytest.mark.parametrize("compress", ["deflate", "zstd"])
def test_cog_exports_pass_gdal_validator_and_read_back(
    tmp: Path, line_asset: terrabake.Asset, layer: str, compress: str
) -> None:
    from osgeo_utils.samples.validate_cloud_optimized_geotiff import validate

    out = tmp / f"{layer}-{compress}.tif"
    cli("export", line_asset.path, "--layer", layer, "--tile", "32", "--compress", compress, "-o", out)
    warnings, errors, _ = validate(str(out), full_check=True)
    assert errors == [], errors
    ds = gdal.Open(str(out))
    try:
        ours = line_asset.read(layer)
        assert ds.RasterCount == (ours.shape[0] if ours.ndim == 3 else 1)
        assert ds.GetGeoTransform() == pytest.approx(line_asset.transform, abs=0)
        assert ds.GetRasterBand(1).GetOverviewCount() >= 1
        np.testing.assert_array_equal(ds.ReadAsArray(), ours)
        if layer == "horizon":
            az = line_asset.band_azimuths("horizon")
            for b in range(ds.RasterCount):
                band = ds.GetRasterBand(b + 1)
                assert band.GetDescription() == f"horizon azimuth {az[b]:.2f} deg, line"
                assert band.GetUnitType() == "deg"
            assert ds.GetMetadataItem("METHOD") == "line"
            assert ds.GetMetadata("IMAGE_STRUCTURE")["INTERLEAVE"] == "BAND"
    finally:
        ds = None


def test_geographic_cog_keeps_the_crs(tmp: Path) -> None:
    out = tmp / "srtm.tbake"
    cli("ingest", ROOT / "data/srtm3_n07w006_geographic_int16.tif", "-o", out)
    tif = tmp / "srtm.tif"
    cli("export", out, "-o", tif)
    ds = gdal.Open(str(tif))
    try:
        assert "4326" in ds.GetSpatialRef().ExportToWkt()
        asset = terrabake.open(out)
        assert ds.GetGeoTransform() == pytest.approx(asset.transform, abs=0)
        assert [o.XSize for o in map(ds.GetRasterBand(1).GetOverview, range(2))] == [601, 301]
        np.testing.assert_array_equal(ds.ReadAsArray(), asset.read("height"))
    finally:
        ds = None


def test_solar_equals_the_cli_and_its_errors_are_the_cli_s(tmp: Path) -> None:
    import shutil

    source = baked(tmp, "line")
    ours, theirs = tmp / "solar-py.tbake", tmp / "solar-cli.tbake"
    for copy in (ours, theirs):
        shutil.rmtree(copy, ignore_errors=True)
        shutil.copytree(source, copy)
    cli("solar", theirs, "--day", "172", "--lat", "46", "--lon", "7")
    got = terrabake.solar(ours, 172, lat=46, lon=7)
    assert set(got) == {"global", "beam", "diffuse", "reflected", "sun_hours"}
    want = terrabake.open(theirs)
    for short, layer in [("global", "solar_global"), ("sun_hours", "sun_hours")]:
        np.testing.assert_array_equal(got[short], want.read(layer))
    assert np.nanmax(got["sun_hours"]) > 14 and np.nanmin(got["global"]) >= 0
    months = terrabake.solar(terrabake.open(ours), "150-200", monthly=True, lat=46)
    assert months["global"].shape == (3, *got["global"].shape)  # May, June, July
    # The DEM has no georeferencing: the CLI's message, naming --lat.
    with pytest.raises(terrabake.Error, match="--lat"):
        terrabake.solar(ours, 172, force=True)
    with pytest.raises(terrabake.Error, match="step"):
        terrabake.solar(ours, 172, lat=46, step=7)


def test_direct_correction_equals_the_command(tmp: Path) -> None:
    asset = baked(tmp, "line")
    suns = [(180.0, 30.0), (90.0, 8.0)]
    f = terrabake.direct_correction(asset, suns)
    rows, cols = terrabake.open(asset).shape
    assert f.shape == (2, rows, cols) and f.dtype == np.float32
    assert np.nanmin(f) == 0 and 0 < np.nanmax(f) <= 25
    # Low sun from the east: more of the terrain in shadow than at noon.
    assert (f[1] == 0).sum() > (f[0] == 0).sum()
    horizontal = terrabake.direct_correction(asset, suns, per_horizontal_area=True)
    assert np.all(horizontal >= f)
    out = tmp / "correction.tif"
    cli("solar", asset, "--sun", "180,30", "--sun", "90,8", "-o", out)
    gdal = pytest.importorskip("osgeo.gdal")
    ds = gdal.Open(str(out))
    assert ds.RasterCount == 2
    np.testing.assert_array_equal(ds.GetRasterBand(1).ReadAsArray(), f[0])
    with pytest.raises(ValueError, match="elevation"):
        terrabake.direct_correction(asset, [(180.0, 95.0)])


def same_layers(a: Path, b: Path) -> int:
    """Every layer of `a` equals `b`'s, NaN for NaN; returns how many."""
    x, y = terrabake.open(a), terrabake.open(b)
    names = sorted((l["name"], l["level"]) for l in x.layers)
    assert names == sorted((l["name"], l["level"]) for l in y.layers)
    for name, level in names:
        np.testing.assert_array_equal(x.read(name, level), y.read(name, level), err_msg=name)
    return len(names)


PARTS_RECIPE = """
[ingest]
tile = 16
[[stage]]
name = "horizons"
sectors = 8
max_distance = 400
[[stage]]
name = "sky"
"""


def test_a_bake_in_parts_equals_one_machine_here_and_on_dask(tmp: Path) -> None:
    baked(tmp, "line")  # the DEM
    recipe = tmp / "parts.toml"
    recipe.write_text(PARTS_RECIPE)
    one = tmp / "parts-one.tbake"
    terrabake.bake(tmp / "dem.tif", one, recipe=recipe)
    here = tmp / "parts-here.tbake"
    terrabake.bake(tmp / "dem.tif", here, recipe=recipe, parts=3)
    assert same_layers(one, here) >= 5
    with pytest.raises(ValueError, match="recipe"):
        terrabake.bake(tmp / "dem.tif", tmp / "x.tbake", budget="horizon=1", parts=2)
    distributed = pytest.importorskip("dask.distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None) as cluster:
        with distributed.Client(cluster) as client:
            on_dask = tmp / "parts-dask.tbake"
            records = json.loads(terrabake.bake(tmp / "dem.tif", on_dask, recipe=recipe, parts=4, client=client))
            assert records and all("stage" in r for r in records)
    assert same_layers(one, on_dask) >= 5


def test_dask_horizons_over_chunks_equal_the_cli_bake(tmp: Path) -> None:
    dask_array = pytest.importorskip("dask.array")
    xr = pytest.importorskip("xarray")
    line = terrabake.open(baked(tmp, "line"))
    size = cell_size(line)
    distance = 6.5 * min(size)
    z = line.read("height")
    da = xr.DataArray(dask_array.from_array(z, chunks=(20, 24)), dims=("y", "x"))
    got = terrabake.xarray.horizons(da, sectors=8, max_distance=distance, cell_size=size, curvature=False)
    assert got.dims == ("azimuth", "y", "x") and isinstance(got.data, dask_array.Array)
    recipe = tmp / "bounded.toml"
    recipe.write_text(
        f"[ingest]\ntile = 32\n[[stage]]\nname = \"horizons\"\nsectors = 8\nmethod = \"line\"\n"
        f"max_distance = {distance}\nencoding = \"f32\"\ncurvature = false\n"
    )
    out = tmp / "bounded.tbake"
    cli("bake", tmp / "dem.tif", "-o", out, "--recipe", recipe)
    want = terrabake.open(out)
    np.testing.assert_array_equal(got.values, want.read("horizon"))
    np.testing.assert_array_equal(got["azimuth"].values, want.band_azimuths("horizon"))
    with pytest.raises(ValueError, match="max_distance"):
        terrabake.xarray.horizons(da, 8)
    with pytest.raises(ValueError, match="rechunk"):
        terrabake.xarray.horizons(da.chunk(4), 8, distance, cell_size=size, curvature=False)


def test_profiles_of_many_points_equal_the_cli_s_one_by_one(tmp: Path) -> None:
    asset = baked(tmp, "line")
    points = [(10.0, 12.0), (40.0, 30.0), (71.0, 0.0)]
    got = terrabake.profile(asset, points, crs="grid", step=15.0, form="arrays")
    for (x, y), p in zip(points, got):
        text = cli("profile", asset, "--at", f"{x},{y}", "--crs", "grid", "--step", "15", "--format", "json")
        want = json.loads(text)
        assert tuple(p["post"]) == tuple(want["post"])
        np.testing.assert_array_equal(p["azimuth"], [q["azimuth_deg"] for q in want["points"]])
        # JSON holds the float32 angles in their shortest decimal form.
        want_h = np.asarray([q["horizon_deg"] for q in want["points"]], dtype=np.float32)
        np.testing.assert_array_equal(p["horizon"], want_h)
    pvgis = terrabake.profile(asset, points[:1], crs="grid", form="pvgis")[0]
    assert len(pvgis) == 48 and min(pvgis) >= 0
    pd = pytest.importorskip("pandas")
    series = terrabake.profile(asset, points[:2], crs="grid", step=30.0)[0]
    assert isinstance(series, pd.Series) and list(series.index) == [30.0 * i for i in range(12)]
    with pytest.raises(ValueError, match="crs"):
        terrabake.profile(asset, points, crs="utm")
    with pytest.raises(terrabake.Error, match="--at"):
        terrabake.profile(asset, [(500.0, 500.0)], crs="grid")
