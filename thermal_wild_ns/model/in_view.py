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


def frames_seeing(means: Tensor, log_scales: Tensor, viewmats: Tensor, Ks: Tensor, sizes) -> Tensor:
    """How many of the cameras with world-to-camera `viewmats` [F, 4, 4], intrinsics `Ks` [F, 3, 3] and image
    `sizes` (F pairs of width, height) may draw each Gaussian at `means` [N, 3] with `log_scales` [N, 3]
    (`in_view`; occlusion ignored, so each count is an upper bound) -> [N] long."""
    count = torch.zeros(means.shape[0], dtype=torch.long, device=means.device)
    for viewmat, K, (width, height) in zip(viewmats, Ks, sizes):
        count += in_view(means, log_scales, viewmat, K, int(width), int(height))
    return count


def few_view_floaters(
    means: Tensor, log_scales: Tensor, viewmats: Tensor, Ks: Tensor, sizes, centres: Tensor, frames: int, nearer: float
) -> Tensor:
    """Gaussians (`means` [N, 3], `log_scales` [N, 3]) that `frames` or fewer of the cameras (`frames_seeing`'s
    `viewmats`, `Ks`, `sizes`; camera centres `centres` [F, 3]) may draw and, where `nearer` > 0, whose nearest
    camera is nearer than `nearer` times the median Gaussian's nearest camera -> [N] bool.

    Such a Gaussian is fitted by one to a few frames only, so it may take those frames' own level or noise, and a
    view from elsewhere sees it at the wrong level; near a camera it is a floater in front of that frame. The ground
    at the edge of a survey's coverage is also seen by few frames, but at the survey's usual distance: `nearer`
    keeps it."""
    with torch.no_grad():
        few = frames_seeing(means, log_scales, viewmats, Ks, sizes) <= frames  # [N]
        if nearer > 0:
            nearest = torch.cdist(means, centres.to(means)).amin(dim=1)  # [N]
            few &= nearest < nearer * nearest.median()
        return few
