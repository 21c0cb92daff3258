"""`python -m experiments.few_view_gaussians`: how many of a trained model's Gaussians few training frames see.

A model without a per-frame state (`wild-thermal-3dgs`) loses held-out views as it grows on flight2
(`docs/results/growth/`); the reading there is that the frames' level changes go into the scene. One way they
can: Gaussians that only one or two training frames see (near a camera, or at the edge of the covered ground)
are free to take a frame's own level, and a held-out view that sees them gets it wrong. This counts, for each
Gaussian of one or more trained runs, the training frames whose view frustum holds its centre in front of the
camera (geometry only: occlusion ignored, so the counts are upper bounds), and writes per run the share of
Gaussians, and of their opacity, that k or fewer frames see, and how near they sit to the nearest camera.
Comparing a small and a large model of the same scene says whether growth adds such Gaussians. With
`--score-without K` it also scores each model's held-out views (`novel`, `time`, `aligned`) as trained and again
with the Gaussians that K or fewer frames see taken out (nothing retrained): whether they cost or carry the views.

    python -m experiments.few_view_gaussians RUN_A/config.yml RUN_B/config.yml --output few_view.json
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional

import torch
import tyro

FEW = (1, 2, 3)
"""The frame counts the summary reports ("seen by k or fewer training frames")."""


@dataclass
class FewViewArgs:
    configs: tyro.conf.Positional[List[Path]] = field(default_factory=list)
    """config.yml of each trained run."""
    output: Path = Path("outputs/few_view_gaussians.json")
    chunk: int = 65536
    """Gaussians projected at once (memory: chunk x frames floats)."""
    score_without: Optional[int] = None
    """Also score the held-out views without the Gaussians this many or fewer training frames see (None: no)."""


SCORED = ("novel", "time", "aligned")


def keep_gaussians(model, keep: torch.Tensor) -> None:
    """Keep only the Gaussians where `keep` [N] holds, in every per-Gaussian parameter of `model`."""
    for name, param in list(model.gauss_params.items()):
        model.gauss_params[name] = torch.nn.Parameter(param.detach()[keep.to(param.device)])


def frames_seeing(means: torch.Tensor, cameras, chunk: int = 65536) -> Dict[str, torch.Tensor]:
    """Per Gaussian centre (`means` [N, 3], world frame): how many of `cameras` (nerfstudio's, OpenGL axes:
    looking down -z) hold it inside their image and in front (`count` [N]), and its distance to the nearest
    camera centre (`nearest` [N])."""
    c2w = cameras.camera_to_worlds.to(means)  # [F, 3, 4]
    rotation, centre = c2w[:, :, :3], c2w[:, :, 3]  # [F, 3, 3], [F, 3]
    fx, fy = cameras.fx.to(means).view(-1), cameras.fy.to(means).view(-1)  # [F]
    cx, cy = cameras.cx.to(means).view(-1), cameras.cy.to(means).view(-1)
    width, height = cameras.width.to(means).view(-1), cameras.height.to(means).view(-1)
    counts, nearest = [], []
    for part in means.split(chunk):
        offset = part[:, None, :] - centre[None]  # [n, F, 3]
        local = torch.einsum("nfi,fij->nfj", offset, rotation)  # R^T (x - c) [n, F, 3]
        depth = -local[..., 2]  # [n, F]
        safe = depth.clamp_min(1e-9)
        u = fx * local[..., 0] / safe + cx
        v = -fy * local[..., 1] / safe + cy
        inside = (depth > 0) & (u >= 0) & (u < width) & (v >= 0) & (v < height)
        counts.append(inside.sum(1))
        nearest.append(offset.norm(dim=-1).amin(1))
    return {"count": torch.cat(counts), "nearest": torch.cat(nearest)}


def summary(count: torch.Tensor, nearest: torch.Tensor, opacity: torch.Tensor, frames: int) -> Dict:
    """The shares of Gaussians (and of their opacity) that `FEW` or fewer frames see, and the median distance to
    the nearest camera of those and of the rest, over the median of all."""
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


def _scores(scores: Dict) -> Dict:
    return {p: scores[f"psnr_{p}"] for p in SCORED}


def main(args: FewViewArgs) -> None:
    from nerfstudio.utils.eval_utils import eval_setup

    from thermal_wild_ns._upstream import prepare_checkpoint_commands

    prepare_checkpoint_commands()
    results = []
    for config in args.configs:
        _, pipeline, _, step = eval_setup(config, test_mode="test")
        model = pipeline.model
        cameras = pipeline.datamanager.train_dataset.cameras
        with torch.no_grad():
            means = model.means.detach().float()
            seen = frames_seeing(means, cameras, args.chunk)
            opacity = torch.sigmoid(model.opacities.detach().float()).view(-1)
        result = {
            "config": str(config),
            "step": step,
            **summary(seen["count"].cpu(), seen["nearest"].cpu(), opacity.cpu(), len(cameras)),
        }
        if args.score_without is not None:
            from thermal_wild_ns.pipeline.evaluation import evaluate

            result["scores"] = {p: round(float(v), 3) for p, v in _scores(evaluate(pipeline, protocols=SCORED)).items()}
            keep_gaussians(model, seen["count"] > args.score_without)
            result[f"scores_without_seen_by_at_most_{args.score_without}"] = {
                p: round(float(v), 3) for p, v in _scores(evaluate(pipeline, protocols=SCORED)).items()
            }
        print(json.dumps(result))
        results.append(result)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(results, indent=1) + "\n")


if __name__ == "__main__":
    main(tyro.cli(FewViewArgs))
