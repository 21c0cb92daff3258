"""Which single LUT a novel view should map back through, with no model: the `novel` protocol's LUT
share of its error in the limit of a perfect render (issue 33, the canonical state).

For each held-out frame of a scene's default split, the frame processed by its own LUT (what a perfect
model renders in training space, the preprocessing's stabilization making that the same scene at every
capture time) is mapped back to the sensor's levels through one fixed LUT and scored against the raw
frame, PSNR as the evaluation's (dataset-normalised, range 1):

- `median`: the level-wise median of the training frames' LUTs (`PreprocessedSequence.median_lut`,
  what the `novel` protocol uses);
- `mean_inverse`: the LUT whose inverse is the mean of the training frames' inverses
  (`photometric.blend_inverses` at equal weights): per processed value, the mean of the original
  levels the training frames gave it, the fixed map with the least expected squared error over their
  states.

python -m experiments.canonical_lut --scenes ../shared/data/dunr ../shared/data/flight2 \
    --output-dir docs/results/canonical_lut
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Dict, List

import numpy as np
import torch
import tyro

from experiments import SceneStudyArgs, split_luts
from thermal_wild_ns.data.thermal_io import read_raw_frame
from thermal_wild_ns.image_metrics import psnr
from thermal_wild_ns.preprocessing.photometric import apply_lut, blend_inverses, invert_lut


def scene_scores(scene: Path, cache_dir: Path) -> Dict:
    capture, rng, train, sequence = split_luts(scene, cache_dir)
    candidates = {
        "median": sequence.median_lut(),
        "mean_inverse": blend_inverses([np.asarray(sequence.luts[t]) for t in train], [1.0 / len(train)] * len(train)),
    }
    held_out = [t for t in range(len(capture.frames)) if t not in train]
    scores: Dict[str, List[float]] = {name: [] for name in candidates}
    for t in held_out:
        raw = read_raw_frame(capture.frames[t].image, rng.palette)  # [H, W] native
        processed = apply_lut(sequence.oracle_lut(t), raw, sequence.grid)  # [H, W] native
        truth = torch.from_numpy(np.asarray(rng.normalize(raw), dtype=np.float64))
        for name, lut in candidates.items():
            back = np.asarray(rng.normalize(invert_lut(lut, processed, sequence.grid)), dtype=np.float64)
            scores[name].append(float(psnr(torch.from_numpy(back), truth)))
    return {"scene": scene.name, "held_out": held_out, **{name: s for name, s in scores.items()}}


def main(args: SceneStudyArgs) -> None:
    args.output_dir.mkdir(parents=True, exist_ok=True)
    results = [scene_scores(scene, args.cache_dir) for scene in args.scenes]
    (args.output_dir / "canonical_lut.json").write_text(json.dumps(results, indent=1))
    lines = [
        "| scene | held-out frames | `median` (the `novel` protocol's) | `mean_inverse` "
        "| frames where `mean_inverse` is higher |",
        "| --- | --- | --- | --- | --- |",
    ]
    for r in results:
        median, mean = np.array(r["median"]), np.array(r["mean_inverse"])
        lines.append(
            f"| {r['scene']} | {len(r['held_out'])} | {median.mean():.2f} | {mean.mean():.2f} | "
            f"{int((mean > median).sum())} of {len(median)} |"
        )
    (args.output_dir / "canonical_lut.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main(tyro.cli(SceneStudyArgs))
