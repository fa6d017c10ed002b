#!/usr/bin/env bash
# Out-of-core line horizons (docs/BENCHMARKS.md): a 16384 x 16384 fractal
# DEM (a 1 GiB height layer) swept in 16 directions inside a 512 MiB memory
# cgroup, which also bounds the page cache of the memory-mapped layers.
# Needs root for the cgroup (v1 memory controller); without it only peak RSS
# is reported. Usage: bash pipelines/bench_horizons_out_of_core.sh
set -euo pipefail
BIN=${BIN:-target/release/terrabake}
WORK=${WORK:-/tmp/terrabake-horizons}
N=${N:-16384}
mkdir -p "$WORK"
if [ ! -d "$WORK/fractal_$N.tbake" ]; then
  "$BIN" synth fractal --size "${N}x${N}" -o "$WORK/fractal_$N.tif" -q
  "$BIN" ingest "$WORK/fractal_$N.tif" -o "$WORK/fractal_$N.tbake" -q
  rm -f "$WORK/fractal_$N.tif"
fi
RUN="$BIN horizons $WORK/fractal_$N.tbake --sectors 16 --force"
CG=/sys/fs/cgroup/memory/terrabake-bench
if mkdir -p "$CG" 2>/dev/null && echo $((512 << 20)) > "$CG/memory.limit_in_bytes" 2>/dev/null; then
  echo 0 > "$CG/memory.max_usage_in_bytes"
  # Start cold, so that every page the run maps counts against the limit.
  sync && echo 3 > /proc/sys/vm/drop_caches
  bash -c "echo \$\$ > $CG/cgroup.procs && exec /usr/bin/time -v $RUN" > "$WORK/ooc.log" 2>&1 &
  # Peak anonymous memory (the process's own: row windows, hulls, tile
  # rows), sampled from the cgroup; the rest of its usage is page cache of
  # the mapped layers, which the limit keeps reclaiming.
  peak=0
  while kill -0 $! 2>/dev/null; do
    rss=$(awk '$1 == "rss" { print $2 }' "$CG/memory.stat")
    [ "$rss" -gt "$peak" ] && peak=$rss
    sleep 0.2
  done
  wait $!
  grep -E "horizons|Elapsed|Maximum resident|Exit" "$WORK/ooc.log"
  echo "cgroup limit 512 MiB; peak anonymous memory $((peak >> 20)) MiB; peak usage with page cache $(( $(cat "$CG/memory.max_usage_in_bytes") >> 20 )) MiB"
else
  echo "(no memory cgroup: peak RSS only)"
  /usr/bin/time -v $RUN 2>&1 | grep -E "horizons|Elapsed|Maximum resident"
fi
du -sh "$WORK/fractal_$N.tbake"
