"""`python -m experiments.few_view_gaussians`: how many of a trained model's Gaussians few training frames see,
and what the held-out views lose without them.

A model without a per-frame state (`wild-thermal-3dgs`) loses held-out views as it grows on flight2
(`docs/results/growth/`); the reading there is that the frames' level changes go into the scene. One way they
can: Gaussians that only one to three training frames see (near a camera, or at the edge of the covered ground)
are free to take those frames' own level, and a held-out view that sees them gets it wrong. For each trained run
this counts, per Gaussian, the training frames that may draw it (the model's own `in_view` test: its centre
inside the image grown by its projected extent; occlusion ignored, so the counts are upper bounds), writes the
share of Gaussians, and of their opacity, that k or fewer frames see and how near those sit to a camera, and
scores the held-out views (`novel`, `time`, `aligned`) as trained and again with the Gaussians that `FEW[-1]` or
fewer frames see taken out (nothing retrained): whether they cost or carry the views. Comparing a small and a
large model of one scene says whether growth adds such Gaussians.

    python -m experiments.few_view_gaussians RUN_A/config.yml RUN_B/config.yml --output few_view.json
"""

from __future__ import annotations

from pathlib import Path
from typing import Dict

import torch

from experiments import score_checkpoints
from thermal_wild_ns.model.camera_views import intrinsics
from thermal_wild_ns.model.in_view import frames_seeing as count_frames
from thermal_wild_ns.rendering import world_to_camera

FEW = (1, 2, 3)
"""The frame counts the summary reports ("seen by k or fewer training frames"); the last is the one scored."""
SCORED = ("novel", "time", "aligned")


def frames_seeing(means: torch.Tensor, log_scales: torch.Tensor, cameras) -> torch.Tensor:
    """How many of `cameras` (nerfstudio's) may draw each Gaussian at `means` [N, 3] with `log_scales` [N, 3]
    (the package's `in_view.frames_seeing`, the test the model uses to skip the emission of Gaussians a render
    does not draw, and its few-view prune) -> [N]."""
    viewmats = world_to_camera(cameras.camera_to_worlds.to(means))  # [F, 4, 4]
    Ks = intrinsics(cameras).to(means)  # [F, 3, 3]
    sizes = torch.cat([cameras.width.reshape(-1, 1), cameras.height.reshape(-1, 1)], dim=1).tolist()  # [F, 2]
    return count_frames(means, log_scales, viewmats, Ks, sizes)


def summary(count: torch.Tensor, nearest: torch.Tensor, opacity: torch.Tensor, frames: int) -> Dict:
    """The shares of Gaussians (and of their opacity) that `FEW` or fewer frames see (`count` [N]), and the median
    distance to the nearest camera (`nearest` [N]) of those and of the rest, over the median of all."""
    total_opacity = float(opacity.sum())
    scale = float(nearest.median())
    out: Dict = {
        "gaussians": int(count.numel()),
        "training_frames": frames,
        "median_frames_seeing": int(count.median()),
    }
    for k in FEW:
        few = count <= k
        out[f"share_seen_by_at_most_{k}"] = round(float(few.float().mean()), 4)
        out[f"opacity_share_seen_by_at_most_{k}"] = round(float(opacity[few].sum()) / max(total_opacity, 1e-12), 4)
    few = count <= FEW[-1]
    if few.any() and (~few).any():
        out[f"nearest_camera_seen_by_at_most_{FEW[-1]}_over_median"] = round(float(nearest[few].median()) / scale, 3)
        out["nearest_camera_seen_by_more_over_median"] = round(float(nearest[~few].median()) / scale, 3)
    return out


def keep_gaussians(model, keep: torch.Tensor) -> None:
    """Keep only the Gaussians where `keep` [N] holds, in every per-Gaussian parameter of `model`, for scoring (its
    optimizers and densification state are left behind; new parameter objects, so the baked values go stale)."""
    for name, param in list(model.gauss_params.items()):
        model.gauss_params[name] = torch.nn.Parameter(param.detach()[keep.to(param.device)])


def scored(pipeline) -> Dict[str, float]:
    from thermal_wild_ns.pipeline.evaluation import evaluate

    scores = evaluate(pipeline, protocols=SCORED)
    return {p: round(float(scores[f"psnr_{p}"]), 3) for p in SCORED}


def score_run(config: Path) -> Dict:
    from nerfstudio.utils.eval_utils import eval_setup

    _, pipeline, _, step = eval_setup(config, test_mode="test")
    model = pipeline.model
    cameras = pipeline.datamanager.train_dataset.cameras
    with torch.no_grad():
        means = model.means.detach().float()
        count = frames_seeing(means, model.scales.detach().float(), cameras)
        nearest = torch.cdist(means, cameras.camera_to_worlds[:, :, 3].to(means)).amin(1)  # [N]
        opacity = torch.sigmoid(model.opacities.detach().float()).view(-1)
    result = {"config": str(config), "step": step, **summary(count.cpu(), nearest.cpu(), opacity.cpu(), len(cameras))}
    result["scores"] = scored(pipeline)
    keep_gaussians(model, count > FEW[-1])
    result[f"scores_without_seen_by_at_most_{FEW[-1]}"] = scored(pipeline)
    return result


def main() -> None:
    score_checkpoints(
        "Count the Gaussians few training frames see, and score the held-out views without them.",
        score_run,
        lambda r: (
            f"{r['gaussians']} Gaussians, {r[f'share_seen_by_at_most_{FEW[-1]}']:.1%} seen by <= {FEW[-1]} frames; "
            f"novel {r['scores']['novel']:.2f} -> {r[f'scores_without_seen_by_at_most_{FEW[-1]}']['novel']:.2f} dB "
            "without them"
        ),
    )


if __name__ == "__main__":
    main()
