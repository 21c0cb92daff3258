"""A view-dependent term of the scalar emission: per-Gaussian spherical-harmonic coefficients of the
bands above the constant one, evaluated along the direction from the camera to the Gaussian.

On a thermal survey the radiance reaching the camera changes with the view: emissivity falls as the
angle from the surface normal grows, and surfaces reflect the cold sky, more at grazing angles. The
term is per Gaussian and the same at every capture time, so it can only explain what changes with
direction; what changes over time stays the frame embeddings' (the `time` protocol stays honest). Its
average over all directions is zero (every band above the constant one integrates to zero), so the
emission without it (exports, the splat PLY) is the direction-averaged emission.
Constants and sign conventions are gsplat 1.4.0's (`gsplat.cuda._torch_impl._eval_sh_bases_fast`)."""

from __future__ import annotations

import torch
from torch import Tensor

from thermal_wild_ns.image_metrics import radial_fit, squared_centre_distance

SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)


def view_coefficients(degree: int) -> int:
    """Coefficients per Gaussian of the bands 1..`degree` ((degree + 1)^2 - 1): 3 for degree 1, 8 for 2."""
    if degree not in (0, 1, 2):
        raise ValueError(f"view_sh_degree must be 0, 1 or 2, got {degree}")
    return (degree + 1) ** 2 - 1


def sh_bands(dirs: Tensor, degree: int) -> Tensor:
    """Spherical-harmonic basis of bands 1..`degree` along unit directions [N, 3] -> [N, K]."""
    x, y, z = dirs.unbind(-1)  # [N] each
    bands = [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        bands += [
            SH_C2[0] * x * y,
            SH_C2[1] * y * z,
            SH_C2[2] * (2.0 * zz - xx - yy),
            SH_C2[3] * x * z,
            SH_C2[4] * (xx - yy),
        ]
    return torch.stack(bands, dim=-1)


def view_term(means: Tensor, coefficients: Tensor, camera_position: Tensor) -> Tensor:
    """The view-dependent emission [N, 1] of Gaussians at `means` [N, 3] with band coefficients [N, K]
    seen from `camera_position` [3] (or [N, 3]: each Gaussian from its own camera)."""
    degree = {3: 1, 8: 2}[coefficients.shape[-1]]
    dirs = torch.nn.functional.normalize(means - camera_position, dim=-1)  # [N, 3]
    return (sh_bands(dirs, degree) * coefficients).sum(dim=-1, keepdim=True)  # [N, 1]


def radial_part(term: Tensor, emission: Tensor, centres: Tensor, width: int, height: int) -> Tensor:
    """The mean square of the part of the visible Gaussians' view term `term` [M, 1] that one camera
    response explains in this view (`radial_fit`, with their `emission` [M, 1] and the r^2 of their
    projected centres `centres` [M, 2], pixels of a width x height image: `squared_centre_distance`). A
    loss on it pushes what every view shares radially to the camera model and leaves the term what
    follows surfaces."""
    u, v = centres.detach().split(1, dim=-1)  # [M, 1] each
    r2 = squared_centre_distance(u, v, width, height)  # [M, 1]
    return radial_fit(term, emission, r2).square().mean()


def visible_radial_part(
    means: Tensor, coefficients: Tensor, info: dict, colors: Tensor, camera_position: Tensor, size: tuple, c: int
) -> Tensor:
    """`radial_part` of camera `c` of a training render (gsplat's `info`; the camera at `camera_position` [3], its
    image `size` (width, height)) over the Gaussians it draws (`means` [N, 3], view-term `coefficients` [N, K],
    radiance `colors` [N, 1] in that camera)."""
    visible = info["radii"][c].reshape(means.shape[0], -1).amax(-1) > 0  # [N]
    return radial_part(
        view_term(means[visible], coefficients[visible], camera_position),  # [M, 1]
        colors[visible].detach(),  # [M, 1]
        info["means2d"][c][visible],  # [M, 2]
        *size,
    )
