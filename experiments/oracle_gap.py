"""The `time`-`oracle` gap of each run, split by `oracle_lut` into the LUT prediction's share
(`oracle_lut` - `time`) and the embedding's (`oracle` - `oracle_lut`), from bench results
(`bench.json` files); mean (min-max) of the per-run differences, per file and scene. `oracle` and
`oracle_lut` read the held-out frame's pixels: bounds, not results.

    python -m experiments.oracle_gap docs/results/camera_flat_field/{flight2,dunr}-*.json
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import List

from experiments import mean_range


def main(paths: List[Path]) -> None:
    print("| results | scene | runs | `oracle` - `time` | the LUT's share | the embedding's share |")
    print("| --- | --- | --- | --- | --- | --- |")
    for path in paths:
        runs = [r for r in json.loads(path.read_text())["runs"] if "psnr_oracle_lut" in r]
        for scene in dict.fromkeys(r["scene"] for r in runs):
            own = [r for r in runs if r["scene"] == scene]
            gap = mean_range([r["psnr_oracle"] - r["psnr_time"] for r in own])
            lut = mean_range([r["psnr_oracle_lut"] - r["psnr_time"] for r in own])
            embedding = mean_range([r["psnr_oracle"] - r["psnr_oracle_lut"] for r in own])
            print(f"| {path.stem} | {scene} | {len(own)} | {gap} | {lut} | {embedding} |")


if __name__ == "__main__":
    main([Path(p) for p in sys.argv[1:]])
