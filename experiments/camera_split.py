"""How much of a generated scene's vignetting each run left to the camera model: the fitted gain fall-off at
the image corner, read from each run's recorded "camera fall-off" decision, beside its held-out scores.

    python -m experiments.camera_split RUNS-bench.json RUNS-decisions.tgz [--corner-rho 0.529] ...

Each pair is one bench.json and an archive of its runs' decisions.json files (a bench run's folder, its
runs' decisions.json files packed with `tar czf`). The fall-off is `g1 rho + g2 rho^2` at the corner's rho (the squared
off-axis tangent; 0.529 at the generated scenes' corner); a view term that takes part of the vignetting
into the scene leaves less of it to the camera (docs/results/view_verdict_cpu).
"""

from __future__ import annotations

import argparse
import json
import re
import tarfile
from pathlib import Path
from typing import Dict, Tuple

from experiments import mean_range

FALLOFF = re.compile(r"gain 1 ([+-]\d+\.\d+) rho ([+-]\d+\.\d+) rho\^2")


def corner_falloffs(archive: Path, corner_rho: float) -> Dict[Tuple[str, int], float]:
    """(scene, seed) -> the fitted gain fall-off at the corner, from every decisions.json in `archive`."""
    found = {}
    with tarfile.open(archive) as tar:
        for member in tar.getmembers():
            if not member.name.endswith("decisions.json"):
                continue
            match = re.search(r"runs/([^/]+)/[^/]*_seed(\d+)/", member.name)
            if match is None:
                raise ValueError(f"{archive}: cannot tell the scene and seed of {member.name}")
            parts = {d["part"]: d["choice"] for d in json.load(tar.extractfile(member))}
            gain = FALLOFF.search(parts.get("camera fall-off", ""))
            if gain is None:
                raise ValueError(f"{archive}: {member.name} records no fitted camera fall-off")
            g1, g2 = map(float, gain.groups())
            found[(match.group(1), int(match.group(2)))] = g1 * corner_rho + g2 * corner_rho**2
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description="The camera model's share of the vignetting, run by run.")
    parser.add_argument("pairs", nargs="+", type=Path, help="bench.json and decisions archive, pair by pair")
    parser.add_argument("--corner-rho", type=float, default=0.529, help="rho at the image corner")
    args = parser.parse_args()
    if len(args.pairs) % 2:
        parser.error("give bench.json and decisions archive in pairs")
    print("| runs | scene | fall-off at the corner, by seed | `novel` | `time` | `aligned` (a fit) |")
    print("| --- | --- | --- | --- | --- | --- |")
    for bench, archive in zip(args.pairs[::2], args.pairs[1::2]):
        falloffs = corner_falloffs(archive, args.corner_rho)
        runs = [r for r in json.loads(bench.read_text())["runs"] if "failed" not in r]
        for scene in sorted({r["scene"] for r in runs}):
            mine = sorted((r for r in runs if r["scene"] == scene), key=lambda r: r["seed"])
            corner = ", ".join(f"{falloffs[(scene, r['seed'])]:+.3f}" for r in mine)
            scores = " | ".join(mean_range([r[f"psnr_{p}"] for r in mine]) for p in ("novel", "time", "aligned"))
            print(f"| {bench.name} | {scene} | {corner} | {scores} |")


if __name__ == "__main__":
    main()
