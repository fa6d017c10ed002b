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
source "$(dirname "$0")/bench_common.sh"
ASSET=$(fractal_asset "$N")
RUN="$BIN horizons $ASSET --sectors 16 --force"
if run_in_cgroup 512 "$WORK/ooc.log" $RUN; then
  grep -E "horizons|Elapsed|Maximum resident|Exit" "$WORK/ooc.log"
  echo "cgroup limit 512 MiB; peak anonymous memory $PEAK_ANON_MIB MiB; peak usage with page cache $PEAK_CGROUP_MIB MiB"
else
  echo "(no memory cgroup: peak RSS only)"
  /usr/bin/time -v $RUN 2>&1 | grep -E "horizons|Elapsed|Maximum resident"
fi
du -sh "$ASSET"
