#!/usr/bin/env bash
# The Python the solar comparisons use (pvlib for the clear sky, tifffile
# and imagecodecs to read our GeoTIFFs, Pillow to draw the difference
# maps), in a virtual environment under target/ from PyPI, made once.
# Prints the interpreter's path.
set -euo pipefail
cd "$(dirname "$0")/../.."
venv=target/solar-venv
if ! "$venv/bin/python" -c "import pvlib, tifffile, imagecodecs, PIL" 2>/dev/null; then
  python3 -m venv "$venv" >&2
  "$venv/bin/pip" install -q --disable-pip-version-check pvlib tifffile imagecodecs pillow >&2
fi
echo "$(pwd)/$venv/bin/python"
