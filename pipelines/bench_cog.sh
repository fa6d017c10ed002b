#!/usr/bin/env bash
# COG export benchmark (docs/BENCHMARKS.md, "Cloud-Optimized GeoTIFF
# export"): a SIZE x SIZE fractal (16384: a 1 GiB height layer) ingested
# raw, then exported as a COG (deflate, zstd, none) and as NetCDF-4 inside a memory cgroup
# of LIMIT_MIB (256: a quarter of the layer; page cache included, as the
# kernel charges it), under /usr/bin/time -v: wall time, MiB/s of float32
# posts, peak RSS (which counts the mapped input's pages, reclaimable) and
# the peak anonymous memory of the cgroup (memory.stat total_rss, sampled
# every 0.1 s): what the process itself holds. With OLD=path/to/older/terrabake,
# that binary's export runs too, alternating with ours (OLD_LABEL names it). Then the bundled
# tile's 32-band horizon layer, alternating likewise. Root is needed for
# the cgroup (v1 memory controller); without it the limit is skipped, said.
#   make bench-cog [SIZE=16384] [LIMIT_MIB=256] [OLD=/tmp/old/terrabake]
set -euo pipefail
BIN=${BIN:-target/release/terrabake}
OLD=${OLD:-}
OLD_LABEL=${OLD_LABEL:-previous strip writer}
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
measure() { # label out command...: one row of the table
  local label=$1 out=$2; shift 2
  rm -f "$out"
  local sampler=""
  if [ $limited = 1 ]; then
    ( while :; do sed -n 's/^total_rss //p' "$cg/memory.stat"; sleep 0.1; done ) > "$WORK/anon.txt" &
    sampler=$!
  fi
  local status=0
  sh -c 'if [ "$1" = 1 ]; then echo $$ > "$2/cgroup.procs"; fi; shift 2; exec "$@"' _ "$limited" "$cg" \
    /usr/bin/time -v "$@" 2> "$WORK/time.txt" || status=$?
  [ -n "$sampler" ] && kill "$sampler" 2>/dev/null && wait "$sampler" 2>/dev/null || true
  if [ $status != 0 ]; then echo "| $label | failed (status $status: killed at the limit?) | | | | |"; return; fi
  local secs rss anon mib
  secs=$(grep "Elapsed (wall clock)" "$WORK/time.txt" | awk '{print $NF}' | awk -F: '{ if (NF==3) print $1*3600+$2*60+$3; else print $1*60+$2 }')
  rss=$(grep "Maximum resident set size" "$WORK/time.txt" | awk '{print $NF}')
  anon=$([ $limited = 1 ] && sort -n "$WORK/anon.txt" | tail -1 | awk '{ printf "%.0f", $1 / 1048576 }' || echo "-")
  mib=$(awk -v f="$(stat -c %s "$out")" 'BEGIN { printf "%.0f", f / 1048576 }')
  echo "| $label | $secs s | $(awk -v p="$POSTS_MIB" -v s="$secs" 'BEGIN { printf "%.0f", p / s }') MiB/s | $((rss / 1024)) MiB | $anon MiB | $mib MiB |"
}
run() { # label binary asset layer out extra...
  local label=$1 bin=$2 asset=$3 layer=$4 out=$5; shift 5
  measure "$label" "$out" "$bin" export "$asset" --layer "$layer" -o "$out" --quiet "$@"
}
echo "| export | wall | posts (float32) per second | peak RSS | peak anonymous memory (cgroup limit ${LIMIT_MIB} MiB) | file |"
echo "| --- | --- | --- | --- | --- | --- |"
POSTS_MIB=$(( SIZE * SIZE * 4 >> 20 ))
for round in 1 2; do
  [ -n "$OLD" ] && run "height ${SIZE}^2, $OLD_LABEL (round $round)" "$OLD" "$WORK/fractal.tbake" height "$WORK/old.tif"
  run "height ${SIZE}^2, COG deflate (round $round)" "$BIN" "$WORK/fractal.tbake" height "$WORK/cog.tif"
done
run "height ${SIZE}^2, COG zstd" "$BIN" "$WORK/fractal.tbake" height "$WORK/cog_zstd.tif" --compress zstd
# The same heights as NetCDF-4 (shuffle and deflate, 256^2 chunks), beside.
run "height ${SIZE}^2, NetCDF-4 deflate" "$BIN" "$WORK/fractal.tbake" height "$WORK/height.nc"
# The peer: GDAL's COG driver on the same heights (the synthetic GeoTIFF,
# tiled 512 and uncompressed, so its reading is as cheap as our mapping),
# its default levels, every core, a 64 MiB block cache to fit the cgroup.
gdal_cog() { # label out compression
  GDAL_CACHEMAX=64 measure "$1" "$2" gdal_translate -q -of COG -co COMPRESS="$3" -co PREDICTOR=YES \
    -co NUM_THREADS=ALL_CPUS -co BLOCKSIZE=512 "$SRC" "$2"
}
if command -v gdal_translate >/dev/null; then
  gdal_cog "height ${SIZE}^2, $(gdalinfo --version | cut -d, -f1) COG DEFLATE" "$WORK/gdal.tif" DEFLATE
  gdal_cog "height ${SIZE}^2, GDAL COG ZSTD" "$WORK/gdal_zstd.tif" ZSTD
else
  echo "(gdal_translate not installed: the GDAL rows are left out)"
fi
run "height ${SIZE}^2, COG uncompressed" "$BIN" "$WORK/fractal.tbake" height "$WORK/cog_none.tif" --compress none
# The bundled tile's horizons: 32 bands of 1201^2 u8 codes, decoded.
DEMO="$WORK/srtm.tbake"
[ -d "$DEMO" ] || "$BIN" bake data/srtm3_n07w006_geographic_int16.tif -o "$DEMO" --recipe pipelines/demo.toml --quiet
POSTS_MIB=$(( 1201 * 1201 * 32 * 4 >> 20 ))
for round in 1 2; do
  [ -n "$OLD" ] && run "SRTM horizon, 32 bands, $OLD_LABEL (round $round)" "$OLD" "$DEMO" horizon "$WORK/old_h.tif"
  run "SRTM horizon, 32 bands, COG deflate (round $round)" "$BIN" "$DEMO" horizon "$WORK/cog_h.tif"
done
if [ $limited = 1 ]; then rmdir "$cg" 2>/dev/null || true; fi
if python3 -c "import osgeo_utils" 2>/dev/null || /usr/bin/python3 -c "import osgeo_utils" 2>/dev/null; then
  for f in cog.tif cog_h.tif; do /usr/bin/python3 -m osgeo_utils.samples.validate_cloud_optimized_geotiff "$WORK/$f" | head -1; done
fi
