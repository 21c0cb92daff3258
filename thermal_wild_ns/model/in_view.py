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


def in_views(means: Tensor, log_scales: Tensor, viewmats: Tensor, Ks: Tensor, widths, heights) -> Tensor:
    """Gaussians at `means` [N, 3] with `log_scales` [N, 3] that may cover a pixel of each camera with gsplat's
    world-to-camera `viewmats` [C, 4, 4], intrinsics `Ks` [C, 3, 3] and image `widths`, `heights` (numbers, or
    [C, 1] tensors) -> [C, N] bool."""
    with torch.no_grad():
        p = means @ viewmats[:, :3, :3].transpose(1, 2) + viewmats[:, None, :3, 3]  # [C, N, 3], camera (OpenCV) axes
        z = p[..., 2]
        safe_z = z.clamp_min(NEAR)
        fx, fy, cx, cy = Ks[:, 0, 0, None], Ks[:, 1, 1, None], Ks[:, 0, 2, None], Ks[:, 1, 2, None]  # [C, 1] each
        u = fx * p[..., 0] / safe_z + cx
        v = fy * p[..., 1] / safe_z + cy
        extent = 3.0 * torch.exp(log_scales.max(dim=-1).values)  # [N], world units
        r = MARGIN * extent * torch.maximum(fx, fy) / safe_z + MARGIN_PX  # [C, N], pixels
        # gsplat culls a Gaussian whose centre is not beyond the near plane, whatever its extent
        return (z > NEAR) & (u + r > 0) & (u - r < widths) & (v + r > 0) & (v - r < heights)


def in_view(means: Tensor, log_scales: Tensor, viewmat: Tensor, K: Tensor, width: int, height: int) -> Tensor:
    """`in_views` for one camera (`viewmat` [4, 4], `K` [3, 3], `width` x `height`) -> [N] bool."""
    return in_views(means, log_scales, viewmat[None], K[None], width, height)[0]


CAMERA_CHUNK_ELEMENTS = 2**23
"""`frames_seeing` tests this many (camera, Gaussian) pairs at once: a few [C, N] temporaries of this size."""


def frames_seeing(means: Tensor, log_scales: Tensor, viewmats: Tensor, Ks: Tensor, sizes) -> Tensor:
    """How many of the cameras with world-to-camera `viewmats` [F, 4, 4], intrinsics `Ks` [F, 3, 3] and image
    `sizes` (F pairs of width, height) may draw each Gaussian at `means` [N, 3] with `log_scales` [N, 3]
    (`in_views`, cameras in chunks; occlusion ignored, so each count is an upper bound) -> [N] long."""
    count = torch.zeros(means.shape[0], dtype=torch.long, device=means.device)
    chunk = max(1, CAMERA_CHUNK_ELEMENTS // max(means.shape[0], 1))
    for start in range(0, len(sizes), chunk):
        wh = torch.tensor(sizes[start : start + chunk], dtype=means.dtype, device=means.device)  # [C, 2]
        seen = in_views(
            means, log_scales, viewmats[start : start + chunk], Ks[start : start + chunk], wh[:, :1], wh[:, 1:]
        )
        count += seen.sum(dim=0)
    return count


def few_view_mask(
    means: Tensor, log_scales: Tensor, viewmats: Tensor, Ks: Tensor, sizes, centres: Tensor, frames: int, nearer: float
) -> Tensor:
    """Gaussians (`means` [N, 3], `log_scales` [N, 3]) that `frames` or fewer of the cameras (`frames_seeing`'s
    `viewmats`, `Ks`, `sizes`; camera centres `centres` [F, 3]) may draw and, where `nearer` > 0, whose nearest
    camera is nearer than `nearer` times the median Gaussian's nearest camera -> [N] bool.

    Such a Gaussian is fitted by one to a few frames only, so it may take those frames' own level or noise, and a
    view from elsewhere sees it at the wrong level; near a camera it is a floater in front of that frame. The ground
    at the edge of a survey's coverage is also seen by few frames, but from the survey's usual distance: `nearer`
    keeps it, 0 does not."""
    with torch.no_grad():
        few = frames_seeing(means, log_scales, viewmats, Ks, sizes) <= frames  # [N]
        if nearer > 0:
            nearest = torch.cdist(means, centres.to(means)).amin(dim=1)  # [N]
            few &= nearest < nearer * nearest.median()
        return few
