"""The one seam between the model and a rasterizer."""

from __future__ import annotations

from typing import Dict, Literal, Tuple

import torch
from torch import Tensor

Backend = Literal["auto", "gsplat", "torch"]


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
        from gsplat.rendering import rasterization as gsplat_rasterization

        return gsplat_rasterization(*args, **kwargs)
    from thermal_wild_ns.rendering.torch_rasterizer import rasterization as torch_rasterization

    return torch_rasterization(*args, **kwargs)
