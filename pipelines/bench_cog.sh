#!/usr/bin/env bash
# COG export benchmark (docs/BENCHMARKS.md, "Cloud-Optimized GeoTIFF
# export"): a SIZE x SIZE fractal (16384: a 1 GiB height layer) ingested
# raw, then exported as a COG (deflate, zstd, none) inside a memory cgroup
# of LIMIT_MIB (256: a quarter of the layer; page cache included, as the
# kernel charges it), under /usr/bin/time -v: wall time, MiB/s of float32
# posts, peak RSS and the cgroup's peak. With OLD=path/to/older/terrabake,
# that binary's export runs too, alternating with ours. Then the bundled
# tile's 32-band horizon layer, alternating likewise. Root is needed for
# the cgroup (v1 memory controller); without it the limit is skipped, said.
#   make bench-cog [SIZE=16384] [LIMIT_MIB=256] [OLD=/tmp/old/terrabake]
set -euo pipefail
BIN=${BIN:-target/release/terrabake}
OLD=${OLD:-}
WORK=${WORK:-/tmp/terrabake-cog}
SIZE=${SIZE:-16384}
LIMIT_MIB=${LIMIT_MIB:-256}
mkdir -p "$WORK"
SRC="$WORK/fractal_${SIZE}.tif"
[ -f "$SRC" ] || "$BIN" synth fractal --size "${SIZE}x${SIZE}" -o "$SRC" --quiet
[ -d "$WORK/fractal.tbake" ] || "$BIN" ingest "$SRC" -o "$WORK/fractal.tbake" --quiet
cg=/sys/fs/cgroup/memory/terrabake-bench-cog
if mkdir -p "$cg" 2>/dev/null && echo $((LIMIT_MIB << 20)) > "$cg/memory.limit_in_bytes" 2>/dev/null; then
  limited=1
else
  limited=0; echo "(no memory cgroup here: runs are not limited)"
fi
run() { # label binary asset layer out extra...
  local label=$1 bin=$2 asset=$3 layer=$4 out=$5; shift 5
  rm -f "$out"
  [ $limited = 1 ] && echo 0 > "$cg/memory.max_usage_in_bytes" 2>/dev/null || true
  sh -c 'if [ "$1" = 1 ]; then echo $$ > "$2/cgroup.procs"; fi; shift 2; exec "$@"' _ "$limited" "$cg" \
    /usr/bin/time -v "$bin" export "$asset" --layer "$layer" -o "$out" --quiet "$@" 2> "$WORK/time.txt"
  local secs rss cgpeak mib
  secs=$(grep "Elapsed (wall clock)" "$WORK/time.txt" | awk '{print $NF}' | awk -F: '{ if (NF==3) print $1*3600+$2*60+$3; else print $1*60+$2 }')
  rss=$(grep "Maximum resident set size" "$WORK/time.txt" | awk '{print $NF}')
  cgpeak=$([ $limited = 1 ] && echo $(( $(cat "$cg/memory.max_usage_in_bytes") >> 20 )) || echo "-")
  mib=$(awk -v f="$(stat -c %s "$out")" 'BEGIN { printf "%.0f", f / 1048576 }')
  echo "| $label | $secs s | $(awk -v p="$POSTS_MIB" -v s="$secs" 'BEGIN { printf "%.0f", p / s }') MiB/s | $((rss / 1024)) MiB | $cgpeak MiB | $mib MiB |"
}
echo "| export | wall | posts (float32) per second | peak RSS | cgroup peak (limit ${LIMIT_MIB} MiB) | file |"
echo "| --- | --- | --- | --- | --- | --- |"
POSTS_MIB=$(( SIZE * SIZE * 4 >> 20 ))
for round in 1 2; do
  [ -n "$OLD" ] && run "height ${SIZE}^2, previous strip writer (round $round)" "$OLD" "$WORK/fractal.tbake" height "$WORK/old.tif"
  run "height ${SIZE}^2, COG deflate (round $round)" "$BIN" "$WORK/fractal.tbake" height "$WORK/cog.tif"
done
run "height ${SIZE}^2, COG zstd" "$BIN" "$WORK/fractal.tbake" height "$WORK/cog_zstd.tif" --compress zstd
run "height ${SIZE}^2, COG uncompressed" "$BIN" "$WORK/fractal.tbake" height "$WORK/cog_none.tif" --compress none
# The bundled tile's horizons: 32 bands of 1201^2 u8 codes, decoded.
DEMO="$WORK/srtm.tbake"
[ -d "$DEMO" ] || "$BIN" bake data/srtm3_n07w006_geographic_int16.tif -o "$DEMO" --recipe pipelines/demo.toml --quiet
POSTS_MIB=$(( 1201 * 1201 * 32 * 4 >> 20 ))
for round in 1 2; do
  [ -n "$OLD" ] && run "SRTM horizon, 32 bands, previous strip writer (round $round)" "$OLD" "$DEMO" horizon "$WORK/old_h.tif"
  run "SRTM horizon, 32 bands, COG deflate (round $round)" "$BIN" "$DEMO" horizon "$WORK/cog_h.tif"
done
if [ $limited = 1 ]; then rmdir "$cg" 2>/dev/null || true; fi
if python3 -c "import osgeo_utils" 2>/dev/null || /usr/bin/python3 -c "import osgeo_utils" 2>/dev/null; then
  for f in cog.tif cog_h.tif; do /usr/bin/python3 -m osgeo_utils.samples.validate_cloud_optimized_geotiff "$WORK/$f" | head -1; done
fi
