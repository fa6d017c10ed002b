#!/usr/bin/env bash
# Observer viewsheds of the bundled SRTM tile by terrabake and by GRASS
# r.viewshed, in one run, on the same grid: agreement (cross-tabulated in
# GRASS) and wall times, alternating. GRASS is installed from Debian's
# packages if missing. Prints markdown rows for docs/BENCHMARKS.md, and
# draws docs/charts/viewshed_rviewshed.svg (CHART=): time against the
# posts within reach, one curve per observer through its maximum
# distances, each of our points labelled with the two's agreement.
#
#   bash pipelines/compare_grass_viewshed.sh [RUNS]
set -euo pipefail
cd "$(dirname "$0")/.."
RUNS=${1:-3}
BIN=target/release/terrabake
BENCH=target/release/terrabake-bench
CHART=${CHART:-docs/charts/viewshed_rviewshed.svg}
DEM=data/srtm3_n07w006_geographic_int16.tif
WORK=$(mktemp -d /tmp/terrabake-grass.XXXXXX)
trap 'rm -rf "$WORK"' EXIT

if ! command -v grass >/dev/null; then
  echo "installing GRASS (Debian's grass-core)..." >&2
  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends grass-core >/dev/null
fi
cargo build --release --locked -q
cargo build --release --locked -q -p terrabake-bench --bin terrabake-bench
"$BIN" ingest "$DEM" -o "$WORK/srtm.tbake" -q

now() { date +%s.%N; }
# Observers: lon,lat (the tile is geographic); the first through five
# maximum distances (its curve on the chart), two more unbounded and 10 km.
CASES=("-5.5,7.5 10 2500" "-5.5,7.5 10 5000" "-5.5,7.5 10 10000" "-5.5,7.5 10 20000" "-5.5,7.5 10 none"
       "-5.25,7.75 10 10000" "-5.8,7.2 2 none")
printf "series\tkind\tlabel\tx\ty\n" > "$WORK/points.tsv"

cat > "$WORK/grass.sh" <<'EOF'
set -euo pipefail
r.in.gdal --q input="$DEM" output=dem
g.region raster=dem
read -r xy eye dist <<< "$CASE"
max=-1; [ "$dist" != none ] && max=$dist
t0=$(date +%s.%N)
r.viewshed -b -c -r --q input=dem output=theirs coordinates="$xy" observer_elevation="$eye" target_elevation=0 max_distance="$max" refraction_coeff=0.13 memory=2000
t1=$(date +%s.%N)
r.in.gdal --q input="$OURS" band=1 output=ours
# Outside our reach (NaN) is null in both.
r.mapcalc --q "oursi = if(isnull(ours), null(), int(ours))"
r.mapcalc --q "both = if(isnull(ours), null(), theirs)"
echo "grass_seconds $(echo "$t1 - $t0" | bc)"
r.stats -c -n input=oursi,both separator=space | sed 's/^/cell /'
EOF

echo "| observer (lon, lat) | eye | max distance | posts | agree | we see, r.viewshed not | r.viewshed sees, we not | terrabake s (command) | r.viewshed s |"
echo "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"
for c in "${CASES[@]}"; do
  read -r xy eye dist <<< "$c"
  extra=(); [ "$dist" != none ] && extra=(--max-distance "$dist")
  ours_t=(); grass_t=()
  for _ in $(seq "$RUNS"); do
    t0=$(now)
    "$BIN" viewshed "$WORK/srtm.tbake" --observer "$xy" --crs lonlat --observer-height "$eye" \
      --curvature on --refraction 0.13 "${extra[@]}" -o "$WORK/ours.tif" -q
    t1=$(now)
    ours_t+=("$(echo "$t1 - $t0" | bc)")
    out=$(DEM="$PWD/$DEM" OURS="$WORK/ours.tif" CASE="$c" grass --tmp-location "$PWD/$DEM" --exec bash "$WORK/grass.sh" 2>/dev/null)
    grass_t+=("$(echo "$out" | awk '/^grass_seconds/ {print $2}')")
  done
  # ours value, theirs value, count: 1 1 / 0 0 agree.
  read -r agree us them total < <(echo "$out" | awk '/^cell/ {n[$2" "$3]+=$4; t+=$4} END {print n["1 1"]+n["0 0"], n["1 0"]+0, n["0 1"]+0, t}')
  median() { printf '%s\n' "$@" | sort -g | awk '{a[NR]=$1} END {print a[int((NR+1)/2)]}'; }
  share=$(printf '%.2f' "$(echo "100 * $agree / $total" | bc -l)")
  printf '| %s | %s m | %s | %d | %s %% | %d | %d | %.2f | %.2f |\n' "$xy" "$eye" "$dist" "$total" \
    "$share" "$us" "$them" "$(median "${ours_t[@]}")" "$(median "${grass_t[@]}")"
  printf 'terrabake viewshed, %s, eye %s m\tline\t%s %%\t%s\t%s\n' "$xy" "$eye" "$share" "$total" "$(median "${ours_t[@]}")" >> "$WORK/points.tsv"
  printf 'GRASS r.viewshed, %s, eye %s m\tmark\t\t%s\t%s\n' "$xy" "$eye" "$total" "$(median "${grass_t[@]}")" >> "$WORK/points.tsv"
done
"$BENCH" points "$WORK/points.tsv" --chart "$CHART" \
  --title "Observer viewsheds beside r.viewshed: time against reach (labels: agreement)" \
  --x-label "posts within the maximum distance" --y-label "seconds (ours: the command, 2 cores; r.viewshed: the module)"
