#!/usr/bin/env bash
# Line horizons against the memory-bandwidth floor of the sweep (#17 item 1):
# this machine's read and write bandwidth on both cores (sysbench, installed
# from Debian's packages if missing), then the line sweep's time per
# post-direction on the UTM SRTM tile, and how far above the floor it is.
# The floor: a sweep must read each post (4 bytes; the DEM is read once
# per direction) and write each angle (4 bytes, f32) once per direction.
#   bash pipelines/bench_line_floor.sh     # DEM=, BIN=
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${BIN:-target/release/terrabake}
BENCH=${BENCH:-target/release/terrabake-bench}
DEM=${DEM:-../shared/data/srtm3_n07w006_utm90_f32.tif}
WORK=$(mktemp -d /tmp/terrabake-floor.XXXXXX)
trap 'rm -rf "$WORK"' EXIT
source pipelines/apt.sh
command -v sysbench >/dev/null || apt_install sysbench || { echo "bench_line_floor.sh: sysbench is needed" >&2; exit 1; }
bandwidth() { # read|write -> MiB/s on two threads
  sysbench memory --threads=2 --memory-block-size=64M --memory-total-size=1T \
    --memory-oper="$1" --time=5 run | sed -n 's/.*(\([0-9.]*\) MiB\/sec).*/\1/p'
}
read_mib=$(bandwidth read)
write_mib=$(bandwidth write)
"$BIN" ingest "$DEM" -o "$WORK/dem.tbake" -q
"$BENCH" horizons "$WORK/dem.tbake" --speed line:16,line:64 --methods line --counts 8 \
  --reference 16 --crop 32 --json > "$WORK/speed.json"
python3 - "$read_mib" "$write_mib" "$WORK/speed.json" <<'PY'
import json, sys
read, write = (float(v) * 2**20 for v in sys.argv[1:3])
floor_ns = (4 / read + 4 / write) * 1e9
print(f"bandwidth on 2 threads: read {read / 2**30:.1f} GiB/s, write {write / 2**30:.1f} GiB/s; "
      f"floor {floor_ns:.2f} ns per post-direction (4 bytes read, 4 written)")
print("| directions | time (s) | ns per post-direction (2 cores) | above the floor |")
print("| --- | --- | --- | --- |")
for row in json.load(open(sys.argv[3]))["speed"]:
    ns = row["seconds"] / (row["posts"] * row["bands"]) * 1e9
    print(f"| {row['bands']} | {row['seconds']:.3f} | {ns:.1f} | {ns / floor_ns:.0f}x |")
PY
