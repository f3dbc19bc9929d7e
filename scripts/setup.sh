#!/usr/bin/env bash
# Creates .venv (Python >= 3.10) and installs scan2terrain into it, editable.
#   bash scripts/setup.sh          runtime dependencies only
#   bash scripts/setup.sh test     plus the test tools, and the Debian packages that hold Gazebo's
#                                  own code (SDFormat, gz-common, gz-physics with its dartsim
#                                  plugin and heightmaps) used by the integration tests
set -euo pipefail
cd "$(dirname "$0")/.."
extra="${1:-}"

as_root() { if [ "$(id -u)" = 0 ]; then "$@"; elif command -v sudo >/dev/null; then sudo "$@"; else
  echo "setup: need root to run: $*" >&2; return 1; fi; }
apt_install() {
  export DEBIAN_FRONTEND=noninteractive
  # Wait (up to 10 min) for another apt/dpkg to finish instead of failing on its lock.
  local lock=(-o DPkg::Lock::Timeout=600)
  if ! as_root apt-get "${lock[@]}" update -qq || \
     ! as_root apt-get "${lock[@]}" install -y -qq "$@" >/dev/null; then
    echo "setup: apt-get could not install: $*" >&2
    return 1
  fi
}

PY="${PYTHON:-python3}"
if ! "$PY" -c 'import sys; assert sys.version_info >= (3, 10)' 2>/dev/null; then
  echo "setup: need Python >= 3.10 as '$PY' (set PYTHON=...)" >&2; exit 2
fi
if [ ! -x .venv/bin/python ]; then
  if ! "$PY" -m venv .venv 2>/dev/null; then
    rm -rf .venv
    # Debian's Python keeps venv in a separate package.
    ver=$("$PY" -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")')
    apt_install "python${ver}-venv"
    "$PY" -m venv .venv
  fi
fi
# Python packages: skipped when this venv already holds them for this pyproject.toml and extra
# (the demo's second run costs nothing); any change to pyproject.toml reinstalls.
stamp=".venv/.scan2terrain-installed-${extra:-runtime}-$(sha256sum pyproject.toml | cut -c1-16)"
pip_install() {
  if [ -f "$stamp" ] && .venv/bin/python -c 'import scan2terrain' 2>/dev/null; then return 0; fi
  .venv/bin/python -m pip install -q --upgrade pip >/dev/null
  .venv/bin/python -m pip install -q -e "$1"
  touch "$stamp"
}
# Open3D's wheel links libusb even when headless.
# grep reads all of ldconfig's output (no -q): an early exit would fail the pipe under pipefail.
if ! ldconfig -p 2>/dev/null | grep 'libusb-1.0.so.0' >/dev/null; then apt_install libusb-1.0-0; fi
if [ "$extra" = "test" ]; then
  need=()
  for pc in sdformat12 ignition-common4-graphics ignition-physics5-heightmap ignition-physics5-mesh; do
    pkg-config --exists "$pc" 2>/dev/null || need+=(x)
  done
  command -v edit_octree >/dev/null || need+=(x)
  command -v chromium >/dev/null || need+=(x)  # test_view loads the viewer's page in it
  if [ "${#need[@]}" -gt 0 ] || ! command -v g++ >/dev/null; then
    apt_install libsdformat-dev libignition-common-graphics-dev libignition-physics-dev \
      libignition-physics-heightmap-dev pkg-config g++ octomap-tools chromium
  fi
  pip_install ".[test]"
else
  pip_install .
fi
# Compile the numba kernels into numba's cache now, not during the user's first command.
.venv/bin/python -m scan2terrain.warmup
