#!/usr/bin/env bash
# Out-of-core cone planes (docs/BENCHMARKS.md): a 16384 x 16384 fractal DEM
# (a 1 GiB height layer; in core the planes would need 8 GiB of working
# memory) baked with --max-memory 256 inside a 512 MiB memory cgroup, which
# also bounds the page cache of the memory-mapped layers. Needs root for the
# cgroup (v1 memory controller); without it only peak RSS is reported.
# Usage: bash pipelines/bench_cones_out_of_core.sh [WORK=/tmp/terrabake-cones]
set -euo pipefail
BIN=${BIN:-target/release/terrabake}
WORK=${WORK:-/tmp/terrabake-cones}
N=16384
mkdir -p "$WORK"
source "$(dirname "$0")/bench_common.sh"
ASSET=$(fractal_asset "$N")
RUN="$BIN cones $ASSET --slices 16 --max-memory 256 --force"
report_limited 512 "$WORK/ooc.log" cones $RUN
du -sh "$ASSET"
