#!/usr/bin/env bash
# `make bench-peers`: the horizon and sky-view tools our users come from,
# installed outside the project's own dependencies and run beside
# terrabake on the same DEM, directions and search radius (the whole DEM).
#
#   bash pipelines/peers/bench_peers.sh     # DEM=, DIRECTIONS=16, CROP=256, LIMIT=600, WORK=,
#                                            # PEERS=horayzon,grass (default: every peer;
#                                            # the charts are redrawn only then),
#                                            # TOLERANCE=4.5 (also our stage with its line
#                                            # directions that far from nominal, timed and scored),
#                                            # KNOBS=8,16,32,64 (the direction counts every peer
#                                            # also runs on the crop: its curve on the charts)
#
# Installs (as root; once): Debian's gdal-bin, grass-core and saga; a
# virtual environment target/peers-venv from PyPI with whitebox-workflows,
# topocalc (built from its sdist: its shipped C is too old for this Python,
# so Cython regenerates it), SurtGIS and RVT (without its GUI and GIS
# extras). A peer that cannot be installed is named in the tables with the
# reason. Then bench_peers.py runs every peer and our stage, and
# `terrabake-bench horizons --peers` scores them all against 1024 exact
# sight lines, prints the tables for docs/BENCHMARKS.md and redraws
# docs/charts/horizons_{horizon,svf}.svg with the peers on them.
set -euo pipefail
cd "$(dirname "$0")/../.."
BIN=${BIN:-target/release/terrabake}
BENCH=${BENCH:-target/release/terrabake-bench}
DEM=${DEM:-../shared/data/srtm3_n07w006_utm90_f32.tif}
DIRECTIONS=${DIRECTIONS:-16}
CROP=${CROP:-256}
LIMIT=${LIMIT:-600}
WORK=${WORK:-/tmp/terrabake-peers}
PEERS=${PEERS:-}
TOLERANCE=${TOLERANCE:-}
VENV=target/peers-venv
source pipelines/apt.sh
say() { echo "bench-peers: $*" >&2; }
missing=()

command -v gdal_translate >/dev/null || apt_install gdal-bin || { say "GDAL is needed to cut the crop"; exit 1; }
command -v grass >/dev/null || apt_install grass-core || missing+=("grass=grass-core could not be installed (not root, or no Debian)")
command -v saga_cmd >/dev/null || apt_install saga || missing+=("saga=saga could not be installed (not root, or no Debian)")

py=/usr/bin/python3
[ -x "$py" ] || py=$(command -v python3)
"$py" -c "import ensurepip, venv" 2>/dev/null || apt_install python3-venv
if [ ! -x "$VENV/bin/python" ]; then
  say "creating $VENV"
  "$py" -m venv "$VENV"
fi
pip() { "$VENV/bin/pip" install -q --disable-pip-version-check "$@"; }
pip numpy scipy "cython<3.1" setuptools_scm wheel
installed() { "$VENV/bin/python" -c "import $1" 2>/dev/null; }
try() { # module reason pip-args...
  local module=$1 reason=$2
  shift 2
  installed "$module" || pip "$@" >"$WORK.pip.log" 2>&1 || true
  installed "$module" || missing+=("$module=$reason: $(tail -1 "$WORK.pip.log" 2>/dev/null)")
}
mkdir -p "$WORK"
try whitebox_workflows "pip install whitebox-workflows failed" whitebox-workflows
try topocalc "pip install topocalc failed" --no-build-isolation topocalc
try surtgis "pip install surtgis failed" surtgis
try rvt "pip install rvt-py failed" --no-deps rvt-py
# HORAYZON is published on conda-forge and GitHub only, neither of which
# this machine reaches. Given a source tree (HORAYZON_SRC: a checkout of its
# last Embree 3 commit, 2bcc0ca^), it is built here against Debian's Embree
# 3 and TBB; its setup.py finds Embree under $CONDA_PREFIX/lib, so a folder
# with one link stands in for a conda environment.
if [ -n "${HORAYZON_SRC:-}" ]; then
  if ! installed horayzon; then
    apt_install libembree-dev libtbb-dev || true
    # Absolute: pip builds in a directory of its own.
    shim=$PWD/$VENV/embree-prefix
    mkdir -p "$shim/lib"
    ln -sf "$(ls /usr/lib/*/libembree3.so | head -1)" "$shim/lib/libembree3.so"
    pip tqdm requests geographiclib xarray
    CONDA_PREFIX=$shim pip --no-build-isolation "$HORAYZON_SRC" >"$WORK.pip.log" 2>&1 || true
  fi
  installed horayzon || missing+=("horayzon=building HORAYZON_SRC failed: $(tail -1 "$WORK.pip.log")")
else
  missing+=("horayzon=not on PyPI or in Debian (conda-forge and GitHub only); HORAYZON_SRC=checkout builds it here")
fi

[ -x "$BIN" ] || cargo build --release --locked -q
args=()
for m in "${missing[@]}"; do args+=(--missing "$m"); done
"$py" pipelines/peers/bench_peers.py --bin "$BIN" --venv "$VENV" --dem "$DEM" --work "$WORK" \
  --directions "$DIRECTIONS" --crop "$CROP" --limit "$LIMIT" --only "$PEERS" "${args[@]}" \
  ${KNOBS:+--knobs "$KNOBS"} \
  ${TOLERANCE:+--tolerance "$TOLERANCE"}
# The charts show every peer: a run of some (PEERS=) prints their tables
# and leaves the charts as the last full run drew them.
chart=()
if [ -z "$PEERS" ]; then
  chart=(--chart docs/charts/horizons)
else
  say "PEERS=$PEERS: docs/charts/horizons_*.svg left as they are (they are drawn from a run of every peer)"
fi
"$BENCH" horizons "$WORK/whole.tbake" --peers "$WORK/peers.json" --crop "$CROP" \
  --speed none "${chart[@]}" ${TOLERANCE:+--direction-tolerance "$TOLERANCE"}
