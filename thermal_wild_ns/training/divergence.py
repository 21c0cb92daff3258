"""The divergence guard, apart from any trainer: `check_step` says why a step must be skipped (its
loss or gradients are not finite, or its loss spikes far above the recent median), `check_model` now
and then whether the model itself is broken (NaN/inf parameters, every Gaussian gone or transparent),
`record` counts skips and stops after too many in a row (`TrainingDiverged`)."""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass
from typing import Deque, Dict, List, Optional

import torch
from nerfstudio.models.splatfacto import SplatfactoModel
from nerfstudio.utils.rich_utils import CONSOLE


class TrainingDiverged(RuntimeError):
    """Training cannot go on: the model is broken (NaN/inf, collapsed) or every step fails."""


@dataclass
class DivergenceGuardConfig:
    enabled: bool = True
    """Skip bad steps and roll a broken model back (off: train without these checks)."""
    loss_spike_factor: float = 20.0
    """Skip a step whose loss exceeds this many times the median loss of the last accepted steps."""
    spike_window: int = 100
    """Accepted steps the median is taken over (no spike test before the window is full)."""
    persistent_frame_factor: float = 2.0
    """A spike is sudden: a frame whose loss on its previous visit was already within this factor
    of the spike is a hard frame (a flat-field jump, an outlier frame), and its step is accepted.
    Skipping it at every visit would silently drop that frame from training."""
    max_consecutive_skips: int = 50
    """Stop when this many steps in a row had to be skipped."""
    check_every: int = 100
    """Steps between checks of the model itself (finite parameters, Gaussians left, opacity)."""
    max_rollbacks: int = 3
    """When the model breaks (NaN/inf parameters, collapse, every step skipped), training goes back
    to the last healthy state (kept at every model check) up to this many times, then stops."""
    min_mean_opacity: float = 1e-3
    """Stop when the mean Gaussian opacity falls below this (everything turned transparent)."""


class DivergenceGuard:
    """The checks, independent of the trainer (`check_step` before the optimizer step,
    `check_model` now and then)."""

    def __init__(self, config: DivergenceGuardConfig):
        self.config = config
        self.recent: Deque[float] = collections.deque(maxlen=config.spike_window)
        self.frame_loss: Dict[int, float] = {}  # each training frame's loss at its last visit
        self.skipped = 0
        self.consecutive = 0
        self.rollbacks = 0

    def check_step(
        self, loss: Optional[torch.Tensor], parameters: dict, groups: List[str], frame: Optional[int] = None
    ) -> Optional[str]:
        """Why this step must be skipped, or None. One host sync: the loss and the sum of all
        gradient norms (one fused kernel; NaN/inf anywhere makes it non-finite) travel together.
        `frame`: the training image of this step, for telling spikes from hard frames."""
        grads = [(g, p.grad) for g in groups for p in parameters[g] if p.grad is not None]
        checks = [loss.detach().float().reshape(1)] if loss is not None else []
        if grads:
            checks.append(torch.stack(torch._foreach_norm([grad for _, grad in grads])).sum().float().reshape(1))
        if not checks:
            return None
        values = torch.cat([c.to(checks[0].device) for c in checks]).tolist()
        if loss is not None:
            value = values.pop(0)
            if not math.isfinite(value):
                return f"non-finite loss ({value})"
            previous = self.frame_loss.get(frame) if frame is not None else None
            if frame is not None:
                self.frame_loss[frame] = value
            if len(self.recent) == self.recent.maxlen:
                median = sorted(self.recent)[len(self.recent) // 2]
                hard_frame = previous is not None and value <= self.config.persistent_frame_factor * previous
                if value > self.config.loss_spike_factor * median and not hard_frame:
                    return f"loss spike ({value:.4g} > {self.config.loss_spike_factor:g} x recent median {median:.4g})"
        if grads and not math.isfinite(values[0]):  # rare: find the culprits one by one
            bad = sorted({g for g, grad in grads if not bool(torch.isfinite(grad).all())}) or ["(norm overflow)"]
            return f"non-finite gradients in {', '.join(bad)}"
        if loss is not None:
            self.recent.append(value)
        return None

    def rebaseline(self) -> None:
        """Forget the recent losses: the schedule itself just moved the loss (an opacity reset, a
        finer training resolution). Without this, every frame's first visit after such a step
        looks like a spike and is skipped, right when the model must recover."""
        self.recent.clear()
        self.frame_loss.clear()

    def record(self, step: int, reason: Optional[str]) -> None:
        if reason is None:
            self.consecutive = 0
            return
        self.skipped += 1
        self.consecutive += 1
        CONSOLE.log(f"[yellow]step {step}: {reason}; step skipped ({self.skipped} so far)")
        if self.consecutive >= self.config.max_consecutive_skips:
            raise TrainingDiverged(
                f"step {step}: {self.consecutive} steps in a row were skipped (last: {reason}). Training has diverged; "
                "lower the learning rates or check the data (diagnose it with wild-thermal-diagnose)."
            )

    def check_model(self, model, step: int) -> None:
        named = [(name, param) for name, param in model.named_parameters() if param.numel() > 0]
        finite = torch.stack([torch.isfinite(param).all() for _, param in named]).tolist()  # one host sync
        for (name, _), ok in zip(named, finite):
            if not ok:
                raise TrainingDiverged(f"step {step}: parameter '{name}' holds NaN/inf values; training has diverged")
        if isinstance(model, SplatfactoModel):  # Gaussians to count
            if model.num_points == 0:
                raise TrainingDiverged(f"step {step}: every Gaussian was pruned; the model collapsed to an empty scene")
            opacity = float(torch.sigmoid(model.opacities.detach()).mean())
            if opacity < self.config.min_mean_opacity:
                raise TrainingDiverged(
                    f"step {step}: mean Gaussian opacity {opacity:.2e} < {self.config.min_mean_opacity:g}; the "
                    f"scene has turned "
                    "transparent (the background explains every pixel)"
                )
