#!/usr/bin/env bash
# Cone planes (docs/BENCHMARKS.md). Bake time against DEM size (square fractal terrain, 1k to 8k
# posts a side) and slice count, with the exact cones beside them
# (docs/BENCHMARKS.md). Both cores; wall time and peak memory per bake.
# Then the speed of parametric tracing against bake time for K = 4 .. 1024
# and exact, in each encoding, on the SRTM tile, with the chart.
# Usage: make bench-cones [WORK=/tmp/terrabake-cones]
set -euo pipefail
BIN=${BIN:-target/release/terrabake}
BENCH=${BENCH:-target/release/terrabake-bench}
WORK=${WORK:-/tmp/terrabake-cones}
mkdir -p "$WORK"
source "$(dirname "$0")/bench_common.sh"
echo "| side | cells | slices | bake (s) | peak RSS (MiB) | ns per cell per slice |"
echo "| --- | --- | --- | --- | --- | --- |"
for n in 1024 2048 4096 8192; do
  asset=$(fractal_asset "$n")
  cells=$(( (n - 1) * (n - 1) ))
  for k in 16 64 256 exact; do
    /usr/bin/time -f "%e %M" -o "$WORK/time" "$BIN" cones "$asset" --slices "$k" --force -q
    read -r secs kb < "$WORK/time"
    per=$( [ "$k" = exact ] && echo "-" || awk -v s="$secs" -v c="$cells" -v k="$k" 'BEGIN { printf "%.2f", s * 1e9 / c / k }')
    echo "| $n | $cells | $k | $secs | $(( kb / 1024 )) | $per |"
  done
done
echo
echo "## Speed against bake time: SRTM N07W006, 16 views, 512 x 512, every 4th pixel, tracing on one thread"
"$BIN" bake data/srtm3_n07w006_geographic_int16.tif -o "$WORK/srtm.tbake" --recipe pipelines/demo.toml -q
"$BENCH" cones "$WORK/srtm.tbake" --encodings f32,f16,u16 --chart docs/charts/cones
