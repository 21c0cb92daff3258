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

On top of it, optionally, a flat-field map: a gain and an offset per cell of an n x n grid laid
over the image, bilinear between cell centres, each made zero-mean (so it too cannot take a frame's
overall level or gain): the part of the camera's fixed pattern that is not radial (an off-centre
fall-off, a shutter's or the housing's uneven warmth).

The model fits (g, o) (and the map) with the scene; the response is rendered into every image compared with a
recorded frame (the training loss, the held-back scores, the evaluation protocols) and left out of
the scene's renders (the viewer, `ns-render`, the survey exports): those show the scene, not the
lens."""

from __future__ import annotations

from typing import Optional

import torch
from torch import Tensor

from thermal_wild_ns.model.bilinear import bilinear_resize

FALLOFF_ORDER = 2
"""Powers of rho in the gain and in the offset (rho, rho^2): a smooth fall-off to the corners."""


def off_axis_squared(directions: Tensor) -> Tensor:
    """rho [H, W, 1], the squared tangent of each pixel's angle off the optical axis, from the camera's
    unit view directions in its own frame [H, W, 3] (`camera_views.ray_directions` without rotation,
    as `background.CameraFrameDirections` keeps them per camera and size)."""
    return directions[..., :2].square().sum(dim=-1, keepdim=True) / directions[..., 2:].square()


def centred_cells(cells: Tensor) -> Tensor:
    """The flat-field cells [2, n, n] less each row's mean: the map never holds an overall level or gain."""
    return cells - cells.mean(dim=(1, 2), keepdim=True)


def flat_field_maps(cells: Tensor, height: int, width: int) -> Tensor:
    """The flat-field map's gain and offset [2, H, W] at every pixel of a height x width image, from
    its cells [2, n, n] (row 0 the gain's, row 1 the offset's), each made zero-mean, bilinear between
    cell centres: the same places of the sensor at any render resolution."""
    return bilinear_resize(centred_cells(cells), height, width)


def falloff_basis(directions: Tensor, order: int = FALLOFF_ORDER) -> Tensor:
    """rho, rho^2, ... [H, W, order] at each pixel, from the camera's unit view directions in its own
    frame [H, W, 3]: what the gain's and the offset's polynomials weigh. A fixed function of the camera
    and the render size, kept with them (`background.CameraFrameDirections(derive=falloff_basis)`)."""
    rho = off_axis_squared(directions)  # [H, W, 1]
    return torch.cat([rho**k for k in range(1, order + 1)], dim=-1)


def respond(image: Tensor, coefficients: Tensor, basis: Tensor, flat_field: Optional[Tensor] = None) -> Tensor:
    """`image` [H, W, 1] as the camera records it: gain (1 + the gain's polynomial) times the image plus
    the offset's polynomial, at each pixel's `basis` [H, W, K] (`falloff_basis`) with `coefficients`
    [2, K] (row 0 the gain's, row 1 the offset's), plus the flat-field map of `flat_field` [2, n, n]
    where given (`flat_field_maps`). Few operations: it runs at every training step."""
    return through_terms(image, response_terms(coefficients, basis, flat_field))


def response_terms(coefficients: Tensor, basis: Tensor, flat_field: Optional[Tensor] = None) -> Tensor:
    """The response's gain (less 1) and offset at each pixel [H, W, 2] (`respond`), a function of the camera, the
    render size and the response's parameters alone: made once where those stay fixed (`through_terms`)."""
    terms = basis @ coefficients.T  # [H, W, 2]: the gain's and the offset's polynomial
    if flat_field is not None:
        terms = terms + flat_field_maps(flat_field, basis.shape[0], basis.shape[1]).permute(1, 2, 0)
    return terms


def through_terms(image: Tensor, terms: Tensor) -> Tensor:
    """`image` [..., H, W, 1] through the response's `terms` [..., H, W, 2] (`response_terms`)."""
    return torch.addcmul(terms[..., 1:], image, terms[..., :1] + 1.0)


def describe_falloff(coefficients: Tensor) -> str:
    """The fitted radial response as a person reads it (the run's decisions), e.g. 'gain 1 -0.120 rho
    +0.010 rho^2, offset -0.050 rho +0.000 rho^2' (rho: the squared off-axis tangent)."""

    def polynomial(row: list) -> str:
        return " ".join(f"{c:+.3f} rho" + (f"^{k}" if k > 1 else "") for k, c in enumerate(row, start=1))

    gain, offset = coefficients.detach().cpu().tolist()
    return f"gain 1 {polynomial(gain)}, offset {polynomial(offset)}"


def describe_flat_field(flat_field: Tensor) -> str:
    """The fitted flat-field map [2, n, n] as a person reads it, e.g. '8x8: gain +-0.031, offset +-0.012'
    (the largest deviation of a cell from the map's mean)."""
    spread = centred_cells(flat_field.detach()).abs().amax(dim=(1, 2)).tolist()
    return f"{'x'.join(map(str, flat_field.shape[1:]))}: gain +-{spread[0]:.3f}, offset +-{spread[1]:.3f}"
