#!/usr/bin/env bash
# terrabake solar beside GRASS r.sun, in one run, on the same grids: r.sun
# with its own shadowing and with terrabake's exported horizons, days 80,
# 172 and 355 at 15-minute steps, Linke 3, albedo 0.2, nprocs = the
# machine's cores. Prints markdown rows for docs/BENCHMARKS.md (seconds,
# and the mean and 95th percentile of |ours - r.sun| / r.sun of the daily
# global irradiation, per cent, over the posts both compute) and writes the
# day-172 difference map (ours - r.sun with its own shadowing, per cent)
# to OUT/solar_vs_rsun_172.tif. GRASS is installed from Debian's packages
# if missing.
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
CORES=$(nproc)
BIN=$(realpath target/release/terrabake)
mkdir -p "$OUT"
if ! command -v grass >/dev/null; then
  echo "installing GRASS (Debian's grass-core)..." >&2
  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends grass-core >/dev/null
fi
cargo build --release --locked -q
now() { date +%s.%N; }
secs() { echo "$2 - $1" | bc; }

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
  cat >"$work/grass.sh" <<SH
set -euo pipefail
export GRASS_OVERWRITE=1 GRASS_VERBOSE=0
r.in.gdal --quiet input=$dem output=dem
g.region raster=dem
r.slope.aspect elevation=dem slope=slope aspect=aspect
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
  grass -c "$dem" "$work/db/loc" --exec bash "$work/grass.sh" >"$work/grass.log" 2>&1 || {
    echo "compare_rsun.sh: GRASS failed:" >&2; tail -20 "$work/grass.log" >&2; exit 1; }
  grep '^row ' "$work/grass.log" | while read -r _ day how rsun mean p95; do
    printf "| %s | %s | %s | %.1f | %.2f | %.2f | %.2f |\n" "$name" "$day" "$how" "$rsun" \
      "$(echo "$horizons_s + ${ours_s[$day]}" | bc)" "$mean" "$p95"
  done
  printf "| %s | 1-365 | (year, terrabake alone) | | %.2f (year only: %.2f) | | |\n" "$name" \
    "$(echo "$horizons_s + $year_s" | bc)" "$year_s"
  rm -rf "$work"
done
