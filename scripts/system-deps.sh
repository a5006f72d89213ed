#!/usr/bin/env bash
# Installs the system libraries that open3d, OpenCV and depthai load, when they are missing.
# Debian/Ubuntu as root: installs them with apt-get. Otherwise: says exactly what to install.
set -euo pipefail

libs=(libGL.so.1 libEGL.so.1 libX11.so.6 libusb-1.0.so.0 libudev.so.1 libgomp.so.1)
pkgs=(libgl1 libegl1 libx11-6 libusb-1.0-0 libudev1 libgomp1)

missing=()
for i in "${!libs[@]}"; do
  if ! ldconfig -p 2>/dev/null | grep -q "${libs[$i]}"; then
    missing+=("${pkgs[$i]}")
  fi
done
[ ${#missing[@]} -eq 0 ] && exit 0

if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
  echo "installing system libraries: ${missing[*]}"
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq
  apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
else
  echo "error: missing system libraries for open3d/depthai: ${missing[*]}" >&2
  echo "install them with: sudo apt-get install ${missing[*]}" >&2
  exit 1
fi
