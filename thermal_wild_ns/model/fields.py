"""The small networks of the thermal model: emission MLP and background MLP."""

from __future__ import annotations

import torch
from nerfstudio.field_components.encodings import SHEncoding
from torch import Tensor, nn


def mlp(in_dim: int, width: int, hidden_layers: int, out_dim: int = 1) -> nn.Sequential:
    """`hidden_layers` Linear+ReLU layers of `width`, then a linear output initialised to zero,
    so that a freshly added MLP is a no-op residual and training starts from the plain scalars."""
    layers, dim = [], in_dim
    for _ in range(hidden_layers):
        layers += [nn.Linear(dim, width), nn.ReLU(inplace=True)]
        dim = width
    out = nn.Linear(dim, out_dim)
    nn.init.zeros_(out.weight)
    nn.init.zeros_(out.bias)
    return nn.Sequential(*layers, out)


class EmissionMLP(nn.Module):
    """c_i(t) = base_i + MLP([e_i^(g), e_t^(f)]): scalar emission of Gaussian i seen in frame t.

    The per-Gaussian scalar `base_i` is what a plain 3DGS model would learn; the MLP adds what
    the embeddings explain (residual thermal transients of frame t, view-independent detail of
    Gaussian i). Zero-initialised output: at step 0 the model is plain scalar splatting.
    """

    def __init__(self, gaussian_dim: int, frame_dim: int, width: int = 128, hidden_layers: int = 3):
        super().__init__()
        self.net = mlp(gaussian_dim + frame_dim, width, hidden_layers)

    def forward(self, base: Tensor, gaussian_embed: Tensor, frame_embed: Tensor) -> Tensor:
        """base [N, 1], gaussian_embed [N, Dg], frame_embed [Df] -> emission [N, 1]."""
        frame = frame_embed[None, :].expand(gaussian_embed.shape[0], -1)  # [N, Df]
        return base + self.net(torch.cat([gaussian_embed, frame], dim=-1))


class BackgroundMLP(nn.Module):
    """b(d, e_t): thermal radiance arriving from direction d (sky, far field) in frame t.

    Directions are encoded with real spherical harmonics up to degree 3 (smooth, as distant
    thermal backgrounds are); a learned scalar offset starts it at `init_value`. `frame_coupling`
    'mlp': the frame embedding is an input of the MLP (any change with direction and frame);
    'affine': the MLP sees the direction only, and the frame embedding sets a gain and an offset of
    the whole map (a frame's state changes every direction alike, as a sensor's drift does).
    """

    def __init__(
        self,
        frame_dim: int,
        frame_coupling: str,
        width: int = 64,
        hidden_layers: int = 2,
        init_value: float = 0.0,
    ):
        super().__init__()
        if frame_coupling not in ("mlp", "affine"):
            raise ValueError(f"background frame coupling {frame_coupling!r}: 'mlp' or 'affine'")
        self.encoding = SHEncoding(levels=4, implementation="torch")
        net_frame_dim = frame_dim if frame_coupling == "mlp" else 0
        self.net = mlp(self.encoding.get_out_dim() + net_frame_dim, width, hidden_layers)
        self.offset = nn.Parameter(torch.tensor([init_value]))
        self.frame_affine = None  # [Df] -> (gain - 1, offset) of the whole map, 'affine' only
        if frame_coupling == "affine":
            self.frame_affine = nn.Linear(frame_dim, 2)
            nn.init.zeros_(self.frame_affine.weight)  # gain 1 and offset 0 for every frame at the start
            nn.init.zeros_(self.frame_affine.bias)

    def encode(self, directions: Tensor) -> Tensor:
        """directions [..., 3] (unit, world frame) -> their encoding [..., 16], which depends on
        the view only (callers may cache it per camera)."""
        return self.encoding(directions.reshape(-1, 3)).reshape(*directions.shape[:-1], -1)

    def from_encoded(self, encoded: Tensor, frame_embed: Tensor) -> Tensor:
        """encoded directions [..., 16], frame_embed [Df] -> background [..., 1]."""
        enc = encoded.reshape(-1, encoded.shape[-1])  # [P, 16]
        if self.frame_affine is not None:
            gain, shift = self.frame_affine(frame_embed)  # [2]
            out = (self.net(enc) + self.offset) * (1.0 + gain) + shift  # [P, 1]
            return out.reshape(*encoded.shape[:-1], 1)
        frame = frame_embed[None, :].expand(enc.shape[0], -1)
        out = self.net(torch.cat([enc, frame], dim=-1)) + self.offset
        return out.reshape(*encoded.shape[:-1], 1)

    def forward(self, directions: Tensor, frame_embed: Tensor) -> Tensor:
        """directions [..., 3] (unit, world frame), frame_embed [Df] -> background [..., 1]."""
        return self.from_encoded(self.encode(directions), frame_embed)
