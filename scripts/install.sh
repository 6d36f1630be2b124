#!/usr/bin/env bash
# Installs InceptionGS and what it needs on a fresh Debian machine.
#   bash scripts/install.sh          # the package
#   bash scripts/install.sh --dev    # + test tools and Xvfb (for the windowed app's tests)
set -euo pipefail
cd "$(dirname "$0")/.."

dev=0
[ "${1:-}" = "--dev" ] && dev=1

# System libraries: Mesa's EGL/GL (headless rendering) and, for tests, Xvfb for the GLFW window.
need_apt=()
ldconfig -p | grep -q 'libEGL.so.1' || need_apt+=(libegl1 libegl-mesa0)
ldconfig -p | grep -q 'libGL.so.1' || need_apt+=(libgl1 libglx-mesa0)
[ -e /usr/lib/x86_64-linux-gnu/dri/swrast_dri.so ] || [ -e /usr/lib/aarch64-linux-gnu/dri/swrast_dri.so ] || need_apt+=(libgl1-mesa-dri)
if [ "$dev" = 1 ]; then
  command -v Xvfb >/dev/null || need_apt+=(xvfb)
  command -v xdotool >/dev/null || need_apt+=(xdotool)
fi
if [ "${#need_apt[@]}" -gt 0 ]; then
  sudo=""
  [ "$(id -u)" = 0 ] || sudo="sudo"
  echo "installing system packages: ${need_apt[*]}"
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${need_apt[@]}" >/dev/null
fi

# torch first and pinned: 2.13.0 is the CPU build these machines carry; anything looser
# would pull a multi-GB CUDA build.
python3 -m pip install -q --disable-pip-version-check "torch==2.13.0"
if [ "$dev" = 1 ]; then
  python3 -m pip install -q --disable-pip-version-check -e ".[dev]"
else
  python3 -m pip install -q --disable-pip-version-check -e .
fi

# The CPU kernels compiled once now (numba caches them beside the code), so the first run does
# not stop for the compiler.
python3 scripts/compile_kernels.py
