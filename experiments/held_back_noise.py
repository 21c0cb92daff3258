"""How much the automatic stop's held-back score moves from check to check once a run has levelled
off, per scene, from bench results (`bench.json` files): the noise that the stop's plateau rule and
the view-term rule compare their 0.05 dB thresholds with.

    python -m experiments.held_back_noise docs/results/camera_flat_field/*.json

Per run, the stop's last four checks (the plateau it stopped on): their standard deviation, and the
mean absolute change between consecutive ones; mean (min-max) over the runs of a scene and file.
"""

from __future__ import annotations

import json
import statistics
import sys
from pathlib import Path
from typing import Dict, List, Tuple

from experiments import mean_range

LAST = 4


def plateau_noise(checks: List[float]) -> Tuple[float, float]:
    """(standard deviation of the last `LAST` checks, mean |change| between consecutive ones among them)."""
    tail = checks[-LAST:]
    return statistics.pstdev(tail), statistics.mean(abs(b - a) for a, b in zip(tail, tail[1:]))


def main(paths: List[Path]) -> None:
    rows: Dict[Tuple[str, str], List[Tuple[float, float]]] = {}
    for path in paths:
        for run in json.loads(path.read_text())["runs"]:
            checks = [c["psnr"] for c in (run.get("auto_stop") or {}).get("checks", [])]
            if len(checks) >= LAST:
                rows.setdefault((path.stem, run["scene"]), []).append(plateau_noise(checks))
    print(f"| results | scene | runs | std of the last {LAST} checks (dB) | mean change between them (dB) |")
    print("| --- | --- | --- | --- | --- |")
    for (name, scene), noise in rows.items():
        spread, change = mean_range([n[0] for n in noise]), mean_range([n[1] for n in noise])
        print(f"| {name} | {scene} | {len(noise)} | {spread} | {change} |")


if __name__ == "__main__":
    main([Path(p) for p in sys.argv[1:]])
