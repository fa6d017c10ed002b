#!/usr/bin/env bash
# GRASS GIS reads terrabake's horizons as its own: bakes 16 horizon
# directions on the bundled SRTM tile, exports them with
# `terrabake export --layer horizon --for grass`, imports each file under
# its stem (r.in.gdal) and runs `r.sun horizon_basename=horizon
# horizon_step=22.5`, then checks the beam irradiance it gives against
# r.sun's own shadowing (no horizon maps) on the same region and day.
# Skipped, with a message, where GRASS is not installed (Debian: grass-core).
#
#   bash pipelines/gis/check_grass.sh [target/release/terrabake]
set -euo pipefail
bin=$(realpath "${1:-target/release/terrabake}")
dem=$(realpath data/srtm3_n07w006_geographic_int16.tif)
if ! command -v grass >/dev/null; then
  echo "check_grass.sh: skipped: GRASS GIS is not installed (apt-get install grass-core)"
  exit 0
fi
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cat >"$work/recipe.toml" <<'TOML'
description = "16 exact horizon lines for r.sun"
[[stage]]
name = "horizons"
sectors = 16
method = "line"
TOML
"$bin" --quiet bake "$dem" -o "$work/a.tbake" --recipe "$work/recipe.toml"
"$bin" export "$work/a.tbake" --layer horizon --for grass -o "$work/horizons"
ls "$work/horizons" | head -3
cat >"$work/run.sh" <<SH
set -euo pipefail
export GRASS_OVERWRITE=1 GRASS_VERBOSE=0
r.in.gdal --quiet input=$dem output=dem
for f in $work/horizons/horizon_*.tif; do
  r.in.gdal --quiet input=\$f output=\$(basename \$f .tif)
done
# A 300 x 300 post window keeps r.sun to seconds.
g.region raster=dem rows=300 cols=300 n=7.6 w=-5.6
r.slope.aspect elevation=dem slope=slope aspect=aspect
r.sun elevation=dem aspect=aspect slope=slope day=355 time=9 beam_rad=beam_ours \
  horizon_basename=horizon horizon_step=22.5
r.sun elevation=dem aspect=aspect slope=slope day=355 time=9 beam_rad=beam_grass
r.univar -g map=beam_ours > $work/ours.txt
r.univar -g map=beam_grass > $work/grass.txt
SH
grass -c EPSG:4326 "$work/db/loc" --exec bash "$work/run.sh" >"$work/grass.log" 2>&1 || {
  echo "check_grass.sh: GRASS failed:" >&2; tail -20 "$work/grass.log" >&2; exit 1; }
get() { sed -n "s/^$1=//p" "$2"; }
ours=$(get mean "$work/ours.txt"); theirs=$(get mean "$work/grass.txt")
n=$(get n "$work/ours.txt"); cells=$(get cells "$work/ours.txt")
echo "r.sun beam irradiance at 9:00 on day 355 over $n posts: mean $ours W/m2 with terrabake's horizons, $theirs W/m2 with r.sun's own shadowing"
awk -v a="$ours" -v b="$theirs" -v n="$n" -v c="$cells" 'BEGIN {
  d = (a - b) / b; if (d < 0) d = -d
  if (n != c) { print "check_grass.sh: r.sun left " c - n " posts null"; exit 1 }
  # 1.8 % apart while negative horizons wrapped in the bytes of r.sun; the same since.
  if (d > 0.005) { printf "check_grass.sh: means differ by %.2f%%\n", 100 * d; exit 1 }
  printf "check_grass.sh: ok (means within %.2f%%)\n", 100 * d }'
