#!/usr/bin/env bash
# The planner's chart (docs/PLANNING.md): plan, bake and check every DEM at
# every budget. The bundled SRTM tile, the held-out DEMs of ../shared/data
# (the planner was never tuned on them; skipped where absent) and the
# synthetic terrains the issue names (spike, bowl, cliffs, flat, 8-bit
# fractal) at 256 x 256 with a seed the tests never use. Writes the table to
# stdout and docs/charts/planning_{error,cost}.svg.
#   BIN=target/release/terrabake bash pipelines/bench_plan.sh
set -euo pipefail
BIN=${BIN:-target/release/terrabake}
BENCH=${BENCH:-target/release/terrabake-bench}
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
assets=()
ingest() { "$BIN" ingest "$1" -o "$WORK/$2.tbake" -q; assets+=("$WORK/$2.tbake"); }
ingest data/srtm3_n07w006_geographic_int16.tif srtm_geographic
for held_out in jacksboro_utm80_f32 srtm3_n07w006_utm90_f32; do
  [ -f "../shared/data/$held_out.tif" ] && ingest "../shared/data/$held_out.tif" "$held_out"
done
for kind in spike bowl blocks flat quantised; do
  "$BIN" synth "$kind" --size 256x256 --seed 4242 -o "$WORK/$kind.tif" -q
  ingest "$WORK/$kind.tif" "synthetic_$kind"
done
"$BENCH" plan "${assets[@]}" --budgets 0.25,0.5,1,2,4 --chart docs/charts/planning
