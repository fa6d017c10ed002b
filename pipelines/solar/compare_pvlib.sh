#!/usr/bin/env bash
# terrabake solar beside pvlib on a flat open post: the day's clear-sky
# irradiation on the horizontal (global, beam, diffuse) at three latitudes
# and days 80, 172 and 355, Linke 3, 100 m above sea level, longitude 0.
# pvlib's side is its Ineichen-Perez clear sky (the Linke-turbidity model
# PV tools use; r.sun's ESRA model is not in pvlib) with the sun from its
# NREL SPA, summed minute by minute over the UTC day (the solar day at
# longitude 0 to within the equation of time, which a daily sum does not
# see). Prints markdown rows for docs/BENCHMARKS.md. pvlib comes from PyPI
# into a virtual environment under target/ (pipelines/solar/venv.sh).
#
#   bash pipelines/solar/compare_pvlib.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
PY=$(bash pipelines/solar/venv.sh)
cargo build --release --locked -q --bin terrabake
BIN=$(realpath target/release/terrabake)
work=$(mktemp -d /tmp/terrabake-pvlib.XXXXXX)
trap 'rm -rf "$work"' EXIT
"$BIN" -q synth flat --size 24x24 -o "$work/flat.tif"
"$BIN" -q ingest "$work/flat.tif" -o "$work/a.tbake"
"$BIN" -q horizons "$work/a.tbake" --sectors 16
for lat in 46 -33 60; do
  for day in 80 172 355; do
    "$BIN" -q solar "$work/a.tbake" --day "$day" --lat "$lat" --lon 0 --force -o "$work/s_${lat}_${day}.tif"
  done
done
"$PY" - "$work" <<'PY'
import sys
import warnings

import numpy as np
import pandas as pd
import pvlib
import tifffile

warnings.simplefilter("ignore")
work = sys.argv[1]
print("| latitude | day | ours global Wh/m2 | pvlib Ineichen global | diff % | ours beam | pvlib beam | ours diffuse | pvlib diffuse |")
print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
for lat in (46, -33, 60):
    for day in (80, 172, 355):
        bands = tifffile.imread(f"{work}/s_{lat}_{day}.tif")
        # Bands: global, beam, diffuse, reflected, sun hours; the centre post.
        g, b, d = (float(bands[12, 12, i]) if bands.ndim == 3 and bands.shape[-1] == 5
                   else float(bands[i, 12, 12]) for i in range(3))
        start = pd.Timestamp("2026-01-01", tz="UTC") + pd.Timedelta(days=day - 1)
        times = pd.date_range(start, periods=24 * 60, freq="1min") + pd.Timedelta(seconds=30)
        loc = pvlib.location.Location(lat, 0.0, altitude=100.0)
        sky = loc.get_clearsky(times, model="ineichen", linke_turbidity=3.0)
        sun = loc.get_solarposition(times)
        up = sun["apparent_elevation"] > 0
        ghi = float(sky["ghi"][up].sum()) / 60.0
        beam = float((sky["dni"] * np.cos(np.radians(sun["apparent_zenith"])))[up].sum()) / 60.0
        dhi = float(sky["dhi"][up].sum()) / 60.0
        diff = 100.0 * (g - ghi) / ghi if ghi > 0 else float("nan")
        print(f"| {lat} | {day} | {g:.0f} | {ghi:.0f} | {diff:+.1f} | {b:.0f} | {beam:.0f} | {d:.0f} | {dhi:.0f} |")
PY
