"""Is a held-out frame's state better predicted by blending its neighbours' renders than by rendering
at the blend of their embeddings? Scores one trained run's `time` protocol both ways, per view.

    python -m experiments.time_blend RUN/config.yml [RUN2/config.yml ...] [--output F.json]

`time` (`pipeline/evaluation.py`) renders a held-out frame at the frame embedding interpolated linearly
between the two training frames around it (`FrameStates.at`). The emission MLP is not linear in the
embedding, so the render at the middle embedding need not be the middle of the two renders, even
where the sensor's state is linear in time (the flat-field scene's ramp). The blend here renders each
neighbour at its own state (its embedding and LUT), takes each back to the original space, and mixes
the two images with the same weights: a render is linear in the Gaussians' emission and the
background, so that is the blend of the emissions, not of the embeddings. Per view also the `time`
render's mean error against the recorded frame and its PSNR with that mean taken out (an offset fitted
on the held-out view: a fit, not a result): where that PSNR reaches `oracle`'s, the predicted state's
loss is its level alone.
"""

from __future__ import annotations

from pathlib import Path
from typing import Dict, List

import numpy as np

from experiments import held_out_views, offset_fitted, score_checkpoints
from thermal_wild_ns.pipeline.evaluation import scores
from thermal_wild_ns.pipeline.photometric_state import render, state_at
from thermal_wild_ns.preprocessing.photometric import time_weights


def neighbour_blend(pipeline, camera, t: float) -> np.ndarray:
    """[H, W] original space: the renders at the two training frames around `t`, each at its own
    state (`state_at` a training frame's position is exactly its embedding and LUT), mixed with the
    weights `time` interpolates their embeddings with."""
    times = pipeline.model.frame_times
    i, j, w = time_weights(times, t)
    left = render(pipeline, camera, state_at(pipeline, times[i]))[1]
    if w == 0.0:
        return left
    return (1.0 - w) * left + w * render(pipeline, camera, state_at(pipeline, times[j]))[1]


def score_run(config: Path) -> Dict:
    rows: List[Dict] = []
    for pipeline, camera, _, index, frame in held_out_views(config):
        recorded = pipeline.datamanager.eval_dataset.recorded_image(index)
        embedded = render(pipeline, camera, state_at(pipeline, frame))[1]
        blended = neighbour_blend(pipeline, camera, frame)
        level, fitted = offset_fitted(embedded, recorded)
        rows.append(
            {
                "frame": frame,
                "psnr_time": scores(embedded, recorded)["psnr"],
                "psnr_time_blend": scores(blended, recorded)["psnr"],
                "time_mean_error": level,
                "psnr_time_offset_fitted": fitted,
            }
        )
    return {
        "config": str(config),
        "psnr_time": float(np.mean([r["psnr_time"] for r in rows])),
        "psnr_time_blend": float(np.mean([r["psnr_time_blend"] for r in rows])),
        "psnr_time_offset_fitted": float(np.mean([r["psnr_time_offset_fitted"] for r in rows])),
        "per_view": rows,
    }


def main() -> None:
    def line(result: Dict) -> str:
        views = " ".join(
            f"{r['frame']}:{r['psnr_time']:.2f}/{r['psnr_time_blend']:.2f}/{r['psnr_time_offset_fitted']:.2f}"
            f"/{r['time_mean_error']:+.4f}"
            for r in result["per_view"]
        )
        return (
            f"time {result['psnr_time']:.2f}, blended renders {result['psnr_time_blend']:.2f}, offset fitted "
            f"{result['psnr_time_offset_fitted']:.2f} (per view: time/blend/offset fitted/mean error: {views})"
        )

    score_checkpoints("Score `time` with blended embeddings and blended renders.", score_run, line)


if __name__ == "__main__":
    main()
