#!/usr/bin/env bash
# `make bench-targets`: issue #17's speed targets measured on this machine
# in one run, each against its target, as a table for docs/BENCHMARKS.md.
# The two absolute targets (seconds) move with the machine, and the ratio
# of parametric to hierarchical tracing moves with its caches, so a claim
# that a target holds names the machine it held on; this says which hold
# here.
#
#   bash pipelines/bench_targets.sh    # BIN=, WORK=/tmp/terrabake-targets, RUNS=3, RATIO_RUNS=11
#
# - sector horizons: a 1024² fractal, 64 sectors, the horizons stage alone
#   (`--no-sky`), f32 bands; RUNS runs, wall time;
# - cone planes: an 8192² fractal, K = 256, default encoding; RUNS runs;
# - parametric against hierarchical tracing: the same DEM with its pyramid
#   and u16 cone planes (the planner's encoding), one thread, 15 passes a
#   run (`terrabake-bench views --repeat 15`), the ratio of the two medians in each of
#   RATIO_RUNS runs;
# - line horizons: our stage's wall time on the UTM tile, 16 directions,
#   at the default tolerance and within 4.5 degrees. The target is a ratio
#   to HORAYZON's whole process in the same run, which
#   `HORAYZON_SRC=... PEERS=horayzon TOLERANCE=4.5 make bench-peers` gives
#   (HORAYZON is built from a source tree: pipelines/peers/bench_peers.sh).
#
# Each row prints min, median and max; "met" compares the median.
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${BIN:-target/release/terrabake}
BENCH=${BENCH:-target/release/terrabake-bench}
WORK=${WORK:-/tmp/terrabake-targets}
RUNS=${RUNS:-3}
RATIO_RUNS=${RATIO_RUNS:-11}
DEM=${DEM:-../shared/data/srtm3_n07w006_utm90_f32.tif}
mkdir -p "$WORK"
source pipelines/bench_common.sh
say() { echo "bench-targets: $*" >&2; }

# A table row: work, target, the spread, and whether the median meets the
# target (`below` for seconds, `above` for ratios).
row() {
  local work=$1 target=$2 unit=$3 sense=$4
  read -r lo mid hi
  local met
  met=$(awk -v m="$mid" -v t="$target" -v s="$sense" 'BEGIN { print ((s == "below" ? m <= t : m >= t) ? "met" : "not met") }')
  echo "| $work | $target$unit | $lo-$hi$unit (median $mid$unit) | $met |"
}

say "assets in $WORK"
f1024=$(fractal_asset 1024)
f8192=$(fractal_asset 8192)
utm=$WORK/utm.tbake
[ -d "$utm" ] || "$BIN" ingest "$DEM" -o "$utm" -q
[ -n "$(ls "$f8192"/pyramid_max.L0.* 2>/dev/null)" ] || "$BIN" pyramid "$f8192" -q

say "line horizons (the UTM tile, 16 directions), $RUNS runs each"
line=() line45=()
for _ in $(seq "$RUNS"); do
  line+=("$(wall "$BIN" horizons "$utm" --method line --sectors 16 --no-sky --force -q)")
  line45+=("$(wall "$BIN" horizons "$utm" --method line --sectors 16 --no-sky --direction-tolerance 4.5 --force -q)")
done

say "sector horizons (1024², 64 sectors), $RUNS runs"
sector=()
for _ in $(seq "$RUNS"); do
  sector+=("$(wall "$BIN" horizons "$f1024" --method sector --sectors 64 --encoding f32 --no-sky --force -q)")
done

say "cone planes (8192², K = 256), $RUNS runs"
cones=()
for _ in $(seq "$RUNS"); do
  cones+=("$(wall "$BIN" cones "$f8192" --slices 256 --force -q)")
done

say "parametric against hierarchical (8192², u16 planes, one thread), $RATIO_RUNS runs"
"$BIN" cones "$f8192" --slices 256 --encoding u16 --force -q
ratios=()
for _ in $(seq "$RATIO_RUNS"); do
  RAYON_NUM_THREADS=1 "$BENCH" views "$f8192" --every 16 --methods hierarchical,parametric --repeat 15 --json > "$WORK/views.json"
  ratios+=("$(python3 -c '
import json, sys
seconds = {m["method"]: m["seconds"] for m in json.load(open(sys.argv[1]))["methods"]}
print("%.2f" % (seconds["hierarchical"] / seconds["parametric"]))' "$WORK/views.json")")
done

echo
echo "On $(lscpu | sed -n 's/^Model name: *//p'), $(nproc) cores, $(date -u +%F); $(git rev-parse --short HEAD 2>/dev/null || echo "no git")."
echo
echo "| work | target | measured here | here |"
echo "| --- | --- | --- | --- |"
printf '%s\n' "${sector[@]}" | spread | row "sector horizons, 1 M posts x 64 sectors" 5 " s" below
printf '%s\n' "${ratios[@]}" | spread | row "parametric against hierarchical tracing, 8192², one core" 1.5 x above
printf '%s\n' "${cones[@]}" | spread | row "cone planes, 8192², K = 256" 30 " s" below
echo
read -r lo mid hi < <(printf '%s\n' "${line[@]}" | spread)
read -r lo45 mid45 hi45 < <(printf '%s\n' "${line45[@]}" | spread)
echo "Line horizons, the UTM tile, 16 directions, horizons stage alone: $lo-$hi s (median $mid s) at the default tolerance, $lo45-$hi45 s (median $mid45 s) within 4.5 degrees."
awk -v a="$mid" -v b="$mid45" 'BEGIN { printf "The 50x target against HORAYZON holds where HORAYZON takes at least %.1f s (default tolerance) or %.1f s (within 4.5 degrees) in the same run: make bench-peers.\n", 50 * a, 50 * b }'
