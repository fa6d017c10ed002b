# Sourced by the test scripts that need a Debian package the project's own
# build does not (chromium, valgrind, g++, Python's venv and GDAL bindings).
#
# apt_install PKG...: installs the packages when running as root on Debian
# (updating the index only when the first try fails); returns non-zero,
# installing nothing, where that is not possible, so the caller can skip
# with a message.
apt_install() {
  [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null || return 1
  export DEBIAN_FRONTEND=noninteractive
  apt-get install -y -qq "$@" >/dev/null 2>&1 ||
    { apt-get update -qq >/dev/null && apt-get install -y -qq "$@" >/dev/null; }
}
