#!/usr/bin/env bash
# Horizons (docs/BENCHMARKS.md): speed and accuracy on the bundled SRTM tile
# (terrabake-bench horizons), the Fourier chart, then time and peak memory of the whole
# stage against DEM size and sector count on fractal DEMs.
# Usage: bash pipelines/bench_horizons.sh [WORK=/tmp/terrabake-horizons]
set -euo pipefail
BIN=${BIN:-target/release/terrabake}
BENCH=${BENCH:-target/release/terrabake-bench}
WORK=${WORK:-/tmp/terrabake-horizons}
mkdir -p "$WORK"
"$BIN" ingest data/srtm3_n07w006_geographic_int16.tif -o "$WORK/srtm.tbake" -q
# (The horizon and svf charts are make bench-peers's: the same study on the
# UTM tile with every peer beside our methods.)
"$BENCH" horizons "$WORK/srtm.tbake"
echo
# The demo's 32 line bands as Fourier coefficients: error against kept coefficients.
"$BIN" bake data/srtm3_n07w006_geographic_int16.tif -o "$WORK/demo.tbake" --recipe pipelines/demo.toml -q
"$BENCH" horizons "$WORK/demo.tbake" --fourier 1,2,3,4,6,8,12,15 --chart docs/charts/horizons
echo
echo "| DEM | method | sectors | time (s) | peak RSS (MiB) |"
echo "| --- | --- | --- | --- | --- |"
source "$(dirname "$0")/bench_common.sh"
run() { # side method sectors
  local asset
  asset=$(fractal_asset "$1")
  /usr/bin/time -f "%e %M" -o "$WORK/time.txt" "$BIN" horizons "$asset" --method "$2" --sectors "$3" --force -q
  read -r secs kb < "$WORK/time.txt"
  echo "| $1^2 | $2 | $3 | $secs | $((kb / 1024)) |"
}
for n in 1024 2048 4096 8192; do run $n line 16; done
for n in 1024 2048 4096; do run $n line 64; done
for n in 1024 2048 4096; do run $n sector 16; done
for n in 1024 2048; do run $n sector 64; done
