"""How much of a run's `novel` error is the canonical state's level? Per held-out view, the `novel` render
against the view's truth: its PSNR, its mean error (render minus truth, dataset-normalised units), and its
PSNR once that mean is taken out (an offset fitted on the held-out view, where `aligned` fits a gain and an
offset: a fit, not a result).

    python -m experiments.novel_level RUN/config.yml [RUN2/config.yml ...] [--output F.json]

On a generated scene the truth is the fault-free scene, while the training frames carry the sensor's drift:
the canonical state then renders the scene at the frames' average level, which is not the truth's, and the
PSNR of `novel` reads that level difference along with the scene's shape.
"""

from __future__ import annotations

from pathlib import Path
from typing import Dict, List

import numpy as np

from experiments import held_out_views, offset_fitted, score_checkpoints
from thermal_wild_ns.pipeline.evaluation import scores
from thermal_wild_ns.pipeline.photometric_state import canonical_state, render


def score_run(config: Path) -> Dict:
    rows: List[Dict] = []
    for pipeline, camera, batch, index, frame in held_out_views(config):
        truth = batch["image"].float().mean(dim=-1).cpu().numpy()  # [H, W], as `evaluate` reads it
        recorded = not pipeline.datamanager.eval_dataset.is_clean_truth(index)
        novel = render(pipeline, camera, canonical_state(pipeline), recorded=recorded)[1]
        bias, fitted = offset_fitted(novel, truth)
        rows.append(
            {
                "frame": frame,
                "psnr_novel": scores(novel, truth)["psnr"],
                "mean_error": bias,
                "psnr_novel_offset_fitted": fitted,
            }
        )
    keys = ("psnr_novel", "mean_error", "psnr_novel_offset_fitted")
    return {"config": str(config), **{k: float(np.mean([r[k] for r in rows])) for k in keys}, "per_view": rows}


def main() -> None:
    score_checkpoints(
        "Split a run's `novel` error into the level and the rest.",
        score_run,
        lambda r: (
            f"novel {r['psnr_novel']:.2f} dB, mean error {r['mean_error']:+.4f}, "
            f"offset taken out {r['psnr_novel_offset_fitted']:.2f} dB"
        ),
    )


if __name__ == "__main__":
    main()
