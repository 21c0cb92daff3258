"""A render's camera as gsplat takes it, and the view directions of its pixels."""

from __future__ import annotations

from typing import Callable, Dict, NamedTuple, Optional, Tuple

import torch
from nerfstudio.cameras.cameras import Cameras
from torch import Tensor

from thermal_wild_ns.rendering import world_to_camera


class View(NamedTuple):
    """A render's camera, on the model's device, at the resolution it renders."""

    camera_to_world: Tensor  # [1, 3, 4]
    viewmat: Optional[Tensor]  # [1, 4, 4], gsplat's world-to-camera (None: its caller computes it)
    K: Tensor  # [1, 3, 3]
    width: int
    height: int
    pinhole: Tuple[float, float, float, float]  # K's fx, fy, cx, cy, on the host


def intrinsics(camera: Cameras, factor: float = 1.0) -> Tensor:
    """Pinhole intrinsics [C, 3, 3] of the camera's images resized by `factor`, built on the
    camera's device (nerfstudio's `get_intrinsics_matrices` builds them on the host: one GPU
    round trip per entry)."""
    fx, fy, cx, cy = (camera.fx.reshape(-1), camera.fy.reshape(-1), camera.cx.reshape(-1), camera.cy.reshape(-1))
    if factor != 1.0:
        fx, fy, cx, cy = fx * factor, fy * factor, cx * factor, cy * factor
    zero, one = torch.zeros_like(fx), torch.ones_like(fx)
    return torch.stack([fx, zero, cx, zero, fy, cy, zero, zero, one], dim=-1).reshape(-1, 3, 3)


def make_view(camera: Cameras, camera_to_world: Tensor, scale: int, device) -> View:
    """`camera` posed at `camera_to_world` [1, 3, 4], at 1/`scale` of its resolution, on `device`
    (as nerfstudio's `Cameras.rescale_output_resolution`: intrinsics times the factor, sizes floored)."""
    camera_to_world = camera_to_world.to(device)
    factor = 1.0 / scale
    width, height, pinhole = host_sizes(camera)
    return View(
        camera_to_world,
        world_to_camera(camera_to_world),
        intrinsics(camera, factor).to(device),
        int(width * factor),
        int(height * factor),
        tuple(value * factor for value in pinhole),
    )


def host_sizes(camera: Cameras) -> Tuple[float, float, Tuple[float, float, float, float]]:
    """The camera's width, height and (fx, fy, cx, cy), read to the host in one transfer."""
    sizes = (camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy)
    width, height, *pinhole = torch.cat([v.reshape(-1) for v in sizes]).tolist()
    return width, height, tuple(pinhole)


class ViewingViews:
    """The views of renders outside training (full resolution, any pose), whose view matrix their
    caller computes (`View.viewmat` None): the intrinsics [1, 3, 3] kept per (fx, fy, cx, cy), built
    from the values read to the host anyway, as a viewer renders with the same few again."""

    KEPT = 8

    def __init__(self) -> None:
        self.kept: Dict[tuple, Tensor] = {}

    def get(self, camera: Cameras, device) -> View:
        width, height, pinhole = host_sizes(camera)
        K = self.kept.pop(pinhole, None)
        if K is None:  # the values `intrinsics` stacks, from the same float32 numbers
            fx, fy, cx, cy = pinhole
            K = torch.tensor([[[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]], dtype=camera.fx.dtype, device=device)
        self.kept[pinhole] = K  # the most recent last
        while len(self.kept) > self.KEPT:
            self.kept.pop(next(iter(self.kept)))
        return View(camera.camera_to_worlds.to(device), None, K, int(width), int(height), pinhole)


def ray_directions(K: Tensor, camera_to_world: Tensor, width: int, height: int, stride: int = 1) -> Tensor:
    """Unit world-space view directions (nerfstudio/OpenGL axes) at the pixel centres of the image
    downsampled by `stride` [ceil(H / stride), ceil(W / stride), 3]; K [3, 3] and camera_to_world
    [3, 4] at full resolution."""
    device = camera_to_world.device
    h, w = -(-height // stride), -(-width // stride)
    v, u = torch.meshgrid(
        (torch.arange(h, device=device, dtype=torch.float32) + 0.5) * (height / h),
        (torch.arange(w, device=device, dtype=torch.float32) + 0.5) * (width / w),
        indexing="ij",
    )
    dirs = torch.stack([(u - K[0, 2]) / K[0, 0], -(v - K[1, 2]) / K[1, 1], -torch.ones_like(u)], -1)
    dirs = dirs @ camera_to_world[:3, :3].T  # [h, w, 3]
    return dirs / dirs.norm(dim=-1, keepdim=True)


class TrainingViews:
    """`make_view` of each render, kept for a training camera whose pose is fixed (`cam_idx`) per
    downscale: its view never changes. The camera object is left as it is (a datamanager may hand the
    same one again)."""

    def __init__(self) -> None:
        self.kept: Dict[tuple, View] = {}  # (training camera, downscale) -> its view

    def get(
        self, camera: Cameras, camera_to_world: Callable[[], Tensor], scale: int, device, cam_idx: Optional[int]
    ) -> View:
        """The view of `camera` at 1/`scale` of its resolution; `camera_to_world()` gives its pose [1, 3, 4]."""
        key = (cam_idx, scale)
        if cam_idx is not None and key in self.kept:
            return self.kept[key]
        view = make_view(camera, camera_to_world(), scale, device)
        if cam_idx is not None:
            self.kept[key] = view
        return view
