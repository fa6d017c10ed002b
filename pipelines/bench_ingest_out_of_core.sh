#!/usr/bin/env bash
# Out-of-core ingest benchmark (docs/BENCHMARKS.md): a generated fractal
# float32 GeoTIFF of SIZE x SIZE posts (32768: 4 GiB) is ingested while the
# process may map at most LIMIT_KIB of address space (1 GiB: a quarter of the
# input), under /usr/bin/time -v. Cold (page cache dropped, where permitted)
# and warm runs. Usage: make bench-ingest-ooc [SIZE=32768] [WORK=/tmp/...]
set -euo pipefail
BIN=${BIN:-target/release/terrabake}
WORK=${WORK:-/tmp/terrabake-ooc}
SIZE=${SIZE:-32768}
LIMIT_KIB=${LIMIT_KIB:-1048576}
mkdir -p "$WORK"
SRC="$WORK/fractal_${SIZE}.tif"
if [ ! -f "$SRC" ]; then
  echo "generating $SRC"
  /usr/bin/time -f "synth: %e s, peak RSS %M KiB" "$BIN" synth fractal --size "${SIZE}x${SIZE}" -o "$SRC" --quiet
fi
BYTES=$(stat -c %s "$SRC")
for run in cold warm; do
  rm -rf "$WORK/fractal.tbake"
  if [ "$run" = cold ]; then sync; echo 3 > /proc/sys/vm/drop_caches 2>/dev/null || echo "(cannot drop page cache: cold run is warm)"; fi
  ( ulimit -v "$LIMIT_KIB"; /usr/bin/time -v "$BIN" ingest "$SRC" -o "$WORK/fractal.tbake" --quiet ) 2> "$WORK/time_$run.txt"
  secs=$(grep "Elapsed (wall clock)" "$WORK/time_$run.txt" | awk '{print $NF}' | awk -F: '{ if (NF==3) print $1*3600+$2*60+$3; else print $1*60+$2 }')
  rss=$(grep "Maximum resident set size" "$WORK/time_$run.txt" | awk '{print $NF}')
  echo "$run: input $((BYTES / 1048576)) MiB, address space limit $((LIMIT_KIB / 1024)) MiB, wall ${secs} s, peak RSS $((rss / 1024)) MiB, $(awk -v b="$BYTES" -v s="$secs" 'BEGIN{printf "%.0f", b/1048576/s}') MiB/s"
done
"$BIN" verify "$WORK/fractal.tbake"
