#!/usr/bin/env bash
# Out-of-core horizons (docs/BENCHMARKS.md), each inside a memory cgroup
# smaller than its DEM, which also bounds the page cache of the
# memory-mapped layers:
#   line:   a 16384 x 16384 fractal DEM (a 1 GiB height layer), 16
#           directions, 512 MiB;
#   sector: an 8192 x 8192 fractal DEM (256 MiB), 8 sectors within 150 m
#           (--max-distance: each tile row read with the rows within reach),
#           128 MiB.
# Needs root for the cgroup (v1 memory controller); without it only peak RSS
# is reported. Usage: [PARTS="line sector"] bash pipelines/bench_horizons_out_of_core.sh
set -euo pipefail
BIN=${BIN:-target/release/terrabake}
WORK=${WORK:-/tmp/terrabake-horizons}
PARTS=${PARTS:-line sector}
mkdir -p "$WORK"
source "$(dirname "$0")/bench_common.sh"

# run_limited NAME LIMIT_MIB ASSET ARGS...: one horizons run in the cgroup.
run_limited() {
  local name=$1 limit=$2 asset=$3
  shift 3
  local run="$BIN horizons $asset $* --force"
  echo "== $name: $run (limit $limit MiB)"
  report_limited "$limit" "$WORK/ooc_$name.log" horizons $run
  du -sh "$asset"
}

for part in $PARTS; do
  case $part in
    line) run_limited line 512 "$(fractal_asset "${N:-16384}")" --sectors 16 --max-memory 512 ;;
    sector) run_limited sector 128 "$(fractal_asset "${NS:-8192}")" --method sector --sectors 8 --max-distance 150 ;;
    *) echo "unknown part $part (line, sector)" >&2; exit 2 ;;
  esac
done
