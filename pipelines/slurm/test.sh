#!/usr/bin/env bash
# `make test-slurm`: stands a one-node Slurm cluster up on localhost
# (installing slurm-wlm and munge if missing), bakes with `make bake-slurm`
# in 4 parts the bundled DEM and a DEM generated with a fresh seed (one no
# test has seen), checks each against a bake on one machine with
# `terrabake verify --same-as`, checks that a failing bake exits non-zero
# naming its parts, and stops exactly the daemons it started. Needs root.
set -euo pipefail
cd "$(dirname "$0")/../.."
tb=${TB:-target/release/terrabake}
work=$(mktemp -d /tmp/terrabake-slurm.XXXXXX)
state="$work/cluster"
cleanup() {
    pipelines/slurm/cluster.sh down "$state" || true
    rm -rf "$work"
}
trap cleanup EXIT
eval "$(pipelines/slurm/cluster.sh up "$state")"
export SLURM_CONF

check() { # SRC RECIPE NAME
    local one="$work/$3.one.tbake" parted="$work/$3.slurm.tbake"
    "$tb" bake "$1" -o "$one" --recipe "$2" --quiet
    make --no-print-directory bake-slurm SRC="$1" OUT="$parted" RECIPE="$2" PARTS=4
    "$tb" verify "$parted" --same-as "$one"
}

check data/srtm3_n07w006_geographic_int16.tif pipelines/demo.toml srtm
seed=$(od -An -N4 -tu4 /dev/urandom | tr -d ' ')
"$tb" synth fractal --size 1500x1100 --seed "$seed" -o "$work/unseen.tif" --quiet
cat >"$work/bounded.toml" <<RECIPE
[ingest]
tile = 128
codec = "zstd"
[[stage]]
name = "pyramid"
[[stage]]
name = "horizons"
sectors = 16
max_distance = 2000.0
[[stage]]
name = "sky"
layers = ["svf", "svf_cosine", "openness"]
RECIPE
echo "unseen DEM: fractal, seed $seed" >&2
check "$work/unseen.tif" pipelines/demo.toml unseen-demo
check "$work/unseen.tif" "$work/bounded.toml" unseen-bounded

# A bake whose parts fail (a source that is not a DEM) must fail, naming them.
echo "not a DEM" >"$work/bad.tif"
if out=$(make --no-print-directory bake-slurm SRC="$work/bad.tif" OUT="$work/bad.tbake" \
    RECIPE=pipelines/demo.toml PARTS=2 2>&1); then
    echo "test-slurm: a bake of a bad source succeeded" >&2
    exit 1
fi
grep -q "part(s) 0 1 of 2 failed" <<<"$out" || {
    echo "test-slurm: the failure did not name the parts: $out" >&2
    exit 1
}
[[ ! -e $work/bad.tbake/manifest.tba ]] || { echo "test-slurm: a failed bake committed" >&2; exit 1; }
echo "test-slurm: passed (bundled DEM and an unseen DEM, 4 parts each, identical to one machine)" >&2
