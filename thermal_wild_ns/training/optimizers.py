"""Optimizer configs of the plugin's methods."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Tuple

from nerfstudio.engine.optimizers import AdamOptimizerConfig


@dataclass
class FusedAdamOptimizerConfig(AdamOptimizerConfig):
    """nerfstudio's Adam config with torch's fused implementation: one kernel per optimizer step
    instead of one per elementwise operation (a training step is bound by launches, not by arithmetic)."""

    fused: bool = True
    """Use torch.optim.Adam(fused=True) (CUDA and CPU, torch >= 2.4)."""
    betas: Tuple[float, float] = (0.9, 0.999)
    """Adam's decay rates of its moment estimates (torch's defaults). A run that trains several images
    per step sets them for the batch (`for_images`)."""

    def for_images(self, images: int) -> "FusedAdamOptimizerConfig":
        """These settings, given for one image per step, set for `images` per step as gsplat's
        multi-GPU trainer sets them (examples/simple_trainer.py, batch size N): learning rate times
        sqrt(N), eps over sqrt(N), each beta 1 - N(1 - beta) -- the moments then average over the
        same number of images as one image per step does. The schedulers are left as they are."""
        if images == 1:
            return self
        root = math.sqrt(images)
        betas = tuple(1 - images * (1 - beta) for beta in self.betas)
        if min(betas) <= 0:
            raise ValueError(f"Adam's betas {self.betas} cannot be set for {images} images per step")
        return dataclasses.replace(self, lr=self.lr * root, eps=self.eps / root, betas=betas)
