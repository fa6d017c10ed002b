#!/usr/bin/env bash
# Opens the demo page in a real headless browser (Debian's chromium) and
# checks it as a person would see it: the page loads, every picture in it
# decodes and shows (the page's own script marks each <img> loaded or
# broken and counts them), a chart opens full size as a click opens it,
# and the console reports no error. Also writes screenshots beside the
# page (the page, and one chart opened). Installs chromium when it is missing (root).
#
#   bash pipelines/page/check.sh out/index.html
set -euo pipefail
page=${1:?usage: check.sh PAGE.html}
[ -f "$page" ] || { echo "check.sh: $page: no such page (run make demo)" >&2; exit 1; }

browser=$(command -v chromium || command -v chromium-browser || true)
if [ -z "$browser" ]; then
  echo "check.sh: installing Debian's chromium (once)" >&2
  source "$(dirname "$0")/../apt.sh"
  apt_install chromium
  browser=$(command -v chromium)
fi

url="file://$(cd "$(dirname "$page")" && pwd)/$(basename "$page")"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
flags=(--headless --no-sandbox --disable-gpu --hide-scrollbars --user-data-dir="$work/profile"
       --virtual-time-budget=20000 --enable-logging=stderr --v=0)
timeout 120 "$browser" "${flags[@]}" --dump-dom "$url" >"$work/dom.html" 2>"$work/log" || {
  echo "check.sh: chromium failed on $page:" >&2; grep -v dbus "$work/log" | tail -20 >&2; exit 1; }
timeout 120 "$browser" "${flags[@]}" --window-size=1280,2400 \
  --screenshot="${page%.html}.png" "$url" >/dev/null 2>&1 || true

fail=0
count() { { grep -o "$1" "$2" || true; } | wc -l; }
want=$(count '<img ' "$page")
status=$({ grep -o 'id="status">[^<]*' "$work/dom.html" || true; } | sed 's/.*>//')
loaded=$(count 'data-state="loaded"' "$work/dom.html")
broken=$(count 'data-state="broken"' "$work/dom.html")
echo "page: $page; $status; $loaded loaded, $broken broken, $want in the page"
if [ "$want" -eq 0 ] || [ "$loaded" -ne "$want" ] || [ "$broken" -ne 0 ] ||
   [ "$status" != "$want of $want pictures loaded" ]; then
  echo "check.sh: not every picture shows" >&2; fail=1
fi
# A click opens a picture full size: the page's own `#view-N` opens the
# last (a chart) as the click would, and the viewer must show it.
timeout 120 "$browser" "${flags[@]}" --dump-dom "$url#view-$want" >"$work/viewer.html" 2>>"$work/log" || true
timeout 120 "$browser" "${flags[@]}" --window-size=1280,800 \
  --screenshot="${page%.html}_viewer.png" "$url#view-$want" >/dev/null 2>&1 || true
if ! grep -q '<div id="viewer" data-shows="[^"]' "$work/viewer.html"; then
  echo "check.sh: #view-$want opened no viewer (a click on a chart would not enlarge it)" >&2; fail=1
fi
# Console messages of the page (errors, uncaught exceptions, failed loads).
if grep -E 'CONSOLE|Uncaught|net::ERR' "$work/log" >&2; then
  echo "check.sh: the page wrote to the console" >&2; fail=1
fi
[ "$fail" -eq 0 ] && echo "page ok: every picture shows, no console errors (screenshot ${page%.html}.png)"
exit "$fail"
