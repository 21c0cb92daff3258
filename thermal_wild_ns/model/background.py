"""The background MLP b(direction, frame embedding) as a render samples it: baked into a
latitude-longitude map under one frame embedding, read along a camera's pixel directions, and
upsampled from the `background_stride` grid."""

from __future__ import annotations

import math
from typing import Dict, Tuple

import torch
from torch import Tensor

from thermal_wild_ns.model.camera_views import ray_directions
from thermal_wild_ns.model.fields import BackgroundMLP

BAKED_BACKGROUND_TEXELS = (129, 256)
"""Latitude x longitude samples of the baked background map (about 1.4 degrees apart; the
background's direction encoding has spherical harmonics up to degree 3 only)."""


def background_map(
    mlp: BackgroundMLP, frame_embed: Tensor, texels: Tuple[int, int] = BAKED_BACKGROUND_TEXELS
) -> Tensor:
    """The MLP over every direction under `frame_embed`, as a latitude-longitude map
    [1, 1, rows, cols + 1] for `grid_sample` (align_corners: row 0 is latitude -90 degrees, the
    last +90; column 0 is longitude -180 degrees and the last column repeats it at +180, so
    sampling wraps around)."""
    rows, cols = texels
    latitude = torch.linspace(-math.pi / 2, math.pi / 2, rows, device=frame_embed.device)  # [rows]
    longitude = torch.arange(cols, device=frame_embed.device) * (2 * math.pi / cols) - math.pi  # [cols]
    dirs = torch.stack(
        [
            torch.cos(latitude)[:, None] * torch.cos(longitude)[None, :],
            torch.cos(latitude)[:, None] * torch.sin(longitude)[None, :],
            torch.sin(latitude)[:, None].expand(-1, cols),
        ],
        dim=-1,
    )  # [rows, cols, 3]
    values = mlp(dirs, frame_embed)[..., 0]  # [rows, cols]
    return torch.cat([values, values[:, :1]], dim=1)[None, None]  # [1, 1, rows, cols + 1]


def sample_map(baked: Tensor, dirs: Tensor) -> Tensor:
    """The baked map [1, 1, rows, cols + 1] along unit directions [h, w, 3] -> [h, w, 1]."""
    longitude = torch.atan2(dirs[..., 1], dirs[..., 0]) / math.pi  # [h, w] in [-1, 1]
    latitude = torch.asin(dirs[..., 2].clamp(-1.0, 1.0)) / (math.pi / 2)  # [h, w] in [-1, 1]
    grid = torch.stack([longitude, latitude], dim=-1)  # [h, w, 2]
    return torch.nn.functional.grid_sample(baked, grid[None], mode="bilinear", align_corners=True)[0].permute(
        1, 2, 0
    )  # [h, w, 1]


def upsampled(coarse: Tensor, width: int, height: int) -> Tensor:
    """The background on the `background_stride` grid [h, w, 1] at full resolution [H, W, 1]."""
    if coarse.shape[:2] == (height, width):
        return coarse
    # align_corners=False: coarse samples sit at the centres of stride x stride pixel blocks
    return torch.nn.functional.interpolate(
        coarse.permute(2, 0, 1)[None], size=(height, width), mode="bilinear", align_corners=False
    )[0].permute(1, 2, 0)


class CameraFrameDirections:
    """`ray_directions` of a camera at the origin, unrotated, per (intrinsics, size, stride): the
    last few are kept, as a viewer renders the same ones again."""

    KEPT = 8

    def __init__(self) -> None:
        self.kept: Dict[tuple, Tensor] = {}

    def __call__(self, K: Tensor, pinhole: Tuple[float, float, float, float], width: int, height: int, stride: int):
        """[h, w, 3] for intrinsics `K` [3, 3] (`pinhole`: its fx, fy, cx, cy on the host)."""
        key = (pinhole, width, height, stride)
        cached = self.kept.pop(key, None)
        if cached is None:
            cached = ray_directions(K, torch.eye(3, 4, device=K.device), width, height, stride)
        self.kept[key] = cached  # the most recent last
        while len(self.kept) > self.KEPT:
            self.kept.pop(next(iter(self.kept)))
        return cached
