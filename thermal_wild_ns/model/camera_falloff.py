"""The camera's own radial fall-off (vignetting, the housing's warmth seen at the image edge): a
pattern fixed to the sensor, the same in every frame, that belongs to the camera and not to the scene.

A thermal core's frames are darker (or warmer) towards their corners: a real survey's frames,
each standardised and averaged over the flight, fall towards the corners in both halves of the
flight alike (`python -m experiments.camera_pattern`, docs/results/camera_falloff; a radial fall-off
is only part of a camera's fixed pattern). Without a model of it the Gaussians and the view-dependent
term have to absorb it as scene content: a point seen near the image edge in one frame and near its
centre in the next looks like a view effect, or gets a floater in front of it.

Here the camera's response is a gain and an offset, each a polynomial in the squared off-axis
tangent rho = ((u - cx) / fx)^2 + ((v - cy) / fy)^2 (zero at the principal point, so it cannot take
a frame's overall level or gain from the photometric state; independent of the render's resolution):

    recorded = (1 + sum_k g_k rho^k) * scene + sum_k o_k rho^k,   k = 1 .. FALLOFF_ORDER

The model fits (g, o) with the scene; the response is rendered into every image compared with a
recorded frame (the training loss, the held-back scores, the evaluation protocols) and left out of
the scene's renders (the viewer, `ns-render`, the survey exports): those show the scene, not the
lens."""

from __future__ import annotations

import torch
from torch import Tensor

FALLOFF_ORDER = 2
"""Powers of rho in the gain and in the offset (rho, rho^2): a smooth fall-off to the corners."""


def off_axis_squared(directions: Tensor) -> Tensor:
    """rho [H, W, 1], the squared tangent of each pixel's angle off the optical axis, from the camera's
    unit view directions in its own frame [H, W, 3] (`camera_views.ray_directions` without rotation,
    as `background.CameraFrameDirections` keeps them per camera and size)."""
    return directions[..., :2].square().sum(dim=-1, keepdim=True) / directions[..., 2:].square()


def apply_falloff(image: Tensor, coefficients: Tensor, rho: Tensor) -> Tensor:
    """`image` [H, W, 1] as the camera records it: the gain and offset polynomials of
    `coefficients` [2, FALLOFF_ORDER] (row 0 the gain's, row 1 the offset's) at `rho` [H, W, 1]."""
    powers = torch.cat([rho**k for k in range(1, coefficients.shape[1] + 1)], dim=-1)  # [H, W, K]
    gain = 1.0 + powers @ coefficients[0]  # [H, W]
    offset = powers @ coefficients[1]  # [H, W]
    return image * gain[..., None] + offset[..., None]


def describe_falloff(coefficients: Tensor) -> str:
    """The fitted response as a person reads it (the run's decisions), e.g. 'gain 1 -0.120 rho
    +0.010 rho^2, offset -0.050 rho +0.000 rho^2' (rho: the squared off-axis tangent)."""

    def polynomial(row: list) -> str:
        return " ".join(f"{c:+.3f} rho" + (f"^{k}" if k > 1 else "") for k, c in enumerate(row, start=1))

    gain, offset = coefficients.detach().cpu().tolist()
    return f"gain 1 {polynomial(gain)}, offset {polynomial(offset)}"
