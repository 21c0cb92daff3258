"""The Gaussians a thermal model starts from: seeded at the dataset's points (their grey level as
emission) or at random, scaled to their nearest neighbours, as splatfacto does, plus each one's
appearance embedding where the emission MLP is on."""

from __future__ import annotations

from typing import Callable, Dict, Optional, Tuple

import numpy as np
import torch
from nerfstudio.models.splatfacto import RGB2SH, random_quat_tensor
from torch import Tensor

from thermal_wild_ns.model.view_emission import view_coefficients
from thermal_wild_ns.state_names import CANONICAL


def initial_gaussians(
    seed_points: Optional[Tuple[Tensor, Tensor]],
    config,
    k_nearest: Callable[[Tensor, int], Tuple[np.ndarray, np.ndarray]],
) -> Dict[str, Tensor]:
    """`means` [N, 3], `scales` [N, 3] (log), `quats` [N, 4], `emission` [N, 1], `opacities` [N, 1]
    (logit), with `config.use_emission_mlp` `gauss_embed` [N, De], and with `config.view_sh_degree` > 0
    `view_sh` [N, K] (`view_emission.py`). `seed_points`: the
    dataparser's (xyz [N, 3], grey [N, 3] in 0..255); `k_nearest`: splatfacto's neighbour search."""
    if seed_points is not None and not config.random_init:
        means = seed_points[0].float()
        seed_values = seed_points[1].float()
        if seed_values.shape[0] == means.shape[0] and seed_values.numel() > 0:
            emission = (seed_values[:, :1] / 255.0).clone()  # [N, 1]
        else:
            emission = torch.full((means.shape[0], 1), 0.5)
    else:
        means = (torch.rand((config.num_random, 3)) - 0.5) * config.random_scale
        emission = torch.full((config.num_random, 1), 0.5)
    num_points = means.shape[0]
    if num_points < 4:
        raise ValueError(
            f"WildThermalModel needs at least 4 seed points to initialise Gaussians, got {num_points}. "
            "Provide sparse points or set random_init=True."
        )
    distances, _ = k_nearest(means, 3)
    avg_dist = torch.from_numpy(distances).mean(dim=-1, keepdim=True).clamp(min=1e-6)
    params = {
        "means": means,
        "scales": torch.log(avg_dist.repeat(1, 3)),
        "quats": random_quat_tensor(num_points),
        "emission": emission,
        "opacities": torch.logit(0.1 * torch.ones(num_points, 1)),
    }
    if config.use_emission_mlp:
        params["gauss_embed"] = 0.1 * torch.randn(num_points, config.gaussian_embed_dim)
    if config.view_sh_degree > 0:  # no view dependence until the data asks for it
        params["view_sh"] = torch.zeros(num_points, view_coefficients(config.view_sh_degree))
    return params


class GreyColourAccessors:
    """splatfacto's colour accessors, which nerfstudio's viewer and exporters read, for a model of
    scalar emission (`emission` [N, 1], `gaussian_emission`, `state_embedding`, `num_points`):
    grey RGB as rendered outside training, as the DC band, and no higher bands."""

    @property
    def colors(self) -> Tensor:
        """Grey RGB in [0, 1] per Gaussian [N, 3]: the emission as rendered outside training (MLP
        included, at the canonical state)."""
        with torch.no_grad():
            emission = self.gaussian_emission(self.state_embedding(CANONICAL))
        return emission.clamp(0.0, 1.0).expand(-1, 3)

    @property
    def features_dc(self) -> Tensor:
        return RGB2SH(self.colors)

    @property
    def features_rest(self) -> Tensor:
        return self.emission.new_zeros(self.num_points, 0, 3)

    @property
    def shs_0(self) -> Tensor:
        return self.features_dc

    @property
    def shs_rest(self) -> Tensor:
        return self.features_rest
