"""Image metrics of single-channel images ([H, W, 1] tensors): what training logs, the evaluation
protocols score and the heat-aware SSIM builds on; and the fit of a camera's radial response that the view
term's rule and its penalty measure against (`radial_fit`, `squared_centre_distance`)."""

from __future__ import annotations

import functools
from typing import Dict, Tuple

import torch
import torch.nn.functional as F
from torch import Tensor


@functools.lru_cache(maxsize=8)  # built once per device and dtype, not at every loss evaluation
def _gaussian_window(size: int, sigma: float, device, dtype) -> Tensor:
    """The normalised 1-D Gaussian [size]; the 2-D SSIM window is its outer product."""
    x = torch.arange(size, device=device, dtype=dtype) - (size - 1) / 2
    g = torch.exp(-(x**2) / (2 * sigma**2))
    return g / g.sum()


def ssim(
    pred: Tensor, target: Tensor, data_range: float | Tensor = 1.0, window: int = 11, sigma: float = 1.5
) -> Tensor:
    """Mean SSIM (Wang et al. 2004) of two single-channel images [H, W, 1], Gaussian 11x11 window,
    K1 = 0.01, K2 = 0.03, 'valid' filtering (as pytorch_msssim, which nerfstudio reports)."""
    x = pred.permute(2, 0, 1)[None]  # [1, 1, H, W]
    y = target.permute(2, 0, 1)[None]
    g = _gaussian_window(window, sigma, x.device, x.dtype)
    c1 = (0.01 * data_range) ** 2
    c2 = (0.03 * data_range) ** 2
    # the five local moments in one grouped convolution per axis: the Gaussian window is separable,
    # and two 1-D passes cost 2 x 11 instead of 121 multiply-adds per pixel
    moments = torch.cat([x, y, x * x, y * y, x * y], dim=1)  # [1, 5, H, W]
    moments = F.conv2d(moments, g.view(1, 1, -1, 1).expand(5, 1, -1, -1), groups=5)  # [1, 5, H', W]
    moments = F.conv2d(moments, g.view(1, 1, 1, -1).expand(5, 1, -1, -1), groups=5)  # [1, 5, H', W']
    mu_x, mu_y, exx, eyy, exy = moments[0]
    mu_xy, mu_xx, mu_yy = mu_x * mu_y, mu_x * mu_x, mu_y * mu_y
    ssim_map = ((2 * mu_xy + c1) * (2 * (exy - mu_xy) + c2)) / ((mu_xx + mu_yy + c1) * (exx - mu_xx + eyy - mu_yy + c2))
    return ssim_map.mean()


def psnr(pred: Tensor, target: Tensor, data_range: float = 1.0) -> Tensor:
    """PSNR in dB for images with values in a range of `data_range`."""
    mse = torch.mean((pred - target) ** 2).clamp(min=1e-12)
    return 10 * torch.log10(data_range**2 / mse)


def image_metrics_and_images(pred: Tensor, gt: Tensor, num_points: int) -> Tuple[Dict[str, float], Dict[str, Tensor]]:
    """nerfstudio's evaluation of one image: PSNR and SSIM of the render `pred` [H, W, 1] against `gt`
    (training space), and the two side by side in grey [H, 2W, 3]."""
    metrics = {
        "psnr": float(psnr(pred, gt)),
        "ssim": float(ssim(pred, gt, data_range=1.0)),
        "gaussian_count": float(num_points),
    }
    return metrics, {"img": torch.cat([gt, pred], dim=1).clamp(0, 1).expand(-1, -1, 3)}


def squared_centre_distance(u, v, width: int, height: int):
    """The squared distance of image points (`u`, `v`: pixel coordinates, numpy arrays or tensors of one
    shape) from the centre of a width x height image, 1 at the corners: the variable of a camera's radial
    fall-off wherever it is fitted (`evaluation.centre_r2`, `view_emission.radial_part`)."""
    return ((u - width / 2) ** 2 + (v - height / 2) ** 2) / ((width / 2) ** 2 + (height / 2) ** 2)


def radial_fit(values: Tensor, emission: Tensor, r2: Tensor) -> Tensor:
    """`values` [M, 1] as one camera response explains them: their least-squares fit by a gain fall-off
    (times `emission` [M, 1]) and an offset fall-off, each in r^2 and r^4 (`r2` [M, 1]: the squared distance
    from the image centre, 1 at the corners), the same four coefficients for all M. Differentiable in
    `values` (the normal equations, a ridge of the dtype's precision so that an empty or flat set solves)."""
    basis = torch.cat([emission * r2, emission * r2.square(), r2, r2.square()], dim=-1)  # [M, 4]
    gram = basis.T @ basis  # [4, 4]
    ridge = torch.finfo(gram.dtype).eps * (gram.diagonal().mean() + 1.0)
    coefficients = torch.linalg.solve(
        gram + ridge * torch.eye(4, device=gram.device, dtype=gram.dtype), basis.T @ values
    )
    return basis @ coefficients  # [M, 1]
