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


def keep(kept: Dict, key, value, most: int) -> None:
    """`kept[key] = value` as the most recent entry, the oldest dropped past `most` (`kept.pop(key)` first
    where a looked-up entry stays)."""
    kept[key] = value
    while len(kept) > most:
        kept.pop(next(iter(kept)))


class CameraSizes:
    """`host_sizes` of the cameras a render outside training gets, read once per camera batch: ns-render
    hands the model slices of one batch on the GPU (`cameras[i : i + 1]`), whose fields are views of the
    batch's storage. Reading a GPU tensor waits for every kernel queued before it, so a read per frame
    made the host wait for the last frame before queueing the next; the batch's six fields are read
    whole on its first frame and each slice's values picked by its offset. Kept by storage (held, so
    its address is not reused while kept) and version (a batch written in place is read again)."""

    KEPT = 8

    def __init__(self) -> None:
        self.kept: Dict[tuple, tuple] = {}  # storage addresses -> (storages, versions, their values on the host)

    def __call__(self, camera: Cameras) -> Tuple[float, float, Tuple[float, float, float, float]]:
        fields = (camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy)
        if any(field.numel() != 1 or field.is_inference() for field in fields):  # inference tensors keep no version
            return host_sizes(camera)
        storages = [field.untyped_storage() for field in fields]
        key = tuple(storage.data_ptr() for storage in storages)
        versions = tuple(field._version for field in fields)
        entry = self.kept.pop(key, None)
        if entry is None or entry[1] != versions:
            whole = [  # each storage as its field's dtype, in float64: exact for int64 sizes and float32 values
                field.new_empty(0).set_(storage, 0, (storage.nbytes() // field.element_size(),)).double()
                for field, storage in zip(fields, storages)
            ]
            values = torch.cat(whole).tolist()  # the one transfer
            starts = [0]
            for part in whole[:-1]:
                starts.append(starts[-1] + part.numel())
            entry = (storages, versions, values, starts)
        keep(self.kept, key, entry, self.KEPT)
        values, starts = entry[2], entry[3]
        width, height, *pinhole = (values[start + field.storage_offset()] for field, start in zip(fields, starts))
        return width, height, tuple(pinhole)


class ViewingViews:
    """The views of renders outside training (full resolution, any pose), whose view matrix their
    caller computes (`View.viewmat` None): the intrinsics [1, 3, 3] kept per (fx, fy, cx, cy), built
    from the values read to the host anyway (`CameraSizes`), as a viewer renders with the same few again."""

    KEPT = 8

    def __init__(self) -> None:
        self.kept: Dict[tuple, Tensor] = {}
        self.sizes = CameraSizes()

    def get(self, camera: Cameras, device) -> View:
        width, height, pinhole = self.sizes(camera)
        K = self.kept.pop(pinhole, None)
        if K is None:  # the values `intrinsics` stacks, from the same float32 numbers
            fx, fy, cx, cy = pinhole
            K = torch.tensor([[[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]], dtype=camera.fx.dtype, device=device)
        keep(self.kept, pinhole, K, self.KEPT)
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
