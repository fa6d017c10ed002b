#!/usr/bin/env bash
# The solar panel of the speed-against-accuracy charts: day 172's global
# irradiation at 15-minute steps, terrabake at several line-direction
# counts (a curve) beside GRASS r.sun with its own shadowing and r.sun fed
# terrabake's horizons (points), each against its own model's exact-shadow
# reference, in one run on the same grid:
#
#   - terrabake's reference is terrabake at REF directions (256 by default:
#     at 128 the shadows already part from rays at every step by 0.02 %,
#     docs/SOLAR.md), so its curve is the error the direction count causes;
#   - r.sun's reference is r.sun fed those REF-direction horizons, so its
#     points are the error of its own ray marching (or of fewer exported
#     directions) in its own model, apart from where the two models differ
#     (their difference at REF is printed beside).
#
# Seconds: terrabake's ingest + horizons + sky + the day's stage (its layers
# in the asset; the GeoTIFF export after it is not timed, as r.sun's map is
# not exported); r.sun's own run on every core (the DEM's import, slope
# and aspect not counted); r.sun with our horizons adds their bake, export
# and import. Errors: the mean of |x - ref| / ref, per
# cent, over the posts r.sun computes (it leaves the edges null).
#
#   bash pipelines/solar/chart_rsun.sh [OUT] [DEM ...]
# (default: ../shared/data's UTM copy of the bundled tile and Jacksboro)
# writes OUT/points.tsv and prints a markdown table; then
#   target/release/terrabake-bench solar OUT/points.tsv --chart docs/charts/solar
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT=$(realpath -m "${1:-target/solar-chart}"); shift || true
DEMS=("$@")
if [ ${#DEMS[@]} -eq 0 ]; then
  for extra in srtm3_n07w006_utm90_f32 jacksboro_utm80_f32; do
    [ -f "../shared/data/$extra.tif" ] && DEMS+=("../shared/data/$extra.tif")
  done
fi
COUNTS=${COUNTS:-8 16 32 64}
EXPORTED=${EXPORTED:-16 32}
REF=${REF:-256}
DAY=${DAY:-172}
mkdir -p "$OUT"
source pipelines/solar/common.sh

printf "dem\tseries\tkind\tdirections\tseconds\tmean_pct\tp95_pct\n" >"$OUT/points.tsv"
for dem in "${DEMS[@]}"; do
  dem=$(realpath "$dem")
  name=$(basename "$dem" .tif)
  work=$(mktemp -d /tmp/terrabake-solar-chart.XXXXXX)
  declare -A ours_s=() horizons_s=() export_s=()
  for k in $(echo $COUNTS $EXPORTED $REF | tr " " "\n" | sort -nu); do
    t0=$(now)
    rm -rf "$work/a.tbake"
    "$BIN" --quiet ingest "$dem" -o "$work/a.tbake"
    "$BIN" --quiet horizons "$work/a.tbake" --sectors "$k" --method line
    t1=$(now)
    "$BIN" --quiet solar "$work/a.tbake" --day "$DAY"
    horizons_s[$k]=$(secs "$t0" "$t1")
    ours_s[$k]=$(secs "$t0" "$(now)")
    # Not timed, as r.sun's own map is not exported.
    "$BIN" --quiet export "$work/a.tbake" --layer solar_global -o "$work/ours_$k.tif"
    if [[ " $EXPORTED $REF " == *" $k "* ]]; then
      t0=$(now)
      "$BIN" --quiet export "$work/a.tbake" --layer horizon --for grass -o "$work/hz$k"
      export_s[$k]=$(secs "$t0" "$(now)")
    fi
  done
  grass_script "$dem" >"$work/grass.sh"
  cat >>"$work/grass.sh" <<SH
for k in $COUNTS $REF; do r.in.gdal --quiet input=$work/ours_\$k.tif band=1 output=ours_\$k; done
t0=\$(date +%s.%N)
r.sun elevation=dem aspect=aspect slope=slope day=$DAY step=0.25 linke_value=3.0 albedo_value=0.2 nprocs=$CORES glob_rad=rsun_own
echo "time own \$(echo "\$(date +%s.%N) - \$t0" | bc)"
for k in $EXPORTED $REF; do
  t0=\$(date +%s.%N)
  for f in $work/hz\$k/horizon_*.tif; do
    stem=\$(basename \$f .tif)
    r.in.gdal --quiet input=\$f output=h\$k\${stem#horizon}
  done
  t1=\$(date +%s.%N)
  step=\$(echo "scale=6; 360 / \$k" | bc | sed 's/0*\$//; s/\\.\$//')
  r.sun elevation=dem aspect=aspect slope=slope day=$DAY step=0.25 linke_value=3.0 albedo_value=0.2 nprocs=$CORES glob_rad=rsun_\$k horizon_basename=h\$k horizon_step=\$step
  echo "time \$k \$(echo "\$(date +%s.%N) - \$t1" | bc) \$(echo "\$t1 - \$t0" | bc)"
done
# Every comparison over the posts r.sun computes.
r.mapcalc --quiet "mask = if(isnull(rsun_own) || isnull(rsun_$REF), null(), 1)"
diff() {
  r.mapcalc --quiet "d = if(isnull(mask), null(), 100 * abs(\$1 - \$2) / \$2)"
  echo "diff \$3 \$(r.univar -g map=d | sed -n 's/^mean=//p') \$(r.univar -ge percentile=95 map=d | sed -n 's/^percentile_95=//p')"
}
for k in $COUNTS; do diff ours_\$k ours_$REF ours_\$k; done
diff rsun_own rsun_$REF rsun_own
for k in $EXPORTED; do diff rsun_\$k rsun_$REF rsun_\$k; done
diff ours_$REF rsun_$REF models
SH
  run_grass "$dem" "$work"
  own_s=$(sed -n 's/^time own //p' "$work/grass.log")
  echo "## $name, day $DAY (reference: $REF directions)"
  echo
  echo "| method | directions | seconds | mean abs error % | p95 abs error % |"
  echo "|---|---:|---:|---:|---:|"
  while read -r _ what mean p95; do
    case $what in
      ours_*) k=${what#ours_}; s=${ours_s[$k]}
        printf "%s\tterrabake (line horizons)\tline\t%s\t%s\t%s\t%s\n" "$name" "$k" "$s" "$mean" "$p95" >>"$OUT/points.tsv"
        printf "| terrabake | %s | %.2f | %.4f | %.4f |\n" "$k" "$s" "$mean" "$p95" ;;
      rsun_own) s=$own_s
        printf "%s\tr.sun, own shadowing\tmark\t\t%s\t%s\t%s\n" "$name" "$s" "$mean" "$p95" >>"$OUT/points.tsv"
        printf "| r.sun, own shadowing | | %.2f | %.4f | %.4f |\n" "$s" "$mean" "$p95" ;;
      rsun_*) k=${what#rsun_}
        read -r run import < <(sed -n "s/^time $k //p" "$work/grass.log")
        s=$(echo "${horizons_s[$k]} + ${export_s[$k]} + $import + $run" | bc)
        printf "%s\tr.sun, our horizons\tmark\t%s\t%s\t%s\t%s\n" "$name" "$k" "$s" "$mean" "$p95" >>"$OUT/points.tsv"
        printf "| r.sun, our horizons | %s | %.2f | %.4f | %.4f |\n" "$k" "$s" "$mean" "$p95" ;;
      models)
        printf "| (terrabake against r.sun, both at %s) | | | %.4f | %.4f |\n" "$REF" "$mean" "$p95" ;;
    esac
  done < <(grep '^diff ' "$work/grass.log")
  echo
  rm -rf "$work"
done
