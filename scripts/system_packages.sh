#!/usr/bin/env bash
# The system packages the tests need, installed with apt-get when missing, so that
# `bash scripts/test.sh` passes on a fresh machine of this kind (Debian or Ubuntu) without .ci/run:
# Mesa's software Vulkan (lavapipe) for the off-screen renderer's screenshot tests, Xvfb and xwd
# (x11-apps) for the live viewer's test (tests/view_xvfb.rs) plus the X11 libraries winit loads
# at run time, and python3-venv for scripts/test.sh's .venv.
# As root with apt-get it installs what is missing; otherwise it exits 1 naming the packages.
# SMLWORLD_NO_APT=1 only warns (the tests that need a package then fail); SMLWORLD_APT_GET names
# the apt-get to call (tests/system_packages.rs points it at a fake).
set -euo pipefail
cd "$(dirname "$0")/.."

missing=()
have_lib() { ldconfig -p 2>/dev/null | grep -q "$1"; }
have_lib libvulkan.so.1 || missing+=(libvulkan1)
ls /usr/share/vulkan/icd.d/lvp_icd*.json >/dev/null 2>&1 || missing+=(mesa-vulkan-drivers)
command -v Xvfb >/dev/null || missing+=(xvfb)
command -v xwd >/dev/null || missing+=(x11-apps)
have_lib libX11-xcb.so.1 || missing+=(libx11-xcb1)
have_lib libxkbcommon-x11.so.0 || missing+=(libxkbcommon-x11-0)
have_lib libXcursor.so.1 || missing+=(libxcursor1)
have_lib libXrandr.so.2 || missing+=(libxrandr2)
have_lib libXi.so.6 || missing+=(libxi6)
[ -x .venv/bin/python ] || python3 -c 'import ensurepip, venv' 2>/dev/null || missing+=(python3-venv)
[ "${#missing[@]}" -eq 0 ] && exit 0

if [ "${SMLWORLD_NO_APT:-0}" = 1 ]; then
  echo "scripts/system_packages.sh: missing (not installed, SMLWORLD_NO_APT=1): ${missing[*]}" >&2
  exit 0
fi
apt_get=${SMLWORLD_APT_GET:-apt-get}
if [ "$(id -u)" -eq 0 ] && command -v "$apt_get" >/dev/null; then
  echo "scripts/system_packages.sh: installing the system packages the tests need: ${missing[*]}" >&2
  export DEBIAN_FRONTEND=noninteractive
  "$apt_get" update -qq
  "$apt_get" install -y -qq "${missing[@]}" >/dev/null
else
  echo "scripts/system_packages.sh: the tests need these system packages, missing here: ${missing[*]}" >&2
  echo "  install them as root (apt-get install ${missing[*]}) and run scripts/test.sh again," >&2
  echo "  or set SMLWORLD_NO_APT=1 to run the tests without them (those that need them fail)" >&2
  exit 1
fi
