"""Optimizer configs of the plugin's methods."""

from __future__ import annotations

from dataclasses import dataclass

from nerfstudio.engine.optimizers import AdamOptimizerConfig


@dataclass
class FusedAdamOptimizerConfig(AdamOptimizerConfig):
    """nerfstudio's Adam config with torch's fused implementation: one kernel per optimizer step
    instead of a dozen (a training step is bound by launches, not by arithmetic)."""

    fused: bool = True
    """Use torch.optim.Adam(fused=True) (CUDA and CPU, torch >= 2.4)."""
