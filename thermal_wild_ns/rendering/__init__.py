"""Rendering backends behind one seam: `rasterization` has gsplat's signature and picks gsplat's
CUDA kernels for CUDA tensors and the pure-PyTorch twin otherwise."""

from thermal_wild_ns.rendering.backend import Backend, rasterization, render_one_view, resolve_backend, world_to_camera

__all__ = ["Backend", "rasterization", "render_one_view", "resolve_backend", "world_to_camera"]
