#!/usr/bin/env bash
# Create .venv and install thermal_wild_ns with nerfstudio 1.1.5.
# CPU-only machines: constraints keep the CPU torch and never pull CUDA wheels.
# GPU machines: pass GPU=1 to let pip choose the CUDA torch that nerfstudio/gsplat need.
set -euo pipefail
cd "$(dirname "$0")/../.."
# System packages: from the local apt cache where we can (no network), else from the network.
try_apt() {
  [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null || return 1
  apt-get install -y -q --no-download --no-install-recommends "$@" >/dev/null 2>&1 \
    || apt-get install -y -q --no-install-recommends "$@" >/dev/null 2>&1
}
# open3d (imported by ns-export) needs libusb
if ! ldconfig -p 2>/dev/null | grep -q "libusb-1.0.so.0"; then
  try_apt libusb-1.0-0 || echo "warning: libusb-1.0-0 is missing (apt-get install libusb-1.0-0); ns-export will fail to import open3d" >&2
fi
# headless Chromium for the viewer screenshot (wild-thermal-viewer-screenshot and its test); the
# apt cache may hold a newer build than the package index names, so its .deb files come first
if ! command -v chromium >/dev/null; then
  try_apt /var/cache/apt/archives/chromium_*.deb /var/cache/apt/archives/chromium-common_*.deb || try_apt chromium \
    || echo "warning: chromium is missing (apt-get install chromium); the viewer screenshot test will be skipped" >&2
fi
python3 -m venv .venv
constraints=()
if [ "${GPU:-0}" != "1" ]; then
  constraints=(-c thermal_wild_ns/install/constraints-cpu.txt)
fi
.venv/bin/pip install -q "${constraints[@]}" '.[dev]' 2> >(grep -v "^WARNING: Location" >&2)
rm -rf build
.venv/bin/python -c "import torchvision, thermal_wild_ns.compat; print('environment ready')"
