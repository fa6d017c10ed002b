# Sourced by the solar comparisons (compare_rsun.sh, chart_rsun.sh) from the
# repository root: GRASS from Debian's grass-core where it is missing, the
# release binary ($BIN), the machine's cores ($CORES) and a clock.
source pipelines/apt.sh
if ! command -v grass >/dev/null; then
  echo "installing GRASS (Debian's grass-core)..." >&2
  apt_install --no-install-recommends grass-core || {
    echo "cannot install GRASS (not root, or not Debian)" >&2; exit 1; }
fi
cargo build --release --locked -q --bin terrabake
BIN=$(realpath target/release/terrabake)
CORES=$(nproc)
now() { date +%s.%N; }
secs() { echo "$2 - $1" | bc; }

# grass_script DEM: the first lines of every GRASS script here, the DEM
# imported as `dem`, the region set to it, and its slope and aspect.
grass_script() {
  cat <<SH
set -euo pipefail
export GRASS_OVERWRITE=1 GRASS_VERBOSE=0
r.in.gdal --quiet input=$1 output=dem
g.region raster=dem
r.slope.aspect elevation=dem slope=slope aspect=aspect
SH
}

# run_grass DEM WORK: runs WORK/grass.sh in a new location of the DEM's CRS,
# its output in WORK/grass.log; on failure, says so with the log's tail.
run_grass() {
  grass -c "$1" "$2/db/loc" --exec bash "$2/grass.sh" >"$2/grass.log" 2>&1 || {
    echo "$(basename "$0"): GRASS failed:" >&2; tail -20 "$2/grass.log" >&2; exit 1; }
}
