"""How well a held-out frame's LUT is predicted from its neighbours, with no model: the `time`
protocol's LUT share of the `time`-`oracle` gap in the limit of a perfect render.

For each held-out frame of a scene's default split: its own LUT (`oracle_lut`, built from its
pixels), and the LUT the `time` protocol uses, interpolated between the neighbouring training
frames' LUTs in two ways: level by level (averaging the maps' outputs) and quantile by quantile
(`blend_luts`, averaging their inverses: for frames that differ
by a drifting offset or gain, the in-between frame's map). The frame processed by its own LUT,
mapped back through each prediction, against the raw frame: PSNR (dataset-normalised, range 1, as
the evaluation's). Own LUT: exact.

python -m experiments.lut_prediction --scenes ../shared/data/dunr ../shared/data/flight2 \
    --output-dir docs/results/lut_prediction
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Dict, List, Tuple

import numpy as np
import torch
import tyro

from experiments import SceneStudyArgs, split_luts
from thermal_wild_ns.data.thermal_io import read_raw_frame
from thermal_wild_ns.image_metrics import psnr
from thermal_wild_ns.preprocessing.photometric import apply_lut, blend_luts, invert_lut, time_weights


def blend_levelwise(lut_a: np.ndarray, lut_b: np.ndarray, weight: float) -> np.ndarray:
    """(1 - w) a + w b, level by level: the interpolation `blend_luts` replaced."""
    return (1.0 - weight) * lut_a + weight * lut_b


def scene_scores(scene: Path, cache_dir: Path) -> Dict:
    capture, rng, train, sequence = split_luts(scene, cache_dir)
    frames = train
    rows: List[Tuple[int, float, float]] = []
    for t in range(len(capture.frames)):
        if t in train:
            continue
        raw = read_raw_frame(capture.frames[t].image, rng.palette)  # [H, W] native
        processed = apply_lut(sequence.oracle_lut(t), raw, sequence.grid)  # [H, W] native
        i, j, w = time_weights(frames, t)
        a, b = np.asarray(sequence.luts[frames[i]]), np.asarray(sequence.luts[frames[j]])
        truth = torch.from_numpy(np.asarray(rng.normalize(raw), dtype=np.float64))
        scores = []
        for lut in (blend_levelwise(a, b, w), blend_luts(a, b, w)):
            back = torch.from_numpy(
                np.asarray(rng.normalize(invert_lut(lut, processed, sequence.grid)), dtype=np.float64)
            )
            scores.append(float(psnr(back, truth)))
        rows.append((t, *scores))
    levelwise, quantilewise = (np.array([r[k] for r in rows]) for k in (1, 2))
    return {
        "scene": scene.name,
        "held_out": [r[0] for r in rows],
        "levelwise": levelwise.tolist(),
        "quantilewise": quantilewise.tolist(),
        "mean_levelwise": float(levelwise.mean()),
        "mean_quantilewise": float(quantilewise.mean()),
    }


def main(args: SceneStudyArgs) -> None:
    args.output_dir.mkdir(parents=True, exist_ok=True)
    results = [scene_scores(scene, args.cache_dir) for scene in args.scenes]
    (args.output_dir / "lut_prediction.json").write_text(json.dumps(results, indent=1))
    lines = [
        "| scene | held-out frames | level by level (before) | quantile by quantile (`blend_luts`) |",
        "| --- | --- | --- | --- |",
    ]
    for r in results:
        lines.append(
            f"| {r['scene']} | {len(r['held_out'])} | {r['mean_levelwise']:.2f} | {r['mean_quantilewise']:.2f} |"
        )
    (args.output_dir / "lut_prediction.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main(tyro.cli(SceneStudyArgs))
