#!/usr/bin/env bash
# The Python package as a user installs it: the abi3 wheel `make wheel`
# builds (pipelines/python/wheel.sh), installed into a fresh virtual
# environment with no cargo or rustc on PATH, then its tests (python/tests,
# pytest, under the same PATH). The environment sees the system's
# packages, so that Debian's GDAL bindings (python3-gdal), when present,
# check the COG exports with GDAL's own validator; as root, the script
# installs python3-venv and python3-gdal when they are missing. Besides the
# package's own tests, python/tests/test_real_dems.py runs every command on
# GDAL-made variants of the bundled SRTM tile (latitudes, projections,
# south-up, sample types, nodata conventions). The Zarr export's round
# trip (python/tests/test_zarr_export.py) runs last, in a second
# environment with zarr-python 3, which also reads the NetCDF export
# (python/tests/test_netcdf_export.py) through PyPI's netCDF4 and h5netcdf,
# as the first reads it through Debian's netCDF4 and GDAL.
#
#   bash pipelines/python/test.sh            # what `make test` runs
set -euo pipefail
cd "$(dirname "$0")/../.."
py=/usr/bin/python3
[ -x "$py" ] || py=$(command -v python3)
source pipelines/apt.sh
if ! "$py" -c "import ensurepip, venv" 2>/dev/null; then
  echo "python/test.sh: installing Debian's python3-venv (once)" >&2
  apt_install python3-venv
fi
if ! "$py" -c "import osgeo.gdal" 2>/dev/null; then
  echo "python/test.sh: installing Debian's python3-gdal (once), for GDAL's COG validator" >&2
  apt_install python3-gdal gdal-bin || echo "python/test.sh: no GDAL bindings: the GDAL checks will be skipped" >&2
fi
if ! "$py" -c "import netCDF4" 2>/dev/null; then
  echo "python/test.sh: installing Debian's python3-netcdf4 (once), to read the NetCDF export back" >&2
  apt_install python3-netcdf4 || echo "python/test.sh: no netCDF4: the NetCDF export's Debian round trip will be skipped" >&2
fi
if ! "$py" -c "import xarray" 2>/dev/null; then
  echo "python/test.sh: installing Debian's python3-xarray (once), for to_xarray" >&2
  apt_install python3-xarray || echo "python/test.sh: no xarray: to_xarray's test will be skipped" >&2
fi
venv=target/python-venv
rm -rf "$venv"
"$py" -m venv --system-site-packages "$venv"
"$venv/bin/pip" install -q --disable-pip-version-check pytest
"$venv/bin/python" -c "import numpy" 2>/dev/null || "$venv/bin/pip" install -q --disable-pip-version-check numpy
# rioxarray (with rasterio and pyproj) for to_xarray's round trip, at the
# versions that work with the numpy and xarray already here: pinned to them,
# so that pip never swaps Debian's compiled numpy for another.
if "$venv/bin/python" -c "import xarray" 2>/dev/null; then
  "$venv/bin/python" -c "import numpy, xarray; print(f'numpy=={numpy.__version__}'); print(f'xarray=={xarray.__version__}')" >"$venv/pinned.txt"
  "$venv/bin/pip" install -q --disable-pip-version-check -c "$venv/pinned.txt" rioxarray ||
    echo "python/test.sh: no rioxarray: the xarray round trip will be skipped" >&2
fi
# dask for the backend's chunks, distributed for bakes on a cluster and
# pandas for pvlib's horizon series, pinned as rioxarray is.
if [ -f "$venv/pinned.txt" ]; then
  "$venv/bin/pip" install -q --disable-pip-version-check -c "$venv/pinned.txt" dask distributed pandas ||
    echo "python/test.sh: no dask or pandas: their tests will be skipped" >&2
fi
bash pipelines/python/wheel.sh
# Installed and tested exactly as a user without Rust would: no cargo, no
# rustc on PATH.
no_rust=$(echo "$PATH" | tr ':' '\n' | while read -r d; do
  [ -n "$d" ] && [ ! -x "$d/cargo" ] && [ ! -x "$d/rustc" ] && echo "$d"; done | paste -sd:)
if PATH="$no_rust" command -v cargo >/dev/null; then
  echo "python/test.sh: cargo is still on the PATH meant to lack it" >&2; exit 1
fi
start=$(date +%s.%N)
env -u CARGO_HOME -u RUSTUP_HOME PATH="$no_rust" "$venv/bin/pip" install -q --disable-pip-version-check target/wheels/terrabake-*.whl
echo "python/test.sh: pip install of the wheel, without cargo, took $(awk -v a="$start" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }') s"
env -u CARGO_HOME -u RUSTUP_HOME PATH="$no_rust" TERRABAKE_BIN="$(pwd)/target/release/terrabake" \
  "$venv/bin/python" -m pytest -q python/tests "$@"
# The Zarr export's round trip needs zarr-python 3, which needs a newer
# numpy than Debian's: an environment of its own, from PyPI alone, with the
# same wheel.
zvenv=target/zarr-venv
rm -rf "$zvenv"
"$py" -m venv "$zvenv"
if "$zvenv/bin/pip" install -q --disable-pip-version-check "zarr>=3" xarray rioxarray dask netCDF4 h5netcdf h5py pytest; then
  env -u CARGO_HOME -u RUSTUP_HOME PATH="$no_rust" "$zvenv/bin/pip" install -q --disable-pip-version-check target/wheels/terrabake-*.whl
  env -u CARGO_HOME -u RUSTUP_HOME PATH="$no_rust" TERRABAKE_BIN="$(pwd)/target/release/terrabake" \
    "$zvenv/bin/python" -m pytest -q python/tests/test_zarr_export.py python/tests/test_netcdf_export.py python/tests/test_xarray_backend.py
else
  echo "python/test.sh: no zarr-python 3 (or netCDF4, h5netcdf) from PyPI: the Zarr and NetCDF round trips were not run" >&2
  exit 1
fi
