#!/usr/bin/env bash
# terrabake solar beside GRASS r.sun, in one run, on the same grids: r.sun
# with its own shadowing and with terrabake's exported horizons, days 80,
# 172 and 355 at 15-minute steps, Linke 3, albedo 0.2, nprocs = the
# machine's cores. Prints markdown rows for docs/BENCHMARKS.md (seconds,
# and the mean and 95th percentile of |ours - r.sun| / r.sun of the daily
# global irradiation, per cent, over the posts both compute) and writes the
# day-172 difference maps (ours - r.sun with its own shadowing, per cent)
# to OUT/solar_vs_rsun_172_DEM.tif, and the projected DEMs' side by side
# with a legend to OUT/solar_vs_rsun_172.png (the demo page shows the copy
# in docs/charts/). GRASS is installed from Debian's packages if missing;
# the map's Python from PyPI (pipelines/solar/venv.sh).
#
#   bash pipelines/solar/compare_rsun.sh [OUT] [DEM ...]
# (default: the bundled tile, and ../shared/data's UTM copy of it and
# jacksboro_utm80_f32.tif where they exist; SECTORS=32 line directions)
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT=$(realpath -m "${1:-target/solar-vs-rsun}"); shift || true
DEMS=("$@")
if [ ${#DEMS[@]} -eq 0 ]; then
  DEMS=(data/srtm3_n07w006_geographic_int16.tif)
  for extra in srtm3_n07w006_utm90_f32 jacksboro_utm80_f32; do
    [ -f "../shared/data/$extra.tif" ] && DEMS+=("../shared/data/$extra.tif")
  done
fi
SECTORS=${SECTORS:-32}
mkdir -p "$OUT"
source pipelines/solar/common.sh

echo "| DEM | day | r.sun shadowing | r.sun s | terrabake s (horizons + sky + day) | mean abs diff % | p95 abs diff % |"
echo "|---|---|---|---:|---:|---:|---:|"
for dem in "${DEMS[@]}"; do
  dem=$(realpath "$dem")
  name=$(basename "$dem" .tif)
  work=$(mktemp -d /tmp/terrabake-rsun.XXXXXX)
  t0=$(now)
  "$BIN" --quiet ingest "$dem" -o "$work/a.tbake"
  "$BIN" --quiet horizons "$work/a.tbake" --sectors "$SECTORS" --method line
  t1=$(now)
  horizons_s=$(secs "$t0" "$t1")
  declare -A ours_s=()
  for day in 80 172 355; do
    t0=$(now)
    "$BIN" --quiet solar "$work/a.tbake" --day "$day" -o "$work/ours_$day.tif"
    ours_s[$day]=$(secs "$t0" "$(now)")
  done
  t0=$(now)
  "$BIN" --quiet solar "$work/a.tbake" --year -o "$work/ours_year.tif"
  year_s=$(secs "$t0" "$(now)")
  "$BIN" --quiet export "$work/a.tbake" --layer horizon --for grass -o "$work/hz"
  step=$(echo "scale=6; 360 / $SECTORS" | bc | sed 's/0*$//; s/\.$//')
  grass_script "$dem" >"$work/grass.sh"
  cat >>"$work/grass.sh" <<SH
for f in $work/hz/horizon_*.tif; do r.in.gdal --quiet input=\$f output=\$(basename \$f .tif); done
for day in 80 172 355; do
  r.in.gdal --quiet input=$work/ours_\$day.tif band=1 output=ours_\$day
  for how in own horizons; do
    extra=""; [ \$how = horizons ] && extra="horizon_basename=horizon horizon_step=$step"
    t0=\$(date +%s.%N)
    r.sun elevation=dem aspect=aspect slope=slope day=\$day step=0.25 linke_value=3.0 albedo_value=0.2 nprocs=$CORES glob_rad=g_\$how \$extra
    t1=\$(date +%s.%N)
    r.mapcalc --quiet "d = 100 * abs(ours_\$day - g_\$how) / g_\$how"
    mean=\$(r.univar -g map=d | sed -n 's/^mean=//p')
    p95=\$(r.univar -ge percentile=95 map=d | sed -n 's/^percentile_95=//p')
    echo "row \$day \$how \$(echo "\$t1 - \$t0" | bc) \$mean \$p95"
    if [ \$day = 172 ] && [ \$how = own ]; then
      r.mapcalc --quiet "signed = 100 * (ours_\$day - g_\$how) / g_\$how"
      r.out.gdal --quiet -c input=signed output=$OUT/solar_vs_rsun_172_$name.tif format=GTiff type=Float32 createopt=COMPRESS=DEFLATE 2>/dev/null
    fi
  done
done
SH
  run_grass "$dem" "$work"
  grep '^row ' "$work/grass.log" | while read -r _ day how rsun mean p95; do
    printf "| %s | %s | %s | %.1f | %.2f | %.2f | %.2f |\n" "$name" "$day" "$how" "$rsun" \
      "$(echo "$horizons_s + ${ours_s[$day]}" | bc)" "$mean" "$p95"
  done
  printf "| %s | 1-365 | (year, terrabake alone) | | %.2f (year only: %.2f) | | |\n" "$name" \
    "$(echo "$horizons_s + $year_s" | bc)" "$year_s"
  rm -rf "$work"
done
maps=()
for f in "$OUT"/solar_vs_rsun_172_*.tif; do
  name=$(basename "$f" .tif); name=${name#solar_vs_rsun_172_}
  # r.sun's own shadowing is wrong on geographic grids (docs/BENCHMARKS.md).
  [[ $name == *geographic* ]] || maps+=("$name=$f")
done
if [ ${#maps[@]} -gt 0 ]; then
  "$(bash pipelines/solar/venv.sh)" pipelines/solar/difference_map.py "$OUT/solar_vs_rsun_172.png" 2 "${maps[@]}"
fi
