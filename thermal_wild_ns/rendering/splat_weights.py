"""One view's render as a linear map of the Gaussians' colours.

With the geometry fixed, each pixel of a render is its splats' colours summed by weights (alpha times
transmittance) that the colours do not change. A fit through the render that moves only the colours (a
photometric state fitted to a frame, `pipeline/evaluation.py`) computes those weights once and renders every
step after as one sparse product: the same render and the same gradient for the colours as the rasterizer's,
at the cost of a product instead of a projection, a sort and a composite. The weights are the pure-torch
rasterizer's (`torch_rasterizer.composited_chunks`), on any device."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Literal

import torch
from gsplat.cuda._torch_impl import _quat_scale_to_covar_preci
from torch import Tensor

from thermal_wild_ns.rendering.torch_rasterizer import composited_chunks, intersect_tiles, project_gaussians

TILE_SIZE = 16


class _SparseProduct(torch.autograd.Function):
    """`matrix @ x` for a constant sparse (CSR) `matrix`, its gradient `transposed @ grad` by the transpose kept
    in CSR as well (torch's own backward of a sparse product transposes on every call)."""

    @staticmethod
    def forward(ctx, matrix: Tensor, transposed: Tensor, x: Tensor) -> Tensor:
        ctx.transposed = transposed
        return matrix @ x

    @staticmethod
    def backward(ctx, grad: Tensor):
        return None, None, ctx.transposed @ grad


@dataclass(frozen=True)
class SplatWeights:
    """A view's splat weights: `matrix` [H * W, N] (pixel y * W + x by Gaussian) and its transpose, both sparse
    (CSR), the view's alpha [1, H, W, 1] and expected depth [1, H, W, 1] (gsplat's "ED")."""

    matrix: Tensor
    transposed: Tensor
    alpha: Tensor
    depth: Tensor
    width: int
    height: int

    def render(self, colors: Tensor) -> Tensor:
        """The view with the Gaussians' `colors` [N, D]: [1, H, W, D + 1], the expected depth last (as the
        rasterizer's "RGB+ED" render)."""
        image = _SparseProduct.apply(self.matrix, self.transposed, colors.contiguous())  # [H * W, D]
        return torch.cat([image.view(1, self.height, self.width, colors.shape[-1]), self.depth], -1)


@torch.no_grad()
def splat_weights(
    means: Tensor,  # [N, 3]
    quats: Tensor,  # [N, 4]
    scales: Tensor,  # [N, 3]
    opacities: Tensor,  # [N]
    viewmat: Tensor,  # [1, 4, 4]
    K: Tensor,  # [1, 3, 3]
    width: int,
    height: int,
    near_plane: float,
    far_plane: float,
    rasterize_mode: Literal["classic", "antialiased"] = "classic",
) -> SplatWeights:
    """The weights of every Gaussian in every pixel of one camera, as the rasterizer composites them
    (`packed=False`, gsplat's defaults otherwise)."""
    N = means.shape[0]
    covars, _ = _quat_scale_to_covar_preci(quats, scales, compute_preci=False)
    radii, means2d, depths, conics, compensations = project_gaussians(
        means,
        covars,
        viewmat,
        K,
        width,
        height,
        0.3,
        near_plane,
        far_plane,
        0.0,
        rasterize_mode == "antialiased",
        "pinhole",
    )  # [1, N], [1, N, 2], [1, N], [1, N, 3]
    opacities = opacities[None] if compensations is None else opacities[None] * compensations
    tile_width, tile_height = math.ceil(width / TILE_SIZE), math.ceil(height / TILE_SIZE)
    means2d, radii, depths = means2d.reshape(N, 2), radii.reshape(N), depths.reshape(N)
    _, pair_tile, pair_splat = intersect_tiles(
        means2d, radii, depths, torch.zeros_like(radii), TILE_SIZE, tile_width, tile_height
    )
    local = torch.arange(TILE_SIZE * TILE_SIZE, device=means.device)
    local_x, local_y = local % TILE_SIZE, local // TILE_SIZE  # [P2]: a tile's pixels, row-major
    rows, columns, values = [], [], []
    chunks = composited_chunks(
        means2d, conics.reshape(N, 3), opacities.reshape(N), pair_tile, pair_splat, width, height, TILE_SIZE
    )
    for tiles, idx, weights in chunks:  # [B], [B, K], [B, P2, K]
        x = (tiles % tile_width)[:, None] * TILE_SIZE + local_x  # [B, P2]
        y = (tiles // tile_width)[:, None] * TILE_SIZE + local_y
        drawn = (weights > 0) & ((x < width) & (y < height))[..., None]  # a tile's overhang past the image: none
        b, p, k = drawn.nonzero(as_tuple=True)
        rows.append(y[b, p] * width + x[b, p])
        columns.append(idx[b, k])
        values.append(weights[b, p, k])
    cat = lambda parts, like: torch.cat(parts) if parts else like.new_zeros(0)
    index = torch.stack([cat(rows, local), cat(columns, local)])
    matrix = torch.sparse_coo_tensor(index, cat(values, means), (height * width, N), check_invariants=False)
    matrix = matrix.coalesce()
    with warnings.catch_warnings():  # torch calls its CSR tensors beta at every conversion: not the user's concern
        warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta state")
        csr, transposed = matrix.to_sparse_csr(), matrix.t().coalesce().to_sparse_csr()
    alpha = (csr @ means.new_ones(N, 1)).view(1, height, width, 1)
    depth = (csr @ depths[:, None]).view(1, height, width, 1) / alpha.clamp(min=1e-10)
    return SplatWeights(csr, transposed, alpha, depth, width, height)
