#!/usr/bin/env bash
# Create .venv and install thermal_wild_ns with nerfstudio 1.1.5.
# CPU-only machines: constraints keep the CPU torch and never pull CUDA wheels.
# GPU machines: pass GPU=1 to let pip choose the CUDA torch that nerfstudio/gsplat need.
set -euo pipefail
cd "$(dirname "$0")/../.."
python3 -m venv .venv
constraints=()
if [ "${GPU:-0}" != "1" ]; then
  constraints=(-c thermal_wild_ns/install/constraints-cpu.txt)
fi
.venv/bin/pip install -q "${constraints[@]}" '.[dev]' 2> >(grep -v "^WARNING: Location" >&2)
rm -rf build
.venv/bin/python -c "import torchvision, thermal_wild_ns.compat; print('environment ready')"
