"""gsplat's CUDA functions called directly (its internals): a render a user waits for and a training step's
rasterization (the package's docstring says how each patch is kept)."""

from __future__ import annotations

from typing import Dict, Tuple

import torch
from gsplat.cuda._wrapper import _FullyFusedProjection, _make_lazy_cuda_func, _make_lazy_cuda_obj, _RasterizeToPixels


def gsplat_render_one_view(
    means: torch.Tensor,  # [N, 3]
    quats: torch.Tensor,  # [N, 4]
    scales: torch.Tensor,  # [N, 3]
    opacities: torch.Tensor,  # [N]
    colors: torch.Tensor,  # [N, 1]
    viewmat: torch.Tensor,  # [1, 4, 4]
    K: torch.Tensor,  # [1, 3, 3]
    width: int,
    height: int,
    near_plane: float,
    far_plane: float,
    antialiased: bool,
) -> Tuple[torch.Tensor, torch.Tensor]:
    """gsplat 1.4.0's `rasterization(means, quats, scales, opacities, colors, viewmat, K, width, height,
    near_plane, far_plane, packed=False, render_mode="RGB+ED", sh_degree=None, rasterize_mode=
    "antialiased" if antialiased else "classic")` of one camera, outside autograd: the four CUDA functions
    it calls, in its order, on the same inputs, without its argument checks, its metadata, its autograd
    wrappers and its copy of the opacities per camera. A render a user waits for (the viewer, ns-render)
    spends most of its time on the host; these are the same kernels. Returns its render [1, H, W, 2]
    (emission, expected depth) and alpha [1, H, W, 1]. Checked against gsplat 1.4.0 (`_wrapper.py`'s
    `fully_fused_projection`, `isect_tiles`, `isect_offset_encode`, `rasterize_to_pixels`, `rendering.py`'s
    `rasterization`); `tests/test_gpu_parity.py` compares the two on the GPU."""
    tile_size = 16
    radii, means2d, depths, conics, compensations = _make_lazy_cuda_func("fully_fused_projection_fwd")(
        means.contiguous(),
        None,  # covariances: from quats and scales
        quats.contiguous(),
        scales.contiguous(),
        viewmat.contiguous(),
        K.contiguous(),
        width,
        height,
        0.3,  # eps2d, gsplat's default
        near_plane,
        far_plane,
        0.0,  # radius clip, gsplat's default
        antialiased,  # compensations
        _make_lazy_cuda_obj("CameraModelType.PINHOLE"),
    )  # [1, N], [1, N, 2], [1, N], [1, N, 3], [1, N]
    opacities = opacities[None] * compensations if antialiased else opacities[None]  # [1, N]
    colors = torch.cat((colors[None], depths[..., None]), dim=-1)  # [1, N, 2]
    tile_width, tile_height = -(-width // tile_size), -(-height // tile_size)
    _, isect_ids, flatten_ids = _make_lazy_cuda_func("isect_tiles")(
        means2d, radii, depths, None, None, 1, tile_size, tile_width, tile_height, True, True
    )  # sorted, with radix sort's double buffer, as gsplat's `isect_tiles`
    offsets = _make_lazy_cuda_func("isect_offset_encode")(isect_ids, 1, tile_width, tile_height)  # [1, th, tw]
    render, alpha, _ = _make_lazy_cuda_func("rasterize_to_pixels_fwd")(
        means2d, conics, colors, opacities.contiguous(), None, None, width, height, tile_size, offsets, flatten_ids
    )  # [1, H, W, 2], [1, H, W, 1]
    return torch.cat((render[..., :-1], render[..., -1:] / alpha.clamp(min=1e-10)), dim=-1), alpha


GSPLAT_CHANNELS = frozenset((1, 2, 3, 4, 5, 8, 9, 16, 17, 32, 33, 64, 65, 128, 129, 256, 257, 512, 513))
"""The channel counts gsplat 1.4.0's rasterization kernels are built for (`rasterize_to_pixels` pads others)."""


def gsplat_training_rasterization(
    means: torch.Tensor,  # [N, 3]
    quats: torch.Tensor,  # [N, 4]
    scales: torch.Tensor,  # [N, 3]
    opacities: torch.Tensor,  # [N]
    colors: torch.Tensor,  # [N, D] or [C, N, D]
    viewmats: torch.Tensor,  # [C, 4, 4]
    Ks: torch.Tensor,  # [C, 3, 3]
    width: int,
    height: int,
    near_plane: float,
    far_plane: float,
    antialiased: bool,
    absgrad: bool,
    with_depth: bool,
) -> Tuple[torch.Tensor, torch.Tensor, Dict]:
    """gsplat 1.4.0's `rasterization(means, quats, scales, opacities, colors, viewmats, Ks, width, height,
    near_plane, far_plane, packed=False, sparse_grad=False, sh_degree=None, absgrad=absgrad, render_mode=
    "RGB+ED" if with_depth else "RGB", rasterize_mode="antialiased" if antialiased else "classic")` with
    autograd, for a training step on one GPU: its autograd functions and CUDA calls in its order, on the
    same inputs, without its argument checks, its wrappers' checks and copies of tensors already
    contiguous, and (one camera) its copy of the opacities, whose gradient is then the same values without
    the sum over one camera. The same kernels, so the same render, alpha, gradients and `meta` (the keys the
    densification reads); a training step spends most of its time on the host. Checked against gsplat
    1.4.0 (`rendering.py`'s `rasterization`, `_wrapper.py`'s `fully_fused_projection`, `isect_tiles`,
    `isect_offset_encode`, `rasterize_to_pixels`); `tests/test_gpu_parity.py` compares the two, gradients
    included. Returns the render [C, H, W, D(+1)], alpha [C, H, W, 1] and gsplat's `meta`."""
    C = viewmats.shape[0]
    channels = colors.shape[-1] + (1 if with_depth else 0)
    if channels not in GSPLAT_CHANNELS:
        raise ValueError(f"gsplat's kernels take {sorted(GSPLAT_CHANNELS)} channels, not {channels}")
    tile_size = 16
    radii, means2d, depths, conics, compensations = _FullyFusedProjection.apply(
        means.contiguous(),
        None,  # covariances: from quats and scales
        quats.contiguous(),
        scales.contiguous(),
        viewmats.contiguous(),
        Ks.contiguous(),
        width,
        height,
        0.3,  # eps2d, gsplat's default
        near_plane,
        far_plane,
        0.0,  # radius clip, gsplat's default
        antialiased,  # compensations
        "pinhole",
    )  # [C, N], [C, N, 2], [C, N], [C, N, 3], [C, N] or None
    opacities = opacities[None] if C == 1 else opacities.repeat(C, 1)  # [C, N]
    if compensations is not None:
        opacities = opacities * compensations
    if colors.dim() == 2:
        colors = colors.expand(C, -1, -1)  # [C, N, D]
    if with_depth:
        colors = torch.cat((colors, depths[..., None]), dim=-1)  # [C, N, D + 1]
    tile_width, tile_height = -(-width // tile_size), -(-height // tile_size)
    tiles_per_gauss, isect_ids, flatten_ids = _make_lazy_cuda_func("isect_tiles")(
        means2d, radii, depths, None, None, C, tile_size, tile_width, tile_height, True, True
    )  # sorted, with radix sort's double buffer, as gsplat's `isect_tiles`
    offsets = _make_lazy_cuda_func("isect_offset_encode")(isect_ids, C, tile_width, tile_height)  # [C, th, tw]
    render, alpha = _RasterizeToPixels.apply(
        means2d,
        conics,
        colors.contiguous(),
        opacities.contiguous(),
        None,  # backgrounds
        None,  # masks
        width,
        height,
        tile_size,
        offsets,
        flatten_ids,
        absgrad,
    )  # [C, H, W, channels], [C, H, W, 1]
    if with_depth:
        render = torch.cat((render[..., :-1], render[..., -1:] / alpha.clamp(min=1e-10)), dim=-1)
    meta = {
        "camera_ids": None,
        "gaussian_ids": None,
        "radii": radii,
        "means2d": means2d,
        "depths": depths,
        "conics": conics,
        "opacities": opacities,
        "tile_width": tile_width,
        "tile_height": tile_height,
        "tiles_per_gauss": tiles_per_gauss,
        "isect_ids": isect_ids,
        "flatten_ids": flatten_ids,
        "isect_offsets": offsets,
        "width": width,
        "height": height,
        "tile_size": tile_size,
        "n_cameras": C,
    }
    return render, alpha, meta
