"""The one seam between the model and a rasterizer."""

from __future__ import annotations

from typing import Dict, Literal, Optional, Tuple

import torch
from gsplat.rendering import rasterization as gsplat_rasterization
from torch import Tensor

from thermal_wild_ns._upstream import gsplat_render_one_view, gsplat_training_rasterization
from thermal_wild_ns.rendering.torch_rasterizer import rasterization as torch_rasterization

Backend = Literal["auto", "gsplat", "torch"]
NEAR_PLANE, FAR_PLANE = 0.01, 1e10
"""Every render's clipping planes (splatfacto's), in training and outside it."""


def resolve_backend(backend: Backend, device: torch.device) -> Literal["gsplat", "torch"]:
    """`auto` means gsplat's CUDA kernels on a CUDA device and the pure-torch rasterizer elsewhere."""
    if backend == "auto":
        return "gsplat" if device.type == "cuda" else "torch"
    if backend == "gsplat" and device.type != "cuda":
        raise ValueError(f"The gsplat backend needs CUDA tensors, got device {device}; use backend 'torch' or 'auto'.")
    return backend


def rasterization(*args, backend: Backend = "auto", **kwargs) -> Tuple[Tensor, Tensor, Dict]:
    """gsplat's `rasterization(means, quats, scales, opacities, colors, viewmats, Ks, width, height, ...)`.

    Arguments and returns are gsplat 1.4.0's; `backend` picks the implementation.
    """
    means = kwargs["means"] if "means" in kwargs else args[0]
    if resolve_backend(backend, means.device) == "gsplat":
        return gsplat_rasterization(*args, **kwargs)

    return torch_rasterization(*args, **kwargs)


def rasterize_unpacked(
    means: Tensor,  # [N, 3]
    quats: Tensor,  # [N, 4]
    scales: Tensor,  # [N, 3]
    opacities: Tensor,  # [N]
    colors: Tensor,  # [N, D] or [C, N, D]
    viewmats: Tensor,  # [C, 4, 4]
    Ks: Tensor,  # [C, 3, 3]
    width: int,
    height: int,
    with_depth: bool,
    absgrad: bool,
    rasterize_mode: Literal["classic", "antialiased"] = "classic",
    backend: Backend = "auto",
) -> Tuple[Tensor, Tensor, Dict]:
    """`rasterization` of C cameras on one GPU with autograd (`packed=False`, `sh_degree=None`, `NEAR_PLANE`,
    `FAR_PLANE`, render mode "RGB+ED" with the expected depth, else "RGB"): the render [C, H, W, D(+1)],
    alpha [C, H, W, 1] and meta of a training step (or of a render that is not a viewer's: `render_one_view`).
    On gsplat, its autograd functions and CUDA calls directly (`_upstream.gsplat_training_rasterization`): the
    same kernels with less host work, which is most of a training step's time."""
    inputs = (means, quats, scales, opacities, colors, viewmats, Ks, width, height)  # gsplat's, in its order
    if resolve_backend(backend, means.device) == "gsplat":
        antialiased = rasterize_mode == "antialiased"
        return gsplat_training_rasterization(*inputs, NEAR_PLANE, FAR_PLANE, antialiased, absgrad, with_depth)
    return torch_rasterization(
        *inputs,
        packed=False,
        near_plane=NEAR_PLANE,
        far_plane=FAR_PLANE,
        render_mode="RGB+ED" if with_depth else "RGB",
        sh_degree=None,
        absgrad=absgrad,
        rasterize_mode=rasterize_mode,
    )


def render_one_view(
    means: Tensor,  # [N, 3]
    quats: Tensor,  # [N, 4]
    scales: Tensor,  # [N, 3]
    opacities: Tensor,  # [N]
    colors: Tensor,  # [N, 1]
    viewmat: Tensor,  # [1, 4, 4]
    K: Tensor,  # [1, 3, 3]
    width: int,
    height: int,
    rasterize_mode: Literal["classic", "antialiased"] = "classic",
    backend: Backend = "auto",
) -> Tuple[Tensor, Tensor]:
    """A render outside autograd of one camera with its expected depth: `rasterization`'s render
    [1, H, W, 2] and alpha [1, H, W, 1] (`render_mode="RGB+ED"`, `packed=False`, `NEAR_PLANE`, `FAR_PLANE`).
    On gsplat, its CUDA functions called directly (`_upstream.gsplat_render_one_view`): the same kernels
    with less host work, which is most of the time of a frame the viewer or ns-render waits for."""
    inputs = (means, quats, scales, opacities, colors, viewmat, K, width, height)  # gsplat's, in its order
    if resolve_backend(backend, means.device) == "gsplat":
        return gsplat_render_one_view(*inputs, NEAR_PLANE, FAR_PLANE, rasterize_mode == "antialiased")
    render, alpha, _ = torch_rasterization(
        *inputs,
        packed=False,
        near_plane=NEAR_PLANE,
        far_plane=FAR_PLANE,
        render_mode="RGB+ED",
        rasterize_mode=rasterize_mode,
    )
    return render, alpha


def world_to_camera(camera_to_world: Tensor) -> Tensor:
    """gsplat's view matrices [C, 4, 4] (world to camera, OpenCV axes) from nerfstudio's
    camera-to-world poses [C, 3, 4] (OpenGL axes: y up, z back). The same as splatfacto's
    `get_viewmat`, without its `torch.compile` (which on a CPU compiles C++ at the first call)."""
    # y and z flipped by negation, not by a product with a constant built from a Python list: that
    # would be a host-to-device copy (and a sync) per render
    R = torch.cat([camera_to_world[:, :3, :1], -camera_to_world[:, :3, 1:3]], dim=2)  # [C, 3, 3]
    t = camera_to_world[:, :3, 3:4]  # [C, 3, 1]
    viewmat = torch.zeros(camera_to_world.shape[0], 4, 4, device=camera_to_world.device, dtype=camera_to_world.dtype)
    viewmat[:, :3, :3] = R.transpose(1, 2)
    viewmat[:, :3, 3:4] = -R.transpose(1, 2) @ t
    viewmat[:, 3, 3] = 1.0
    return viewmat


def activated(params: Dict[str, Tensor], ids: Optional[Tensor] = None) -> Tuple[Tensor, Tensor]:
    """gsplat's scales [N, 3] and opacities [N] of every (or the selected `ids`) Gaussian of `params` (log scales,
    logit opacities)."""
    scales, opacities = params["scales"], params["opacities"]
    if ids is not None:
        scales, opacities = scales[ids], opacities[ids]
    return torch.exp(scales), torch.sigmoid(opacities).squeeze(-1)


def rasterize_gaussians(
    params: Dict[str, Tensor],
    colors: Tensor,  # [N, D] or [C, N, D]
    viewmats: Tensor,  # [C, 4, 4]
    Ks: Tensor,  # [C, 3, 3]
    width: int,
    height: int,
    ids: Optional[Tensor],
    with_depth: bool,
    absgrad: bool,
    rasterize_mode: Literal["classic", "antialiased"],
    backend: Backend,
    distributed: bool,
) -> Tuple[Tensor, Tensor, Dict]:
    """The render [C, H, W, D(+1)], alpha [C, H, W, 1] and meta of every (or the selected `ids`) Gaussian of
    `params` (means, quats, log scales, logit opacities) with `colors` in the C cameras: on one GPU its kernels
    with the least host work around them (`rasterize_unpacked`), with the Gaussians split across GPUs gsplat's
    distributed rasterization (packed: only the visible splats travel)."""
    crop = lambda x: x if ids is None else x[ids]
    scales, opacities = activated(params, ids)  # [N, 3], [N]
    means, quats = crop(params["means"]), crop(params["quats"])  # quats: normalised by the projection
    if not distributed:
        args = (means, quats, scales, opacities, colors, viewmats, Ks, width, height, with_depth, absgrad)
        return rasterize_unpacked(*args, rasterize_mode, backend)
    return rasterization(
        means=means,
        quats=quats,
        scales=scales,
        opacities=opacities,
        colors=colors,
        viewmats=viewmats,
        Ks=Ks,
        width=width,
        height=height,
        packed=True,
        near_plane=NEAR_PLANE,
        far_plane=FAR_PLANE,
        render_mode="RGB+ED" if with_depth else "RGB",
        sh_degree=None,
        sparse_grad=False,
        absgrad=absgrad,
        rasterize_mode=rasterize_mode,
        distributed=True,
        backend=backend,
    )
