#!/usr/bin/env bash
# The C ABI gives the Rust reader's values: builds libterrabake_c and
# examples/c/sample.c against the committed header (`make capi`), bakes
# assets the Rust tests never see (a holed fractal with every layer the ABI
# serves, raw; a sine with zstd tiles and u16 horizons), and diffs what the
# C program reads through the ABI against what the Rust reader gives
# (capi/examples/reference.rs), line for line, floats as bits. Then bad
# input: a damaged manifest and a damaged tile must give a status and a
# message, never a crash. With VALGRIND=1 (make test-full) every C run is
# under valgrind: no leak, no invalid read. Where cbindgen is installed the
# committed header is checked against a fresh one.
#
#   bash pipelines/capi/test.sh [target/release/terrabake]
set -euo pipefail
bin=$(realpath "${1:-target/release/terrabake}")
cd "$(dirname "$0")/../.."
source pipelines/apt.sh
if [ "${VALGRIND:-0}" = 1 ] && ! command -v valgrind >/dev/null; then
  echo "capi/test.sh: installing Debian's valgrind (once)" >&2
  apt_install valgrind || { echo "capi/test.sh: valgrind is not installed and cannot be (not root?)" >&2; exit 1; }
fi
make --no-print-directory capi >/dev/null
reference=target/release/examples/reference
cargo build --release --locked --quiet -p terrabake-capi --example reference
run_c() {
  if [ "${VALGRIND:-0}" = 1 ]; then
    valgrind --quiet --error-exitcode=99 --leak-check=full --errors-for-leak-kinds=definite,indirect \
      target/capi/sample "$@"
  else
    target/capi/sample "$@"
  fi
}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

cat >"$work/raw.toml" <<'TOML'
description = "every layer the C ABI serves, raw tiles"
[ingest]
tile = 64
[[stage]]
name = "pyramid"
[[stage]]
name = "cones"
[[stage]]
name = "horizons"
sectors = 12
encoding = "f32"
TOML
cat >"$work/zstd.toml" <<'TOML'
description = "zstd heights, quantised horizons"
[ingest]
tile = 32
codec = "zstd"
[[stage]]
name = "horizons"
sectors = 8
method = "sector"
encoding = "u16"
TOML
"$bin" --quiet synth holes --size 203x171 --seed 11 -o "$work/holes.tif"
"$bin" --quiet synth sine --size 150x190 -o "$work/sine.tif"
"$bin" --quiet bake "$work/holes.tif" -o "$work/raw.tbake" --recipe "$work/raw.toml"
"$bin" --quiet bake "$work/sine.tif" -o "$work/zstd.tbake" --recipe "$work/zstd.toml"

for a in raw zstd; do
  run_c "$work/$a.tbake" >"$work/$a.c.txt"
  "$reference" "$work/$a.tbake" >"$work/$a.rust.txt"
  if ! diff -u "$work/$a.rust.txt" "$work/$a.c.txt" >"$work/$a.diff"; then
    head -40 "$work/$a.diff"
    echo "capi/test.sh: $a: the C ABI and the Rust reader differ" >&2
    exit 1
  fi
  echo "capi/test.sh: $a: $(wc -l <"$work/$a.c.txt") facts equal through the C ABI ($(grep -c '^trace' "$work/$a.c.txt") traces, $(grep -c '^lit' "$work/$a.c.txt") sun fractions, $(grep -c 'compressed' "$work/$a.c.txt") compressed tiles refused)"
done

# A damaged manifest: open fails with a status and the file named.
cp -r "$work/raw.tbake" "$work/bad_manifest.tbake"
printf 'XX' | dd of="$work/bad_manifest.tbake/manifest.tba" bs=1 seek=40 conv=notrunc status=none
out=$(run_c "$work/bad_manifest.tbake")
echo "$out" | grep -q "^open failed TB_CORRUPT: .*manifest.tba" || { echo "$out"; echo "capi/test.sh: damaged manifest: $out" >&2; exit 1; }
# A damaged tile: the read that meets it fails with TB_CORRUPT and a
# checksum message (exit 1 from the sample, not a signal).
cp -r "$work/raw.tbake" "$work/bad_tile.tbake"
layer=$(ls "$work/bad_tile.tbake"/height.L0.*.tbl)
printf '\xff\xff\xff\xff' | dd of="$layer" bs=1 seek=5000 conv=notrunc status=none
set +e
err=$(run_c "$work/bad_tile.tbake" 2>&1 >/dev/null)
rc=$?
set -e
if [ "$rc" != 1 ] || ! echo "$err" | grep -q "TB_CORRUPT.*checksum"; then
  echo "capi/test.sh: damaged tile: exit $rc, $err" >&2
  exit 1
fi
echo "capi/test.sh: damaged manifest and tile refused with TB_CORRUPT and the file named"

# The header is C++ too.
command -v g++ >/dev/null || apt_install g++ || { echo "capi/test.sh: g++ is not installed and cannot be (not root?)" >&2; exit 1; }
g++ -std=c++17 -Wall -Wextra -Werror -fsyntax-only -x c++ -I capi/include - <<'CPP'
#include "terrabake.h"
int main() { tb_asset *a = nullptr; return tb_open("x", &a) == TB_OK ? 0 : 1; }
CPP
if command -v cbindgen >/dev/null; then
  cbindgen --quiet --config capi/cbindgen.toml --crate terrabake-capi --output "$work/terrabake.h" capi
  diff -u capi/include/terrabake.h "$work/terrabake.h" || { echo "capi/test.sh: capi/include/terrabake.h is stale: run make capi-header" >&2; exit 1; }
  echo "capi/test.sh: the committed header is cbindgen's"
else
  echo "capi/test.sh: header freshness not checked: cbindgen is not installed (cargo install cbindgen); tests/capi_header.rs checks the names"
fi
