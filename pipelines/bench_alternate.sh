#!/usr/bin/env bash
# How a change of our own is timed (docs/BENCHMARKS.md): the same command
# with each binary in turn, ROUNDS rounds, so that the machine's slower and
# faster spells fall on every binary alike; then each binary's median, min
# and max wall time.
#
#   bash pipelines/bench_alternate.sh ROUNDS OLD NEW [MORE...] -- ARGS...
#   bash pipelines/bench_alternate.sh 12 /tmp/tb-old target/release/terrabake -- \
#     horizons /tmp/terrabake-targets/utm.tbake --sectors 16 --no-sky --force -q
set -euo pipefail
cd "$(dirname "$0")/.."
source pipelines/bench_common.sh
usage() { echo "usage: $0 ROUNDS BINARY... -- ARGS..." >&2; exit 2; }
[ $# -ge 3 ] || usage
rounds=$1
shift
bins=()
while [ $# -gt 0 ] && [ "$1" != "--" ]; do
  bins+=("$1")
  shift
done
[ $# -gt 0 ] && [ ${#bins[@]} -gt 0 ] || usage
shift
times=$(mktemp)
trap 'rm -f "$times"' EXIT
for _ in $(seq "$rounds"); do
  for i in "${!bins[@]}"; do
    echo "$i $(wall "${bins[$i]}" "$@")" >> "$times"
  done
done
echo "| binary | median (ms) | min-max (ms) | runs |"
echo "| --- | --- | --- | --- |"
for i in "${!bins[@]}"; do
  read -r lo mid hi < <(awk -v i="$i" '$1 == i { print $2 * 1000 }' "$times" | spread %.1f)
  echo "| ${bins[$i]} | $mid | $lo-$hi | $rounds |"
done
