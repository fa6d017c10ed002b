#!/usr/bin/env bash
# Fits the planner's time models (src/plan/models.rs, TimeModels). First a bake's
# fixed cost, then the line sweeps to the edge (seconds = fixed + posts *
# S^EXPONENT / RATE) to the horizons and sky stages on the bundled tile (the wall time
# of `terrabake horizons`, which runs both), planned the way the planner
# bakes (line directions at the stage's default tolerance, u16), S from 16 to 120, on this
# machine's cores. Prints each run and the least-squares fit of
# log((seconds - fixed) / posts) against log(S), its rate then lowered until no run
# took longer than the model says (the times are no clean power of S, and
# a time budget wants the safe side; a plan that widens the tolerance
# sweeps fewer crossings, so the model stays above it). Eight directions or fewer are axis
# and diagonal lines, nearly free: the model overestimates them.
# Then the calibration workload (`terrabake calibrate`), recorded with the
# fit. With OUT=FILE it also writes the fit as the JSON file that
# TERRABAKE_TIME_MODELS=FILE makes the planner use on this machine.
#   BIN=target/release/terrabake [OUT=models.json] bash pipelines/fit_plan_models.sh
set -euo pipefail
BIN=${BIN:-target/release/terrabake}
OUT=${OUT:-}
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
source "$(dirname "$0")/bench_common.sh"
# The fixed cost of a bake (start, open, write): the horizons and sky
# stages on 64 x 64 posts at 8 directions, the longest of three runs. The
# fits below are of what each run took beyond it.
"$BIN" synth flat --size 64x64 -o "$WORK/tiny.tif" -q
"$BIN" ingest "$WORK/tiny.tif" -o "$WORK/tiny.tbake" -q
fixed=$(for _ in 1 2 3; do
  wall "$BIN" horizons "$WORK/tiny.tbake" --sectors 8 --encoding u16 --force -q
done | sort -g | tail -1)
printf 'fixed: %.3f s a bake\n' "$fixed"
printf '"fixed_seconds": %.4g' "$fixed" > "$WORK/fixed"

"$BIN" ingest data/srtm3_n07w006_geographic_int16.tif -o "$WORK/srtm.tbake" -q
posts=$((1201 * 1201))
for s in 16 24 36 48 72 120; do
  echo "$s $(wall "$BIN" horizons "$WORK/srtm.tbake" --sectors "$s" --encoding u16 --force -q)"
done | tee "$WORK/runs" | awk -v posts="$posts" -v fixed="$fixed" -v fit="$WORK/sweep" '
  { x = log($1); y = log(($2 - fixed) / posts); n++; sx += x; sy += y; sxx += x * x; sxy += x * y;
    xs[n] = x; ys[n] = y; printf "S %4d: %7.2f s\n", $1, $2 }
  END {
    b = (n * sxy - sx * sy) / (n * sxx - sx * sx); a = (sy - b * sx) / n;
    printf "least squares: seconds = fixed + posts * S^%.2f / %.3g\n", b, exp(-a)
    for (i = 1; i <= n; i++) if (ys[i] - (a + b * xs[i]) > lift) lift = ys[i] - (a + b * xs[i])
    printf "fit: seconds = fixed + posts * S^%.2f / %.3g\n", b, exp(-(a + lift))
    printf "\"sweep_exponent\": %.6g, \"sweep_rate\": %.6g", b, exp(-(a + lift)) > fit }'

# Bounded line horizons (a walk of each post's reach per direction, the DEM
# in memory): seconds = posts * S * (PER_LINE + PER_CELL * D / cell), with
# D / cell the reach in posts (cell: the mean of dx and dy). Fitted by least
# squares on S in {16, 48} and D in {1000, 3000} metres, then scaled up
# until no run took longer than the model says.
cell=$("$BIN" info "$WORK/srtm.tbake" --json | tr -d ' \n' | sed -E 's/.*"cell_size":\{"dx":([0-9.]+),"dy":([0-9.]+).*/\1 \2/' | awk '{print ($1 + $2) / 2}')
for d in 1000 3000; do
  for s in 16 48; do
    echo "$s $d $(wall "$BIN" horizons "$WORK/srtm.tbake" --sectors "$s" --encoding u16 \
      --max-distance "$d" --force -q)"
  done
done | awk -v posts="$posts" -v cell="$cell" -v fixed="$fixed" -v fit="$WORK/bounded" '
  { x = $2 / cell; y = ($3 - fixed) / (posts * $1); n++; sx += x; sy += y; sxx += x * x; sxy += x * y;
    xs[n] = x; ys[n] = y; printf "S %4d, D %5d m: %7.2f s\n", $1, $2, $3 }
  END {
    b = (n * sxy - sx * sy) / (n * sxx - sx * sx); a = (sy - b * sx) / n;
    printf "least squares: seconds = fixed + posts * S * (%.3g + %.3g * D / cell)\n", a, b
    k = 1; for (i = 1; i <= n; i++) if (ys[i] / (a + b * xs[i]) > k) k = ys[i] / (a + b * xs[i])
    printf "fit: seconds = fixed + posts * S * (%.3g + %.3g * D / cell)\n", a * k, b * k
    printf "\"bounded_per_line\": %.6g, \"bounded_per_cell\": %.6g", a * k, b * k > fit }'
# The calibration workload on this machine (src/plan/calibration.rs): what
# scales these models when the file is carried to another machine.
calibration=$("$BIN" calibrate --fresh --json | sed -nE 's/^  "seconds": ([0-9.e+-]+),?$/\1/p')
printf 'calibration: %s s\n' "$calibration"
if [ -n "$OUT" ]; then
  printf '{%s, %s, %s, "calibration_seconds": %s}\n' "$(cat "$WORK/fixed")" "$(cat "$WORK/sweep")" \
    "$(cat "$WORK/bounded")" "$calibration" \
    > "$OUT.tmp"
  mv "$OUT.tmp" "$OUT"
  echo "wrote $OUT: TERRABAKE_TIME_MODELS=$OUT makes the planner use it"
fi
