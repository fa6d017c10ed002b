"""One Python peer on one DEM, for `make bench-peers` (bench_peers.sh).

    run_peer.py PEER DEM_TIF DEM_BIN ROWS COLS CELL DIRECTIONS OUT_DIR [SETTINGS]

PEER is one of whitebox_workflows, topocalc, surtgis, rvt, horayzon. DEM_BIN is the
same grid as DEM_TIF as raw little-endian float32, row-major, north up
(for the peers that take numpy arrays). The search radius is the whole
DEM (its diagonal) for every peer that has one, unless SETTINGS (a JSON
object: `radius_cells`, and for HORAYZON `hori_acc`, degrees) sets it:
the knobs bench_peers.py turns to draw each peer's curve.

Writes to OUT_DIR, in our conventions so that `terrabake-bench horizons
--peers` reads every peer alike:
  horizons.f32  the horizon elevation angle in degrees, one band per
                azimuth (band-major, raw float32), azimuths clockwise from
                north at i * 360 / DIRECTIONS;
  svf.f32       the peer's own sky-view factor, where it makes one;
  result.json   compute seconds (the peer's calls alone, not the start of
                Python, reading or writing), the version, the outputs and
                each conversion applied to the peer's convention.
"""

import json
import math
import os
import sys
import time
from importlib import metadata

import numpy as np


def main():
    peer, tif, raw, rows, cols, cell, directions, out = sys.argv[1:9]
    settings = json.loads(sys.argv[9]) if len(sys.argv) > 9 else {}
    unknown = set(settings) - {"radius_cells", "hori_acc"}
    if unknown:
        sys.exit(f"run_peer.py: unknown settings {sorted(unknown)}")
    rows, cols, cell, directions = int(rows), int(cols), float(cell), int(directions)
    os.makedirs(out, exist_ok=True)
    dem = np.fromfile(raw, dtype="<f4").reshape(rows, cols)
    radius_cells = settings.get("radius_cells", math.ceil(math.hypot(rows, cols)))
    azimuths = [i * 360.0 / directions for i in range(directions)]
    horizons, svf = None, None
    result = {"notes": []}
    if peer == "whitebox_workflows":
        import whitebox_workflows as wbw

        env = wbw.WbEnvironment()
        env.verbose = False
        raster = env.read_raster(tif)  # reading the GeoTIFF is not the peer's method
        t0 = time.perf_counter()
        bands = []
        for a in azimuths:
            h = env.horizon_angle(raster, azimuth=a, max_dist=radius_cells * cell)
            bands.append(np.asarray(h.to_numpy(), dtype=np.float32).reshape(rows, cols))
        result["seconds"] = time.perf_counter() - t0
        horizons = np.stack(bands)
        result["notes"].append("horizon_angle per azimuth: degrees, clockwise from north, as ours")
    elif peer == "topocalc":
        from topocalc.horizon import horizon
        from topocalc.viewf import viewf

        z = dem.astype(np.float64)
        t0 = time.perf_counter()
        bands = []
        for a in azimuths:
            # topocalc: 0 is south, positive through east, in -180..180.
            t = 180.0 - a
            t = t - 360.0 if t > 180.0 else t
            hcos = horizon(t, z, cell)
            # The cosine of the horizon's zenith angle is the sine of its elevation.
            bands.append(np.degrees(np.arcsin(np.clip(hcos, -1.0, 1.0))).astype(np.float32))
        result["seconds"] = time.perf_counter() - t0
        horizons = np.stack(bands)
        if directions >= 16:  # viewf refuses fewer angles
            t0 = time.perf_counter()
            svf = np.asarray(viewf(z, cell, nangles=directions)[0], dtype=np.float32)
            result["viewf_seconds"] = time.perf_counter() - t0
        result["notes"].append("horizon: azimuth = 180 - ours (0 south, east positive); elevation = asin(hcos)")
    elif peer == "surtgis":
        import surtgis

        z = dem.astype(np.float64)
        t0 = time.perf_counter()
        bands = [
            np.degrees(np.asarray(surtgis.horizon_angle_map_compute(z, cell, a, radius_cells)))
            for a in azimuths
        ]
        result["seconds"] = time.perf_counter() - t0
        horizons = np.stack(bands).astype(np.float32)
        result["notes"].append("horizon_angle_map_compute per azimuth: radians to degrees; it floors horizons at 0")
    elif peer == "rvt":
        import rvt.vis

        t0 = time.perf_counter()
        svf = rvt.vis.sky_view_factor(
            dem.astype(np.float32), cell, svf_n_dir=directions, svf_r_max=radius_cells
        )["svf"].astype(np.float32)
        result["seconds"] = time.perf_counter() - t0
        result["notes"].append("sky_view_factor: Zaksek's svf; no horizon angles come out")
    elif peer == "horayzon":
        import horayzon

        # A planar grid, x east and y north (rows run south), the horizon
        # measured from the horizontal: vertical normals, as in HORAYZON's
        # planar example.
        x = np.arange(cols, dtype=np.float32) * np.float32(cell)
        y = -np.arange(rows, dtype=np.float32) * np.float32(cell)
        vert_grid = horayzon.auxiliary.rearrange_pad_buffer(*np.meshgrid(x, y), dem)
        # Its default search (guess_constant) steps down until a ray hits
        # the terrain and never ends where none does: at its default lowest
        # elevation, -15 degrees, towards a DEM edge or off a cliff, and on
        # the outermost posts at any angle. So the lowest elevation is -90
        # degrees, and the outermost ring of posts is left out (NaN).
        up = np.zeros((rows - 2, cols - 2, 3), dtype=np.float32)
        up[:, :, 2] = 1.0
        north = np.zeros((rows - 2, cols - 2, 3), dtype=np.float32)
        north[:, :, 1] = 1.0
        t0 = time.perf_counter()
        hori, azim = horayzon.horizon.horizon_gridded(
            vert_grid, rows, cols, up, north, 1, 1,
            dist_search=radius_cells * cell / 1000.0, azim_num=directions,
            elev_ang_low_lim=-90.0, hori_acc=settings.get("hori_acc", 0.25),
        )
        result["seconds"] = time.perf_counter() - t0
        horizons = np.full((directions, rows, cols), np.nan, dtype=np.float32)
        horizons[:, 1:-1, 1:-1] = np.degrees(np.moveaxis(hori, 2, 0))
        result["notes"].append(
            "horizon_gridded: radians to degrees, azimuths clockwise from north as ours; its "
            "defaults (hori_acc 0.25 deg, guess_constant, rays from 0.01 m above the surface) but "
            "elev_ang_low_lim -90 and the outermost posts left out (else its search does not end)"
        )
    else:
        sys.exit(f"run_peer.py: unknown peer {peer!r}")
    if horizons is not None:
        horizons.astype("<f4").tofile(os.path.join(out, "horizons.f32"))
        result["horizons"] = "horizons.f32"
        result["azimuths_deg"] = azimuths
    if svf is not None:
        svf.astype("<f4").tofile(os.path.join(out, "svf.f32"))
        result["svf"] = "svf.f32"
    dist = {"whitebox_workflows": "whitebox-workflows", "rvt": "rvt-py"}.get(peer, peer)
    result["version"] = metadata.version(dist)
    with open(os.path.join(out, "result.json"), "w") as f:
        json.dump(result, f, indent=1)


if __name__ == "__main__":
    main()
