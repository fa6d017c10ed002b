#!/usr/bin/env bash
# Fits the planner's time model (src/plan.rs: seconds = posts * S^EXPONENT
# / RATE) to the horizons and sky stages on the bundled tile, planned the
# way the planner bakes (line directions within 0.1 degree, u16), S from 8
# to 180, on this machine's cores. Prints each run and the least-squares
# fit of log(seconds / posts) against log(S).
#   BIN=target/release/terrabake bash pipelines/fit_plan_models.sh
set -euo pipefail
BIN=${BIN:-target/release/terrabake}
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
"$BIN" ingest data/srtm3_n07w006_geographic_int16.tif -o "$WORK/srtm.tbake" -q
posts=$((1201 * 1201))
for s in 8 16 24 36 48 72 120 180; do
  "$BIN" horizons "$WORK/srtm.tbake" --sectors "$s" --direction-tolerance 0.1 --encoding u16 \
    --force --json -q > "$WORK/run.json"
  # The horizons stage and the sky stage it runs after: their seconds.
  secs=$(grep -o '"seconds": [0-9.e+-]*' "$WORK/run.json" | awk '{t += $2} END {print t}')
  echo "$s $secs"
done | tee "$WORK/runs" | awk -v posts="$posts" '
  { x = log($1); y = log($2 / posts); n++; sx += x; sy += y; sxx += x * x; sxy += x * y;
    printf "S %4d: %7.2f s\n", $1, $2 }
  END {
    b = (n * sxy - sx * sy) / (n * sxx - sx * sx); a = (sy - b * sx) / n;
    printf "fit: seconds = posts * S^%.2f / %.3g\n", b, exp(-a) }'
