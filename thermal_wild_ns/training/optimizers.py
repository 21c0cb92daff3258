"""Optimizer configs of the plugin's methods."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Tuple

from nerfstudio.engine.optimizers import AdamOptimizerConfig


@dataclass
class FusedAdamOptimizerConfig(AdamOptimizerConfig):
    """nerfstudio's Adam config with torch's fused implementation: one kernel per optimizer step
    instead of a dozen (a training step is bound by launches, not by arithmetic)."""

    fused: bool = True
    """Use torch.optim.Adam(fused=True) (CUDA and CPU, torch >= 2.4)."""
    betas: Tuple[float, float] = (0.9, 0.999)
    """Adam's decay rates of its moment estimates (torch's defaults). Trainers that take several images
    per step set them for the batch: gsplat's multi-GPU trainer uses 1 - N(1 - beta) for N images, with
    the learning rate times sqrt(N) and eps over sqrt(N)."""
