#!/usr/bin/env bash
# What the layers' zstd codec saves and costs (docs/BENCHMARKS.md, "Layer
# codecs"): the demo recipe baked as it is (raw tiles) and with codec =
# "zstd" on the ingest and every stage that takes one, ROUNDS rounds each,
# alternating; then the wall time, peak RSS and bytes of each, and per layer
# its raw and stored bytes.
#
#   bash pipelines/bench_codecs.sh [ROUNDS]
set -euo pipefail
cd "$(dirname "$0")/.."
source pipelines/bench_common.sh
rounds=${1:-2}
BIN=${BIN:-target/release/terrabake}
WORK=${WORK:-/tmp/terrabake-codecs}
mkdir -p "$WORK"
src=data/srtm3_n07w006_geographic_int16.tif
# Every stage but the pyramid (which has no codec) gets codec = "zstd".
sed -e 's/^codec = "raw"/codec = "zstd"/' \
    -e '/^name = "pyramid"/!s/^name = .*/&\ncodec = "zstd"/' pipelines/demo.toml > "$WORK/zstd.toml"
times=$(mktemp)
trap 'rm -f "$times"' EXIT
for _ in $(seq "$rounds"); do
  for codec in raw zstd; do
    recipe=pipelines/demo.toml
    [ "$codec" = zstd ] && recipe="$WORK/zstd.toml"
    rm -rf "$WORK/$codec.tbake"
    /usr/bin/time -f "$codec %e %M" -o "$times" -a \
      "$BIN" bake "$src" -o "$WORK/$codec.tbake" --recipe "$recipe" -q
  done
done
echo "| tiles | bake (s, each round) | peak RSS (MB) | asset (MB) |"
echo "| --- | --- | --- | --- |"
for codec in raw zstd; do
  secs=$(awk -v c="$codec" '$1 == c { printf "%s%.2f", (n++ ? " / " : ""), $2 }' "$times")
  rss=$(awk -v c="$codec" '$1 == c && $3 > m { m = $3 } END { printf "%.1f", m / 1000 }' "$times")
  mb=$(du -sb "$WORK/$codec.tbake" | awk '{ printf "%.1f", $1 / 1e6 }')
  echo "| $codec | $secs | $rss | $mb |"
done
echo
echo "| layer | elem | raw (MB) | zstd (MB) | ratio |"
echo "| --- | --- | --- | --- | --- |"
python3 - "$WORK" "$BIN" <<'PY'
import json, subprocess, sys
work, binary = sys.argv[1:]
def stored(codec):
    manifest = json.loads(subprocess.check_output([binary, "info", f"{work}/{codec}.tbake", "--json"]))
    layers = {}
    for l in manifest["layers"]:
        name = l["name"] if l["level"] == 0 else l["name"] + " (levels 1+)"
        elem, total = layers.get(name, (l["elem"], 0))
        layers[name] = (elem, total + l["stored_bytes"])
    return layers
raw, packed = stored("raw"), stored("zstd")
for name, (elem, r) in raw.items():
    z = packed[name][1]
    print(f"| {name} | {elem} | {r / 1e6:.2f} | {z / 1e6:.2f} | {r / z:.2f}x |")
PY
