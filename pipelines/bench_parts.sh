#!/usr/bin/env bash
# A partitioned bake measured (docs/SCALE.md): an N x N fractal DEM (default
# 16384, a 1 GiB GeoTIFF) baked in PARTS parts (default 16) one after the
# other on this machine, each under /usr/bin/time -v, then assembled; the
# same recipe baked on one machine; the two compared value for value.
# Prints a markdown table: per part its time, peak memory, bytes written
# and the rows of heights it read beyond its own (the halo). As root, each
# run is held in a memory cgroup of MEM_MIB (default 1024, smaller than the
# DEM) and its peak anonymous memory is reported beside its peak RSS (which
# counts the pages of mapped layer files, reclaimable, too).
set -euo pipefail
BIN=${BIN:-target/release/terrabake}
WORK=${WORK:-/tmp/terrabake-parts}
N=${N:-16384}
PARTS=${PARTS:-16}
MEM_MIB=${MEM_MIB:-1024}
mkdir -p "$WORK"
source "$(dirname "$0")/bench_common.sh"
# measure LIMIT_MIB LOG CMD...: runs CMD in a cgroup of LIMIT_MIB if there
# is one (else under /usr/bin/time -v alone); sets ANON to its peak
# anonymous MiB or "-".
measure() {
    local limit=$1 log=$2
    shift 2
    if run_in_cgroup "$limit" "$log" "$@"; then
        ANON=$PEAK_ANON_MIB
    else
        /usr/bin/time -v "$@" 2>"$log"
        ANON=-
    fi
    grep -q "Exit status: 0" "$log" || { cat "$log" >&2; exit 1; }
}
src="$WORK/fractal_$N.tif"
[[ -f $src ]] || "$BIN" synth fractal --size "${N}x$N" -o "$src" -q
recipe="$WORK/scale.toml"
cat >"$recipe" <<'RECIPE'
# Bounded horizons (split by rows) and their sky-view factors, the pyramid
# (built at the join).
[ingest]
tile = 256
[[stage]]
name = "pyramid"
[[stage]]
name = "horizons"
sectors = 8
max_distance = 300.0
[[stage]]
name = "sky"
layers = ["svf"]
RECIPE
out="$WORK/parts.tbake"
one="$WORK/one.tbake"
rm -rf "$out" "$out.parts" "$one"
field() { grep "$1" "$2" | awk -F': ' '{print $2}'; }
seconds() { # h:mm:ss or m:ss.ss
    awk -F: '{ s = 0; for (i = 1; i <= NF; i++) s = s * 60 + $i; printf "%.1f", s }' <<<"$1"
}
echo "| part | seconds | peak anonymous MiB | peak RSS MiB | MiB written | height rows read | of which halo |"
echo "| ---: | ---: | ---: | ---: | ---: | ---: | ---: |"
total=0
for ((i = 0; i < PARTS; i++)); do
    log="$WORK/part-$i.log"
    measure "$MEM_MIB" "$log" "$BIN" bake "$src" -o "$out" --recipe "$recipe" --parts "$PARTS" --part "$i" -q
    s=$(seconds "$(field 'Elapsed (wall clock)' "$log")")
    rss=$(($(field 'Maximum resident set size' "$log") / 1024))
    dir="$out.parts/part-$i-of-$PARTS"
    written=$(($(du -sb "$dir" | cut -f1) >> 20))
    # Rows of heights the part read: the rest are nodata in its asset (the
    # fractal has none of its own).
    nodata=$("$BIN" info "$dir" --json | tr -d '\n ' | grep -o '"nodata":{[^}]*' |
        sed -E 's/.*"count":([0-9]+).*/\1/')
    rows=$((N - nodata / N))
    own=$(((N / 256) * (i + 1) / PARTS * 256 - (N / 256) * i / PARTS * 256))
    echo "| $i | $s | $ANON | $rss | $written | $rows | $((rows - own)) |"
    total=$(awk -v a="$total" -v b="$s" 'BEGIN { printf "%.1f", a + b }')
done
parts_mib=$(($(du -sb "$out.parts" | cut -f1) >> 20))
measure "$MEM_MIB" "$WORK/assemble.log" "$BIN" assemble "$out" --keep-parts
echo
echo "parts: $total s in all, $parts_mib MiB on disk"
pyramid=$(awk '$1 == "pyramid" { print $2 }' "$WORK/assemble.log")
echo "assemble: $(seconds "$(field 'Elapsed (wall clock)' "$WORK/assemble.log")") s (of which the pyramid, built at the join: $pyramid s), peak anonymous $ANON MiB, peak RSS $(($(field 'Maximum resident set size' "$WORK/assemble.log") / 1024)) MiB, asset $(($(du -sb "$out" | cut -f1) >> 20)) MiB"
# One machine holds the whole DEM for bounded line horizons: no tight limit.
measure 65536 "$WORK/one.log" "$BIN" bake "$src" -o "$one" --recipe "$recipe" -q
echo "one machine: $(seconds "$(field 'Elapsed (wall clock)' "$WORK/one.log")") s, peak anonymous $ANON MiB, peak RSS $(($(field 'Maximum resident set size' "$WORK/one.log") / 1024)) MiB"
"$BIN" verify "$out" --same-as "$one" | tail -1
