#!/usr/bin/env bash
# Create .venv and install thermal_wild_ns with nerfstudio 1.1.5.
# CPU-only machines: constraints keep the CPU torch and never pull CUDA wheels.
# GPU machines: pass GPU=1 to let pip choose the CUDA torch that nerfstudio/gsplat need.
set -euo pipefail
cd "$(dirname "$0")/../.."
# open3d (imported by ns-export) needs libusb; install it from the local apt cache where we can
if ! ldconfig -p 2>/dev/null | grep -q "libusb-1.0.so.0"; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    apt-get install -y -q --no-download libusb-1.0-0 >/dev/null 2>&1 || apt-get install -y -q libusb-1.0-0 >/dev/null 2>&1 \
      || echo "warning: could not install libusb-1.0-0; ns-export will fail to import open3d" >&2
  else
    echo "warning: libusb-1.0-0 is missing (apt-get install libusb-1.0-0); ns-export will fail to import open3d" >&2
  fi
fi
python3 -m venv .venv
constraints=()
if [ "${GPU:-0}" != "1" ]; then
  constraints=(-c thermal_wild_ns/install/constraints-cpu.txt)
fi
.venv/bin/pip install -q "${constraints[@]}" '.[dev]' 2> >(grep -v "^WARNING: Location" >&2)
rm -rf build
.venv/bin/python -c "import torchvision, thermal_wild_ns.compat; print('environment ready')"
