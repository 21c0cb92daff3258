"""Rendering backends behind one seam: `rasterization` has gsplat's signature and picks gsplat's
CUDA kernels for CUDA tensors and the pure-PyTorch twin otherwise."""

from thermal_wild_ns.rendering.backend import (
    FAR_PLANE,
    NEAR_PLANE,
    Backend,
    activated,
    rasterization,
    rasterize_gaussians,
    rasterize_unpacked,
    render_one_view,
    resolve_backend,
    world_to_camera,
)

__all__ = [
    "FAR_PLANE",
    "NEAR_PLANE",
    "Backend",
    "activated",
    "rasterization",
    "rasterize_gaussians",
    "rasterize_unpacked",
    "render_one_view",
    "resolve_backend",
    "world_to_camera",
]
