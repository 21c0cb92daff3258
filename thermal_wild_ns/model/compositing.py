"""A render's last step: gsplat's premultiplied emission and alpha over the background, and the outputs a
render hands nerfstudio (`thermal_outputs`)."""

from __future__ import annotations

from typing import Dict, Optional, Tuple

import torch
from nerfstudio.utils.rich_utils import CONSOLE
from torch import Tensor

from thermal_wild_ns.rendering.viewer_controls import thermal_rgb


def camera_planes(render: Tensor, alpha: Tensor, camera: int = 0) -> Tuple[Tensor, Tensor, Optional[Tensor]]:
    """Camera `camera` of gsplat's render [C, H, W, 1(+1)] and alpha [C, H, W, 1]: its emission [H, W, 1]
    (premultiplied), alpha [H, W, 1] and depth [H, W, 1] (the farthest rendered depth where nothing was
    drawn) or None."""
    # one camera's render as views autograd undoes as views (a squeeze; the whole last axis): an indexing
    # view's backward (a select's, a slice's) fills a zero tensor and copies into it, kernels and host
    # operations at every training step
    if render.shape[0] == 1:
        render, alpha = render.squeeze(0), alpha.squeeze(0)
    else:
        render, alpha = render[camera], alpha[camera]
    emission = render if render.shape[-1] == 1 else render[..., :1]
    depth = None
    if render.shape[-1] > 1:
        depth = render[..., 1:2]
        depth = torch.where(alpha > 0, depth, depth.detach().max())
    return emission, alpha, depth


def over_background(emission: Tensor, alpha: Tensor, background: Tensor) -> Tensor:
    """The premultiplied `emission` [H, W, 1] of a render of `alpha` [H, W, 1] over `background` [H, W, 1]."""
    return emission + (1.0 - alpha) * background


def composite(
    render: Tensor, alpha: Tensor, background: Tensor, camera: int = 0
) -> Tuple[Tensor, Tensor, Optional[Tensor]]:
    """Camera `camera` of gsplat's render [C, H, W, 1(+1)] (emission, and depth where asked) with its alpha
    [C, H, W, 1] over `background` [H, W, 1]: the thermal image (premultiplied render over the background),
    the alpha [H, W, 1] and the depth [H, W, 1] (the farthest rendered depth where nothing was drawn) or None."""
    emission, alpha, depth = camera_planes(render, alpha, camera)
    return over_background(emission, alpha, background), alpha, depth


def thermal_outputs(
    thermal: Tensor,
    alpha: Tensor,
    background: Tensor,
    depth: Optional[Tensor],
    colormap: Optional[str],
    rgb: Optional[Tensor] = None,
) -> Dict:
    """The outputs of a render: `rgb` as given (coloured already), else the thermal image [H, W, 1] through
    `colormap` (viewer, ns-render), or with none (training: nothing reads it) the render itself as grey,
    unclipped (views alone, no kernel)."""
    if rgb is None and colormap is None:
        rgb = thermal.detach().expand(-1, -1, 3)  # [H, W, 3]
    elif rgb is None:
        rgb = thermal_rgb(thermal, colormap)  # [H, W, 3]
    return {  # rgb first: the viewer shows the first output by default
        "rgb": rgb,
        "thermal": thermal,  # [H, W, 1], normalised dataset units (training space)
        "accumulation": alpha,
        "background": background,
        "depth": depth,
    }


def coloured_outputs(thermal: Tensor, alpha: Tensor, background: Tensor, depth: Tensor, colormap: str) -> Tensor:
    """A render outside training as one tensor [H, W, 7]: rgb through `colormap`, thermal, alpha, background,
    depth (what one CUDA graph finishes a viewer's frame with, copied out in one piece)."""
    return torch.cat([thermal_rgb(thermal, colormap), thermal, alpha, background, depth], -1)


def unpacked_outputs(packed: Tensor) -> Dict:
    """`thermal_outputs` of a `coloured_outputs` tensor [H, W, 7] (views of it)."""
    return thermal_outputs(
        packed[..., 3:4], packed[..., 4:5], packed[..., 5:6], packed[..., 6:7], None, packed[..., :3]
    )


def background_only(background: Tensor, colormap: str) -> Dict:
    """The outputs of a model with no Gaussian to render (pruned away, or none in the crop box)."""
    CONSOLE.log("[yellow]WildThermalModel: no Gaussians to render; returning the background only.")
    background = background.clone()  # a CUDA graph's buffer until its next replay
    return thermal_outputs(background, torch.zeros_like(background), background, None, colormap)


def rendered_outputs(render: Optional[Tensor], alpha: Optional[Tensor], background: Tensor, colormap: str) -> Dict:
    """The outputs of a render outside training: gsplat's render [1, H, W, 2] and alpha [1, H, W, 1] over the
    `background` [H, W, 1]; `render` None where there was nothing to render (no Gaussian, or none in the crop box):
    the background alone."""
    if render is None:
        return background_only(background, colormap)
    thermal, alpha, depth = composite(render, alpha, background)
    return thermal_outputs(thermal, alpha, background, depth, colormap)
