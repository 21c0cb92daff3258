"""How far a capture's content moves across the sensor: what tells a pattern fixed to the camera
(vignetting, an uneven flat field) apart from the scene.

A pattern fixed to the sensor stays at the same pixels in every frame; the scene moves across them
as the camera moves. Where every scene point crosses much of the frame (a drone survey flying over
it), a model fitted to the frames can only explain what stays at the same pixels by the camera's
pattern. Where the content stays at about the same place in every frame (an orbit that keeps the
target in the middle), a fixed pattern and the content that always sits there fit the frames
equally well, and a flexible camera model takes scene content into it (docs/results/camera_flat_field).

The measure: each seed point projected into every training camera; the spread (standard deviation)
of its image position over the frames that see it, in frame widths and heights; the mean over the
points seen at least twice."""

from __future__ import annotations

from typing import Optional, Tuple

import torch
from nerfstudio.cameras.cameras import Cameras
from torch import Tensor

MAX_POINTS = 4096
"""Seed points the measure looks at (evenly strided): enough for a stable mean, bounded memory."""
FRAMES_PER_CHUNK = 256


def pixel_positions(cameras: Cameras, points: Tensor) -> Tuple[Tensor, Tensor, Tensor]:
    """Where `points` [P, 3] fall in each of `cameras` [F] (nerfstudio's: OpenGL axes, looking down -z):
    u and v in pixels [F, P] and the depth in front of the camera [F, P] (negative behind it)."""
    c2w = cameras.camera_to_worlds.float()  # [F, 3, 4]
    local = torch.einsum("fji,fpj->fpi", c2w[:, :, :3], points[None] - c2w[:, None, :, 3])  # [F, P, 3]
    depth = -local[..., 2]  # [F, P], positive in front of the camera
    u = cameras.fx.float() * local[..., 0] / depth + cameras.cx.float()  # [F, P]
    v = cameras.fy.float() * -local[..., 1] / depth + cameras.cy.float()
    return u, v, depth


def content_motion(cameras: Cameras, points: Optional[Tensor]) -> Optional[float]:
    """The mean spread of the seed points' image positions across the training frames that see them,
    in frame sizes (0: the content never moves across the sensor; 1/sqrt(12), about 0.29, for points
    seen at evenly spread places along a whole frame's width). `cameras` [F] (nerfstudio's: OpenGL
    axes, the camera looking down -z), `points` [P, 3] in the same world frame. None where fewer than
    two frames see any point (or no points)."""
    if points is None or len(points) == 0 or len(cameras) < 2:
        return None
    points = points[:: len(points) // MAX_POINTS + 1].float()  # [P', 3]
    sums = torch.zeros(3, len(points), dtype=torch.float64)  # per point: frames seeing it, sum of positions, of squares
    squares = torch.zeros(len(points), dtype=torch.float64)
    for start in range(0, len(cameras), FRAMES_PER_CHUNK):
        part = cameras[start : start + FRAMES_PER_CHUNK]
        u, v, depth = pixel_positions(part, points)  # [F, P]
        u, v = u / part.width.float(), v / part.height.float()  # 0..1 in frame
        seen = (depth > 0) & (u >= 0) & (u < 1) & (v >= 0) & (v < 1)  # [F, P]
        u, v = torch.where(seen, u, 0.0).double(), torch.where(seen, v, 0.0).double()
        sums += torch.stack([seen.sum(0).double(), u.sum(0), v.sum(0)])
        squares += (u.square() + v.square()).sum(0)
    count, u_sum, v_sum = sums
    kept = count >= 2
    if not bool(kept.any()):
        return None
    count, u_sum, v_sum, squares = count[kept], u_sum[kept], v_sum[kept], squares[kept]
    variance = squares / count - (u_sum / count).square() - (v_sum / count).square()  # var(u) + var(v)
    return float(variance.clamp(min=0).sqrt().mean())
