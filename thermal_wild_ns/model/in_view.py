"""Which Gaussians a camera can see: the emission MLP need not run for the others.

A frame of a large survey sees a small part of the site; evaluating the emission MLP (and keeping its
activations for backward) for every Gaussian of the site costs memory and time in proportion to the
site, not to the frame. `in_view` is a conservative test (a Gaussian's centre inside the image grown by
its projected 3-sigma extent, with a margin): every Gaussian gsplat would draw passes it, so a render
whose emission is computed for these Gaussians only (zero elsewhere) is the same render.
"""

from __future__ import annotations

import torch
from torch import Tensor

NEAR = 0.01
"""gsplat's near plane in the model's renders."""
MARGIN = 2.0
"""Factor on the projected 3-sigma extent (the Jacobian of an off-axis projection stretches it), plus
`MARGIN_PX` pixels (gsplat's 0.3 px^2 blur and its radius rounding)."""
MARGIN_PX = 4.0


def in_view(means: Tensor, log_scales: Tensor, viewmat: Tensor, K: Tensor, width: int, height: int) -> Tensor:
    """Gaussians at `means` [N, 3] with `log_scales` [N, 3] that may cover a pixel of the camera with
    gsplat's world-to-camera `viewmat` [4, 4] and intrinsics `K` [3, 3] -> [N] bool."""
    with torch.no_grad():
        p = means @ viewmat[:3, :3].T + viewmat[:3, 3]  # [N, 3], camera (OpenCV) axes
        z = p[:, 2]
        safe_z = z.clamp_min(NEAR)
        u = K[0, 0] * p[:, 0] / safe_z + K[0, 2]
        v = K[1, 1] * p[:, 1] / safe_z + K[1, 2]
        extent = 3.0 * torch.exp(log_scales.max(dim=-1).values)  # [N], world units
        r = MARGIN * extent * torch.maximum(K[0, 0], K[1, 1]) / safe_z + MARGIN_PX  # [N], pixels
        # gsplat culls a Gaussian whose centre is not beyond the near plane, whatever its extent
        return (z > NEAR) & (u + r > 0) & (u - r < width) & (v + r > 0) & (v - r < height)
