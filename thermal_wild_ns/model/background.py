"""The background MLP b(direction, frame embedding) as a render samples it: baked into a
latitude-longitude map under one frame embedding, read along a camera's pixel directions, and
upsampled from the `background_stride` grid."""

from __future__ import annotations

import math
from typing import Callable, Dict, Optional, Tuple

import torch
from torch import Tensor, nn

from thermal_wild_ns.model.bake import BakedValues
from thermal_wild_ns.model.bilinear import bilinear_resize
from thermal_wild_ns.model.camera_views import ray_directions
from thermal_wild_ns.model.fields import BackgroundMLP
from thermal_wild_ns.model.graphed import GraphedCalls
from thermal_wild_ns.rendering import world_to_camera
from thermal_wild_ns.rendering.captured import CapturedCalls

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
    """The background on the `background_stride` grid [..., h, w, 1] at full resolution [..., H, W, 1]."""
    if coarse.shape[-3:-1] == (height, width):
        return coarse
    # coarse samples sit at the centres of stride x stride pixel blocks (align_corners=False)
    return bilinear_resize(coarse[..., 0], height, width)[..., None]


class CameraFrameDirections:
    """`ray_directions` of a camera at the origin, unrotated, per (intrinsics, size, stride), or what
    `derive` makes of them (a fixed function of the directions alone, e.g. the camera fall-off's basis):
    the last few are kept, as training and a viewer render the same ones again."""

    KEPT = 8

    def __init__(self, derive: Optional[Callable[[Tensor], Tensor]] = None) -> None:
        self.kept: Dict[tuple, Tensor] = {}
        self.derive = derive

    def __call__(self, K: Tensor, pinhole: Tuple[float, float, float, float], width: int, height: int, stride: int):
        """[h, w, 3] (or `derive`'s [h, w, ...]) for intrinsics `K` [3, 3] (`pinhole`: its fx, fy, cx,
        cy on the host)."""
        key = (pinhole, width, height, stride)
        cached = self.kept.pop(key, None)
        if cached is None:
            cached = ray_directions(K, torch.eye(3, 4, device=K.device), width, height, stride)
            if self.derive is not None:
                cached = self.derive(cached)
        self.kept[key] = cached  # the most recent last
        while len(self.kept) > self.KEPT:
            self.kept.pop(next(iter(self.kept)))
        return cached


class BackgroundGrid(nn.Module):
    """The background MLP over a training camera's encoded directions on the `background_stride`
    grid [h, w, E], upsampled to its frame [height, width, 1]: a piece of fixed shapes per frame size,
    which `GraphedCalls` records (the MLP is shared, not owned: this module is in no state dict)."""

    def __init__(self, mlp: BackgroundMLP, width: int, height: int):
        super().__init__()
        self.mlp, self.width, self.height = mlp, width, height

    def forward(self, encoded: Tensor, frame_embed: Tensor) -> Tensor:
        return upsampled(self.mlp.from_encoded(encoded, frame_embed), self.width, self.height)


class ThermalBackground:
    """The background behind the Gaussians, per pixel [H, W, 1]: the background MLP `mlp` (None: the
    constant `config.background_value`, or with `config.random_background` a uniform value drawn
    afresh at each training render), evaluated on the `config.background_stride` grid and upsampled.
    In training (and under autograd) the MLP runs on every grid point; a training camera whose pose
    is fixed (`cam_idx`) has its encoded directions computed once. Every other render samples the
    baked map (`baked_map`) along the camera-frame directions of its intrinsics, rotated. One method
    per render mode (`renders.py`)."""

    def __init__(self, mlp: Optional[BackgroundMLP], config):
        self.mlp = mlp
        self.config = config
        self.baked = BakedValues()
        self._encoded_directions: Dict[tuple, Tensor] = {}  # (training camera, width, height) -> encoded grid
        self._frame_directions = CameraFrameDirections()
        # training renders' MLP forward and backward replayed as CUDA graphs, one per frame size
        self.graphed = GraphedCalls("background MLP") if mlp is not None and config.graphed_background else None
        self._grids: Dict[Tuple[int, int], BackgroundGrid] = {}

    def baked_map(self, frame_embed: Tensor, step: int) -> Tensor:
        """The MLP over every direction under `frame_embed` (`background_map`), kept until the
        embedding or the MLP's parameters change (`BakedValues`; `step`: the training step)."""
        tensors = (*self.baked.parameters_of(self.mlp), frame_embed)
        return self.baked.get("background", tensors, step, lambda: background_map(self.mlp, frame_embed))

    def training(
        self,
        K: Tensor,
        camera_to_world: Tensor,
        frame_embed: Tensor,
        width: int,
        height: int,
        cam_idx: Optional[int] = None,
        slot: int = 0,
    ) -> Tensor:
        """[H, W, 1] of a training render with intrinsics `K` [3, 3] and pose `camera_to_world` [3, 4]: the MLP on
        every grid point (a training camera whose pose is fixed, `cam_idx`, has its encoded directions computed
        once), replayed as CUDA graphs where `graphed`; `slot`: the camera's place among a training step's cameras
        (`GraphedCalls`)."""
        if self.mlp is None:
            if self.config.random_background:
                return torch.rand(1, 1, 1, device=K.device).expand(height, width, 1)
            return torch.full((height, width, 1), self.config.background_value, device=K.device)
        return self._grid(K, camera_to_world, frame_embed, width, height, cam_idx, slot)

    def rendered(
        self,
        K: Tensor,
        camera_to_world: Tensor,
        frame_embed: Tensor,
        width: int,
        height: int,
        pinhole: Optional[Tuple[float, float, float, float]],
        step: int,
    ) -> Tensor:
        """[H, W, 1] of a render outside training and autograd: the baked map (`baked_map`) along the camera's pixel
        directions (`pinhole`: `K`'s fx, fy, cx, cy on the host, else read from `K`)."""
        if self.mlp is None:
            return torch.full((height, width, 1), self.config.background_value, device=K.device)
        dirs = self.frame_directions(K, width, height, pinhole)
        return self.from_map(self.baked_map(frame_embed, step), dirs, camera_to_world, width, height)

    def exact(self, K: Tensor, camera_to_world: Tensor, frame_embed: Tensor, width: int, height: int) -> Tensor:
        """[H, W, 1] of a render outside training under autograd (a fit through the render): the MLP itself on the
        grid, as in training."""
        if self.mlp is None:
            return torch.full((height, width, 1), self.config.background_value, device=K.device)
        return self._grid(K, camera_to_world, frame_embed, width, height, None, 0)

    def exact_views(self, Ks: Tensor, camera_to_worlds: Tensor, width: int, height: int) -> Callable[[Tensor], Tensor]:
        """`exact` of several cameras of one size (intrinsics [B, 3, 3], poses [B, 3, 4]) as one function of their
        frame embeddings [B, Df] -> [B, H, W, 1], for fits that move the states alone: their directions encoded
        once, the MLP called once for all of them per call."""
        if self.mlp is None:
            value = self.config.background_value
            return lambda embeds: torch.full((embeds.shape[0], height, width, 1), value, device=embeds.device)
        stride = self.config.background_stride
        encoded = torch.stack(
            [self.mlp.encode(ray_directions(K, c2w, width, height, stride)) for K, c2w in zip(Ks, camera_to_worlds)]
        )  # [B, h, w, E]

        return lambda embeds: upsampled(self.mlp.from_encoded(encoded, embeds), width, height)  # [B, H, W, 1]

    def viewing(self, view, frame_embed: Tensor, step: int, captured: CapturedCalls) -> Tuple[Tensor, Tensor]:
        """gsplat's view matrix [1, 4, 4] and the background [H, W, 1] of a render a user waits for
        (`renders.viewing_render`, a `camera_views.View`): one CUDA graph per camera size and intrinsics on a GPU
        (`captured`), the baked map one of its inputs, so a new state needs no new graph."""
        width, height = view.width, view.height
        key = ("view", width, height, view.pinhole)
        if self.mlp is None:  # a constant background
            value = self.config.background_value
            prepare = lambda camera_to_world, K: (
                world_to_camera(camera_to_world),
                torch.full((height, width, 1), value, device=K.device),
            )
            return captured(key, prepare, view.camera_to_world, view.K)

        baked = self.baked_map(frame_embed, step)
        frame_dirs = self.frame_directions(view.K[0], width, height, view.pinhole)

        def prepare(camera_to_world: Tensor, baked: Tensor, frame_dirs: Tensor) -> Tuple[Tensor, Tensor]:
            return world_to_camera(camera_to_world), self.from_map(baked, frame_dirs, camera_to_world[0], width, height)

        return captured(key, prepare, view.camera_to_world, baked, frame_dirs)

    def _grid(self, K, camera_to_world, frame_embed, width: int, height: int, cam_idx: Optional[int], slot: int):
        """The MLP over the `background_stride` grid of the camera's directions, upsampled [H, W, 1]."""
        key = (cam_idx, width, height)
        encoded = self._encoded_directions.get(key) if cam_idx is not None else None
        if encoded is None:
            dirs = ray_directions(K, camera_to_world, width, height, self.config.background_stride)  # [h, w, 3]
            encoded = self.mlp.encode(dirs)  # [h, w, E]
            if cam_idx is not None:
                self._encoded_directions[key] = encoded
        if self.graphed is None:
            return BackgroundGrid(self.mlp, width, height)(encoded, frame_embed)
        grid = self._grids.get((width, height))
        if grid is None:
            grid = self._grids[(width, height)] = BackgroundGrid(self.mlp, width, height)
        return self.graphed((width, height), grid, encoded, frame_embed, slot=slot)  # the same kernels, replayed

    def frame_directions(
        self, K: Tensor, width: int, height: int, pinhole: Optional[Tuple[float, float, float, float]] = None
    ) -> Tensor:
        """The unrotated pixel directions [h, w, 3] of intrinsics `K` [3, 3] on the background's grid
        (`CameraFrameDirections`); `pinhole`: `K`'s fx, fy, cx, cy on the host, else read from `K`."""
        if pinhole is None:
            pinhole = tuple(K[[0, 1, 0, 1], [0, 1, 2, 2]].tolist())  # fx, fy, cx, cy
        return self._frame_directions(K, pinhole, width, height, self.config.background_stride)

    @staticmethod
    def from_map(baked: Tensor, frame_dirs: Tensor, camera_to_world: Tensor, width: int, height: int) -> Tensor:
        """[H, W, 1]: the baked map `baked` (`baked_map`) along the pixel directions `frame_dirs`
        (`frame_directions`) turned to the pose `camera_to_world` [3, 4]."""
        sampled = sample_map(baked, frame_dirs @ camera_to_world[:3, :3].T)  # [h, w, 1]
        return upsampled(sampled, width, height)
