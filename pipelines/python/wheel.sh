#!/usr/bin/env bash
# `make wheel`: the Python package as one abi3 wheel (PyO3's stable ABI:
# every CPython from 3.9 on) tagged manylinux2014 (glibc 2.17 on), and its
# sdist (which builds from source with cargo on any other platform), both
# in target/wheels/. maturin and zig (the ziglang package) come from PyPI
# into target/wheel-venv, once.
#
#   bash pipelines/python/wheel.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
venv=target/wheel-venv
if ! "$venv/bin/maturin" --version >/dev/null 2>&1 || ! "$venv/bin/python" -m ziglang version >/dev/null 2>&1; then
  python3 -m venv "$venv"
  "$venv/bin/pip" install -q --disable-pip-version-check "maturin>=1.7,<2" "ziglang>=0.13"
fi
rm -rf target/wheels
# Linked by zig against glibc 2.17's symbols, so that the wheel's
# manylinux2014 tag is true (a plain build here needs glibc 2.35: maturin's
# auditwheel check refuses it any manylinux tag). maturin finds zig as
# `python3 -m ziglang`, so the venv goes first on PATH.
PATH="$(pwd)/$venv/bin:$PATH" "$venv/bin/maturin" build --release --locked -q -m python/Cargo.toml \
  --zig --compatibility manylinux2014 --strip --out target/wheels
"$venv/bin/maturin" sdist -m python/Cargo.toml --out target/wheels >/dev/null
ls target/wheels
