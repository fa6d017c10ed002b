#!/usr/bin/env bash
# The reference WGSL shader (gpu/src/cone_step.wgsl) through wgpu against the
# CPU parametric tracer (gpu/tests/shader.rs). Where the machine has no
# Vulkan driver, installs Mesa's lavapipe (software Vulkan: Debian's
# mesa-vulkan-drivers and libvulkan1) when root; the test then must find an
# adapter. Without root and without a driver it is skipped with a message.
#
#   bash pipelines/gpu/test.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
source pipelines/apt.sh
require=1
if ! ls /usr/share/vulkan/icd.d/*.json >/dev/null 2>&1 || ! ldconfig -p | grep -q libvulkan.so.1; then
  echo "gpu/test.sh: installing Mesa's lavapipe (software Vulkan, once)" >&2
  apt_install mesa-vulkan-drivers libvulkan1 ||
    { echo "gpu/test.sh: no Vulkan driver and none can be installed (not root?): the shader test will be skipped" >&2; require=0; }
fi
# lavapipe's window-system code asks for a runtime directory it never uses.
XDG_RUNTIME_DIR=$(mktemp -d)
export XDG_RUNTIME_DIR
trap 'rm -rf "$XDG_RUNTIME_DIR"' EXIT
if [ "$require" = 1 ]; then
  export TERRABAKE_REQUIRE_GPU=1
fi
log=$(mktemp)
if ! cargo test --release --locked -p terrabake-gpu -- --nocapture >"$log" 2>&1; then
  tail -40 "$log" >&2
  echo "gpu/test.sh: the shader test failed" >&2
  exit 1
fi
grep -E "^adapter|rays:|skipped" "$log" | sed 's/^/gpu\/test.sh: /'
rm -f "$log"
