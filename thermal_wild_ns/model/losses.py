"""The losses of thermal splatting on single-channel images ([H, W, 1] tensors): heat-aware SSIM
and the alpha regulariser (the plain image metrics are `image_metrics.py`'s)."""

from __future__ import annotations

from typing import Optional

import torch
from torch import Tensor

from thermal_wild_ns.image_metrics import ssim


def thermal_contrast(target: Tensor, max_samples: int = 65536) -> Tensor:
    """Robust intensity span of a thermal frame: 99th minus 1st percentile (detached, >= 1e-3)."""
    flat = target.detach().reshape(-1)
    if flat.numel() > max_samples:  # percentiles of a strided subsample are accurate enough
        flat = flat[:: flat.numel() // max_samples + 1]
    lo, hi = torch.quantile(flat, torch.tensor([0.01, 0.99], device=flat.device, dtype=flat.dtype))
    return (hi - lo).clamp(min=1e-3)


def heat_aware_ssim(pred: Tensor, target: Tensor, contrast: Optional[Tensor] = None) -> Tensor:
    """SSIM whose stabilising constants follow the frame's own thermal contrast.

    Thermal-NeRF (Ye et al. 2024) motivates a "heat-aware" SSIM; its exact formula is not
    available here, so this is the form we can justify: plain SSIM's constants C1 = (0.01 L)^2,
    C2 = (0.03 L)^2 assume the signal spans the data range L = 1. A thermal frame normalised per
    dataset typically spans a few percent of it, so its local variances are of the order of C2
    and SSIM goes blind to exactly the soft heat gradients we must reconstruct. Here
    L = p99 - p1 of the *target* frame (detached), i.e. SSIM is measured relative to the scene's
    actual temperature contrast. For a frame that spans the full range it equals plain SSIM.
    `contrast`: the target's `thermal_contrast`, when the caller has it already.
    """
    return ssim(pred, target, data_range=thermal_contrast(target) if contrast is None else contrast)


def alpha_regularizer(alpha: Tensor, target: Tensor, background: Tensor, tolerance: float) -> Tensor:
    """Penalise opacity where the background model already explains the target.

    weight = exp(-|target - background| / tolerance) is ~1 on pixels the background MLP predicts
    (sky, far field) and ~0 elsewhere; the loss is the mean weighted alpha. Gaussians that sit in
    front of such pixels are floaters: they only pay, so they fade and get pruned. The background
    is detached so that the regulariser cannot move the background towards the splats instead.
    """
    weight = torch.exp(-(target - background.detach()).abs() / tolerance)
    return (weight.detach() * alpha).mean()
