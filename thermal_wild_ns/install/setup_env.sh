#!/usr/bin/env bash
# Create .venv and install thermal_wild_ns with nerfstudio 1.1.5.
# CPU-only machines: constraints keep the CPU torch and never pull CUDA wheels.
# GPU machines: GPU=1 reuses an installed CUDA torch (or installs one); NERFSTUDIO_DEPS=light installs
# only the part of nerfstudio's closure the commands import (requirements-light.txt).
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
if [ "${GPU:-0}" != "1" ]; then
  # CPU: the pinned CPU torch (a local file on this project's machines) and the constraints that keep
  # pip from pulling CUDA wheels
  python3 -m venv .venv
  .venv/bin/pip install -q -c thermal_wild_ns/install/constraints-cpu.txt '.[dev]' 2> >(grep -v "^WARNING: Location" >&2)
else
  # GPU: a venv that sees the system's packages, so a CUDA torch already installed there is reused
  python3 -m venv --system-site-packages .venv
  # where python3 is itself a venv (e.g. an image's /opt/torch/.venv), "system" means its base
  # interpreter: make the parent venv's packages visible too, after the new venv's own
  parent=$(python3 -c 'import sys, sysconfig; print(sysconfig.get_paths()["purelib"] if sys.prefix != sys.base_prefix else "")')
  if [ -n "$parent" ]; then
    echo "$parent" > "$(.venv/bin/python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')/parent-venv.pth"
  fi
  if .venv/bin/python -c "import torch, sys; sys.exit(0 if torch.version.cuda else 1)" 2>/dev/null; then
    echo "reusing the installed CUDA torch: $(.venv/bin/python -c 'import torch; print(torch.__version__)')"
  else
    echo "no CUDA torch found: installing one (pip's default torch wheels are CUDA builds)"
    .venv/bin/pip install -q torch
  fi
  if [ "${NERFSTUDIO_DEPS:-full}" = "light" ]; then
    # nerfstudio and gsplat with only the dependencies the commands import (requirements-light.txt);
    # with PIP_NO_INDEX=1 PIP_FIND_LINKS=<folder of wheels> this runs on a machine without a registry
    .venv/bin/pip install -q --no-deps -r thermal_wild_ns/install/requirements-light.txt
    .venv/bin/pip install -q --no-deps --no-build-isolation '.'
  else
    .venv/bin/pip install -q '.[dev]'
  fi
  # gsplat builds its CUDA extension the first time it rasterizes, with nvcc (minutes); a prebuilt
  # extension for this torch/CUDA/GPU can be dropped in instead: GSPLAT_PREBUILT=path/to/csrc.so
  if [ -n "${GSPLAT_PREBUILT:-}" ]; then
    cp "$GSPLAT_PREBUILT" "$(.venv/bin/python -c 'import gsplat, os; print(os.path.dirname(gsplat.__file__))')/csrc.so"
  elif ! command -v nvcc >/dev/null; then
    echo "warning: no nvcc on PATH: gsplat cannot build its CUDA extension at first use (install the CUDA toolkit)" >&2
  fi
fi
# DJI's converter, for °C of DJI-format R-JPEGs: AGPL-3.0, so it lives in an environment of its own and runs as a
# program, never imported (docs/rjpeg.md). It declares Python >= 3.12 and runs on 3.11 (tests/test_rjpeg.py checks
# it on the 9 DJI cameras); linked beside the venv's Python, where the package looks for it.
install_dji_converter() {
  local env=.venv/dji-converter
  python3 -m venv "$env" \
    && "$env/bin/pip" install -q "numpy<2" "pillow>=11.3" 2> >(grep -v "^WARNING: Location" >&2) \
    && "$env/bin/pip" install -q --no-deps --ignore-requires-python "dji-thermal-cli==1.4.0" 2> >(grep -v "^WARNING" >&2) \
    && ln -sf ../dji-converter/bin/dji-thermal-cli .venv/bin/dji-thermal-cli \
    && .venv/bin/dji-thermal-cli --version
}
install_dji_converter || echo "warning: DJI's converter could not be installed: DJI-format R-JPEGs train on raw counts, without °C" >&2
rm -rf build
.venv/bin/python -c "import torchvision, nerfstudio.scripts.train, nerfstudio.scripts.eval, nerfstudio.scripts.render, thermal_wild_ns.method_configs; print('environment ready')"
