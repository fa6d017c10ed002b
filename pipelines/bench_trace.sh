#!/usr/bin/env bash
# Tracing benchmarks (docs/BENCHMARKS.md), single-threaded for per-core
# figures: Paglieroni and Petersen's Table 1 on the bundled SRTM tile (16
# oblique views, 512 x 512, every 16th pixel and every pixel), cost by
# azimuth, and scaling with DEM size on fractal terrain.
# Usage: make bench-trace [WORK=/tmp/terrabake-trace]
set -euo pipefail
BIN=${BIN:-target/release/terrabake}
BENCH=${BENCH:-target/release/terrabake-bench}
WORK=${WORK:-/tmp/terrabake-trace}
mkdir -p "$WORK"
export RAYON_NUM_THREADS=1
"$BIN" bake data/srtm3_n07w006_geographic_int16.tif -o "$WORK/srtm.tbake" --recipe pipelines/demo.toml -q
echo "## SRTM N07W006, 16 views, 512 x 512, every 16th pixel"
"$BENCH" views "$WORK/srtm.tbake" --every 16 --repeat 5 --methods incremental,runs,hierarchical,parametric,brute-force
echo
echo "## SRTM N07W006, 16 views, 512 x 512, every pixel"
"$BENCH" views "$WORK/srtm.tbake" --every 1 --methods incremental,runs,hierarchical,parametric
echo
echo "## SRTM N07W006, cost per ray by azimuth (3600 rays each, 2 degrees down)"
"$BENCH" views "$WORK/srtm.tbake" --directions 16 --methods incremental,runs,hierarchical
echo
echo "## SRTM N07W006, runs against incremental by run length (Henning and Stephenson's figures)"
"$BENCH" views "$WORK/srtm.tbake" --run-lengths 1,2,3,4,5,6,8,10,16,25,100 --methods incremental,runs --repeat 15
echo
echo "## fractal terrain of growing size, 16 views, 512 x 512, every 16th pixel"
assets=()
for n in 1024 2048 4096 8192; do
  [ -f "$WORK/fractal_$n.tif" ] || "$BIN" synth fractal --size "${n}x${n}" -o "$WORK/fractal_$n.tif" -q
  "$BIN" bake "$WORK/fractal_$n.tif" -o "$WORK/fractal_$n.tbake" --recipe pipelines/demo.toml -q
  assets+=("$WORK/fractal_$n.tbake")
done
mkdir -p docs/charts
"$BENCH" views "${assets[@]}" --every 16 --repeat 5 --methods incremental,runs,hierarchical,parametric --chart docs/charts/trace_scaling
