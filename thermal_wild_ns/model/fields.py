"""The small networks of the thermal model: emission MLP and background MLP."""

from __future__ import annotations

from typing import List, Optional, Tuple

import torch
from nerfstudio.field_components.encodings import SHEncoding
from torch import Tensor, nn
from torch.nn import functional as F


class PackedMLP(nn.Module):
    """`hidden_layers` Linear+ReLU layers of `width`, then a linear output initialised to zero, so that a
    freshly added MLP is a no-op residual and training starts from the plain scalars.

    Every weight and bias is a view of one parameter, `packed` (each layer's weight [out, in], then its
    bias [out], layer after layer): a training step's backward accumulates one gradient for the MLP instead
    of one per tensor, and Adam updates one tensor (each costs the host an operation every step; Adam is
    elementwise, so the update is the same). Initialised as `nn.Linear` layers are, in the same order of
    random draws (a checkpoint of the `nn.Sequential` this replaced: `old_checkpoints.packed_mlp_state`)."""

    def __init__(self, in_dim: int, width: int, hidden_layers: int, out_dim: int = 1):
        super().__init__()
        dims = [in_dim] + [width] * hidden_layers + [out_dim]
        layers = [nn.Linear(a, b) for a, b in zip(dims[:-1], dims[1:])]
        nn.init.zeros_(layers[-1].weight)
        nn.init.zeros_(layers[-1].bias)
        self.shapes = tuple((b, a) for a, b in zip(dims[:-1], dims[1:]))  # each layer's weight [out, in]
        tensors = [t.detach().reshape(-1) for layer in layers for t in (layer.weight, layer.bias)]
        self.packed = nn.Parameter(torch.cat(tensors))

    def layers(self, packed: Optional[Tensor] = None) -> List[Tuple[Tensor, Tensor]]:
        """Each layer's (weight [out, in], bias [out]): views of `packed` (by default the parameter, whose
        gradient they take; or a tensor laid out as it is, such as its gradient)."""
        packed = self.packed if packed is None else packed
        # one split, whose backward is one concatenation (a slice's each fills a zero tensor of the whole size)
        sizes = [n for out_dim, in_dim in self.shapes for n in (out_dim * in_dim, out_dim)]
        chunks = packed.split(sizes)  # weight, bias, weight, bias, ...
        return [(w.view(shape), b) for shape, w, b in zip(self.shapes, chunks[::2], chunks[1::2])]

    def forward(self, x: Tensor) -> Tensor:
        """x [P, in] -> [P, out]."""
        layers = self.layers()
        for weight, bias in layers[:-1]:
            x = torch.relu_(F.linear(x, weight, bias))
        weight, bias = layers[-1]
        return F.linear(x, weight, bias)


class EmissionMLP(nn.Module):
    """c_i(t) = base_i + MLP([e_i^(g), e_t^(f)]): scalar emission of Gaussian i seen in frame t.

    The per-Gaussian scalar `base_i` is what a plain 3DGS model would learn; the MLP adds what
    the embeddings explain (residual thermal transients of frame t, view-independent detail of
    Gaussian i). Zero-initialised output: at step 0 the model is plain scalar splatting.
    """

    def __init__(self, gaussian_dim: int, frame_dim: int, width: int = 128, hidden_layers: int = 3):
        super().__init__()
        self.net = PackedMLP(gaussian_dim + frame_dim, width, hidden_layers)

    def forward(self, base: Tensor, gaussian_embed: Tensor, frame_embed: Tensor) -> Tensor:
        """base [N, 1], gaussian_embed [N, Dg], frame_embed [Df] -> emission [N, 1]; or frame embeddings [B, Df]
        (several states in one call: the held-out fits') -> [B, N, 1]."""
        lead, count = frame_embed.shape[:-1], gaussian_embed.shape[0]
        frame = frame_embed[..., None, :].expand(*lead, count, -1)  # [N, Df] or [B, N, Df]
        x = torch.cat([gaussian_embed.expand(*lead, -1, -1), frame], dim=-1)
        # the MLP on rows [B * N, D]: on a 3-D input each in-place ReLU acts on a view of the matmul, whose
        # backward copies the whole activation
        return base + self.net(x.reshape(-1, x.shape[-1])).view(*lead, count, 1)

    def rows(self, base: Tensor, gaussian_embed: Tensor, frame_embed: Tensor) -> Tensor:
        """base [R, 1], gaussian_embed [R, Dg], frame_embed [R, Df]: each row a Gaussian under its own state ->
        emission [R, 1]."""
        return base + self.net(torch.cat([gaussian_embed, frame_embed], dim=-1))


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
        self.net = PackedMLP(self.encoding.get_out_dim() + net_frame_dim, width, hidden_layers)
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
        """encoded directions [..., 16], frame_embed [Df] -> background [..., 1]; or several images' encoded
        directions [B, ..., 16] each at its own frame embedding [B, Df] -> [B, ..., 1]."""
        if frame_embed.dim() == 2:  # one state per image: [B, P, 16] against [B, Df]
            enc = encoded.reshape(encoded.shape[0], -1, encoded.shape[-1])
            if self.frame_affine is not None:
                gain, shift = self.frame_affine(frame_embed)[:, None, :].unbind(-1)  # [B, 1] each
                out = (self.net(enc)[..., 0] + self.offset) * (1.0 + gain) + shift  # [B, P]
            else:
                frame = frame_embed[:, None, :].expand(-1, enc.shape[1], -1)
                out = self.net(torch.cat([enc, frame], dim=-1))[..., 0] + self.offset
            return out.reshape(*encoded.shape[:-1], 1)
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
