"""A pure-PyTorch Gaussian rasterizer with gsplat 1.4.0's `rasterization` signature.

gsplat ships CUDA kernels only; this module lets the model train and render on a CPU (tests, CI,
the CPU demo) with the same numbers the CUDA kernels produce. It mirrors gsplat's pipeline:

1. projection (EWA splatting, pinhole/ortho/fisheye via gsplat's own reference helpers), with the
   same 3-sigma radius, near/far and off-screen culling, and `eps2d` blur / antialiased
   compensation as `fully_fused_projection_fwd.cu`;
2. tile intersection: every splat is listed in each 16x16 tile its radius box touches, sorted by
   depth inside the tile (gsplat's `isect_tiles`);
3. front-to-back compositing per pixel with gsplat's exact rules: pixel centres at +0.5,
   alpha = min(0.999, opacity * exp(-sigma)), splats with sigma < 0 or alpha < 1/255 skipped,
   a pixel stops before the splat that would bring its transmittance to <= 1e-4.

Gradients come from autograd. `meta["means2d"]` is the tensor the compositing reads, so
`means2d.grad` (after `retain_grad`) and, with `absgrad=True`, `means2d.absgrad` (the sum over
pixels of the absolute per-pixel gradient, as gsplat computes it) are what gsplat's
densification strategies expect.

Memory: tiles are composited in chunks whose padded size is bounded by `_CHUNK_ELEMENTS`.
"""

from __future__ import annotations

import math
from typing import Dict, Iterator, Literal, Optional, Tuple

import torch
from gsplat.cuda._torch_impl import (
    _fisheye_proj,
    _ortho_proj,
    _persp_proj,
    _quat_scale_to_covar_preci,
    _spherical_harmonics,
    _world_to_cam,
)
from torch import Tensor

from thermal_wild_ns.rendering.splat_exchange import all_gather_rows, exchange_splats, exchange_visible

# Upper bound on pixels x splats composited at once (per chunk of tiles); ~16M keeps the
# autograd intermediates of one chunk around 1 GB on CPU.
_CHUNK_ELEMENTS = 1 << 24
_ALPHA_MIN = 1.0 / 255.0
_ALPHA_MAX = 0.999
_T_MIN = 1e-4


class _GatherMeans2d(torch.autograd.Function):
    """`src[index]` broadcast over a tile's pixels [B, P, K, 2]. Its backward sees the gradient of
    every (pixel, splat) pair, so besides the usual sum it accumulates sum |per-pixel gradient|
    into `holder.absgrad`, as gsplat's kernels do (autograd's own broadcast would sum first)."""

    @staticmethod
    def forward(ctx, src: Tensor, index: Tensor, num_pixels: int, holder: Tensor) -> Tensor:  # type: ignore[override]
        ctx.save_for_backward(index)
        ctx.num = src.shape[0]
        ctx.holder = holder
        return src[index][:, None].expand(-1, num_pixels, -1, -1)

    @staticmethod
    def backward(ctx, grad: Tensor):  # type: ignore[override]
        (index,) = ctx.saved_tensors
        flat_index = index.reshape(-1)
        dim = grad.shape[-1]
        out = grad.new_zeros(ctx.num, dim).index_add_(0, flat_index, grad.sum(1).reshape(-1, dim))
        absgrad = grad.new_zeros(ctx.num, dim).index_add_(0, flat_index, grad.abs().sum(1).reshape(-1, dim))
        ctx.holder.absgrad.view(-1, dim).add_(absgrad)
        return out, None, None, None


def project_gaussians(
    means: Tensor,  # [N, 3]
    covars: Tensor,  # [N, 3, 3]
    viewmats: Tensor,  # [C, 4, 4]
    Ks: Tensor,  # [C, 3, 3]
    width: int,
    height: int,
    eps2d: float,
    near_plane: float,
    far_plane: float,
    radius_clip: float,
    calc_compensations: bool,
    camera_model: Literal["pinhole", "ortho", "fisheye"],
) -> Tuple[Tensor, Tensor, Tensor, Tensor, Optional[Tensor]]:
    """Project 3D Gaussians to every camera, as gsplat's `fully_fused_projection` (packed=False).

    Returns radii [C, N] int32 (0 = culled), means2d [C, N, 2], depths [C, N], conics [C, N, 3]
    and compensations [C, N] (or None).
    """
    means_c, covars_c = _world_to_cam(means, covars, viewmats)  # [C, N, 3], [C, N, 3, 3]
    depths = means_c[..., 2]  # [C, N]
    in_depth = (depths > near_plane) & (depths < far_plane)
    # Culled splats still flow through autograd; keep their arithmetic finite (z = 1) so that a
    # zero upstream gradient cannot turn into 0 * inf = NaN in the means' gradient.
    safe_z = torch.where(in_depth, depths, torch.ones_like(depths))
    means_c = torch.cat([means_c[..., :2], safe_z[..., None]], dim=-1)
    proj = {"pinhole": _persp_proj, "ortho": _ortho_proj, "fisheye": _fisheye_proj}[camera_model]
    means2d, covars2d = proj(means_c, covars_c, Ks, width, height)  # [C, N, 2], [C, N, 2, 2]

    a, b, c = covars2d[..., 0, 0], 0.5 * (covars2d[..., 0, 1] + covars2d[..., 1, 0]), covars2d[..., 1, 1]
    det_orig = a * c - b * b
    a, c = a + eps2d, c + eps2d
    det = a * c - b * b
    valid = in_depth & (det > 0)
    safe_det = torch.where(valid, det, torch.ones_like(det))
    conics = torch.stack([c / safe_det, -b / safe_det, a / safe_det], dim=-1)  # [C, N, 3]
    compensations = None
    if calc_compensations:
        compensations = torch.sqrt(torch.clamp(det_orig / safe_det, min=0.0))

    with torch.no_grad():
        half_trace = 0.5 * (a + c)
        v1 = half_trace + torch.sqrt(torch.clamp(half_trace**2 - det, min=0.01))
        radius = torch.ceil(3.0 * torch.sqrt(v1))
        valid = valid & (radius > radius_clip)
        x, y = means2d[..., 0], means2d[..., 1]
        valid = valid & (x + radius > 0) & (x - radius < width) & (y + radius > 0) & (y - radius < height)
        radii = torch.where(valid, radius, torch.zeros_like(radius)).int()
    return radii, means2d, depths, conics, compensations


def tile_rectangles(
    means2d: Tensor,  # [M, 2]
    radii: Tensor,  # [M]
    tile_size: int,
    tile_width: int,
    tile_height: int,
) -> Tuple[Tensor, Tensor, Tensor]:
    """Each splat's rectangle of tiles, as gsplat's `isect_tiles` kernel draws it: its first tile lo [M, 2] (x, y),
    its extent [M, 2] in tiles (both clamped to the image) and tiles_per_gauss [M] (none where the radius is 0).
    No host read, so a CUDA graph can hold it (`experiments/padded_isect.py`)."""
    tile_means = means2d / tile_size
    tile_radii = (radii / tile_size)[:, None]
    lo = torch.floor(tile_means - tile_radii).long()
    hi = torch.ceil(tile_means + tile_radii).long()
    lo[:, 0].clamp_(0, tile_width), hi[:, 0].clamp_(0, tile_width)
    lo[:, 1].clamp_(0, tile_height), hi[:, 1].clamp_(0, tile_height)
    extent = (hi - lo).clamp(min=0)  # [M, 2]
    return lo, extent, extent.prod(-1) * (radii > 0)


def tile_in_rectangle(lo: Tensor, extent: Tensor, splat: Tensor, local: Tensor, tile_width: int) -> Tensor:
    """The tile (y * tile_width + x, within its camera) [P] of each pair: the `local` [P]-th tile, row-major, of
    splat `splat` [P]'s rectangle (`tile_rectangles`' lo and extent)."""
    box_w = extent[splat, 0].clamp(min=1)
    return (lo[splat, 1] + local // box_w) * tile_width + lo[splat, 0] + local % box_w


@torch.no_grad()
def intersect_tiles(
    means2d: Tensor,  # [M, 2]
    radii: Tensor,  # [M]
    depths: Tensor,  # [M]
    camera_ids: Tensor,  # [M]
    tile_size: int,
    tile_width: int,
    tile_height: int,
) -> Tuple[Tensor, Tensor, Tensor]:
    """List (tile, splat) pairs sorted by camera, tile, then depth (gsplat's `isect_tiles`).

    Returns tiles_per_gauss [M], pair_tile [P] (global tile id = camera * tiles + tile) and
    pair_splat [P].
    """
    device = means2d.device
    lo, extent, tiles_per_gauss = tile_rectangles(means2d, radii, tile_size, tile_width, tile_height)
    splat = torch.repeat_interleave(torch.arange(len(radii), device=device), tiles_per_gauss)
    # position of each pair inside its splat's box, row-major over the box
    start = torch.cumsum(tiles_per_gauss, 0) - tiles_per_gauss
    local = torch.arange(len(splat), device=device) - start[splat]
    tile = camera_ids[splat].long() * (tile_width * tile_height) + tile_in_rectangle(
        lo, extent, splat, local, tile_width
    )
    # sort by depth, then stably by tile: depth order inside every tile
    order = torch.argsort(depths[splat], stable=True)
    order = order[torch.argsort(tile[order], stable=True)]
    return tiles_per_gauss, tile[order], splat[order]


def composited_chunks(
    means2d: Tensor,  # [M, 2]
    conics: Tensor,  # [M, 3]
    opacities: Tensor,  # [M]
    pair_tile: Tensor,  # [P]
    pair_splat: Tensor,  # [P]
    width: int,
    height: int,
    tile_size: int,
    absgrad_holder: Optional[Tensor] = None,
) -> Iterator[Tuple[Tensor, Tensor, Tensor]]:
    """Front-to-back compositing of depth-sorted splats, a chunk of tiles at a time: each chunk's tiles [B]
    (global ids), the splat in each of their slots [B, K] and each pixel's weight of it [B, P2, K] (alpha times
    transmittance; 0 in an empty slot and past the pixel's stop). A pixel's render is its splats' colours summed
    by these weights."""
    if pair_tile.numel() == 0:
        return
    device, dtype = means2d.device, means2d.dtype
    tile_width = math.ceil(width / tile_size)
    tile_height = math.ceil(height / tile_size)
    P2 = tile_size * tile_size
    tiles, counts = torch.unique_consecutive(pair_tile, return_counts=True)
    starts = torch.cumsum(counts, 0) - counts
    # composite tiles in order of splat count so that a chunk pads to a similar length
    by_count = torch.argsort(counts)
    tiles, counts, starts = tiles[by_count], counts[by_count], starts[by_count]
    # pixel centres of a tile, relative to its corner: [P2, 2]
    yy, xx = torch.meshgrid(
        torch.arange(tile_size, device=device), torch.arange(tile_size, device=device), indexing="ij"
    )
    local_px = torch.stack([xx.reshape(-1), yy.reshape(-1)], -1).to(dtype) + 0.5
    counts_list = counts.tolist()
    i = 0
    while i < len(counts_list):
        # grow the chunk while it stays within the memory budget and pads little
        j, kmax = i, 0
        while j < len(counts_list):
            k_new = max(kmax, counts_list[j])
            over_budget = (j + 1 - i) * P2 * k_new > _CHUNK_ELEMENTS
            too_ragged = k_new > 1.5 * max(counts_list[i], 16)  # padding would waste > 1/3
            if j > i and (over_budget or too_ragged):
                break
            kmax = k_new
            j += 1
        chunk_tiles = tiles[i:j]
        chunk_cnt = counts[i:j]
        slot = torch.arange(kmax, device=device)
        valid = slot[None, :] < chunk_cnt[:, None]  # [B, K]
        pair_idx = (starts[i:j, None] + slot[None, :]).clamp(max=len(pair_splat) - 1)
        idx = torch.where(valid, pair_splat[pair_idx], torch.zeros_like(pair_idx))  # [B, K]

        tile_in_cam = chunk_tiles % (tile_width * tile_height)
        corner = torch.stack([tile_in_cam % tile_width, tile_in_cam // tile_width], -1).to(dtype) * tile_size
        pix = corner[:, None, :] + local_px[None]  # [B, P2, 2]

        if absgrad_holder is not None:
            mu = _GatherMeans2d.apply(means2d, idx, P2, absgrad_holder)  # [B, P2, K, 2]
        else:
            mu = means2d[idx][:, None]  # [B, 1, K, 2]
        dx = mu[..., 0] - pix[:, :, None, 0]  # [B, P2, K]
        dy = mu[..., 1] - pix[:, :, None, 1]
        con = conics[idx][:, None]  # [B, 1, K, 3]
        sigma = 0.5 * (con[..., 0] * dx * dx + con[..., 2] * dy * dy) + con[..., 1] * dx * dy  # [B, P2, K]
        alpha = torch.clamp(opacities[idx][:, None] * torch.exp(-sigma), max=_ALPHA_MAX)
        keep = valid[:, None, :] & (sigma >= 0) & (alpha >= _ALPHA_MIN)
        alpha = torch.where(keep, alpha, torch.zeros_like(alpha))
        one_minus = 1.0 - alpha
        trans = torch.cumprod(torch.cat([torch.ones_like(one_minus[..., :1]), one_minus[..., :-1]], -1), -1)
        with torch.no_grad():
            # gsplat stops a pixel *before* the splat that would drop T to <= 1e-4
            alive = (trans * one_minus) > _T_MIN
        yield chunk_tiles, idx, alpha * trans * alive
        i = j


def tiles_to_image(x: Tensor, n_cameras: int, width: int, height: int, tile_size: int) -> Tensor:
    """Per-tile pixels [n_tiles, P2, D] as images [C, H, W, D] (the tiles' overhang past the image cut)."""
    tile_width, tile_height = math.ceil(width / tile_size), math.ceil(height / tile_size)
    x = x.view(n_cameras, tile_height, tile_width, tile_size, tile_size, x.shape[-1])
    x = x.permute(0, 1, 3, 2, 4, 5).reshape(n_cameras, tile_height * tile_size, tile_width * tile_size, -1)
    return x[:, :height, :width]


def composite_tiles(
    means2d: Tensor,  # [M, 2]
    conics: Tensor,  # [M, 3]
    opacities: Tensor,  # [M]
    colors: Tensor,  # [M, D]
    pair_tile: Tensor,  # [P]
    pair_splat: Tensor,  # [P]
    n_cameras: int,
    width: int,
    height: int,
    tile_size: int,
    absgrad_holder: Optional[Tensor] = None,
) -> Tuple[Tensor, Tensor]:
    """Front-to-back alpha compositing of depth-sorted splats, tile by tile (`composited_chunks`).

    Returns colors [C, H, W, D] and alphas [C, H, W, 1] (no background).
    """
    n_tiles = n_cameras * math.ceil(width / tile_size) * math.ceil(height / tile_size)
    out_colors = means2d.new_zeros(n_tiles, tile_size * tile_size, colors.shape[-1])
    out_alphas = means2d.new_zeros(n_tiles, tile_size * tile_size, 1)
    chunks = composited_chunks(
        means2d, conics, opacities, pair_tile, pair_splat, width, height, tile_size, absgrad_holder
    )
    for chunk_tiles, idx, weights in chunks:
        out_colors[chunk_tiles] = torch.einsum("bpk,bkd->bpd", weights, colors[idx])
        out_alphas[chunk_tiles] = weights.sum(-1, keepdim=True)
    to_image = lambda x: tiles_to_image(x, n_cameras, width, height, tile_size)
    return to_image(out_colors), to_image(out_alphas)


def rasterization(
    means: Tensor,  # [N, 3]
    quats: Tensor,  # [N, 4]
    scales: Tensor,  # [N, 3]
    opacities: Tensor,  # [N]
    colors: Tensor,  # [(C,) N, D] or [(C,) N, K, 3]
    viewmats: Tensor,  # [C, 4, 4]
    Ks: Tensor,  # [C, 3, 3]
    width: int,
    height: int,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    radius_clip: float = 0.0,
    eps2d: float = 0.3,
    sh_degree: Optional[int] = None,
    packed: bool = True,
    tile_size: int = 16,
    backgrounds: Optional[Tensor] = None,
    render_mode: Literal["RGB", "D", "ED", "RGB+D", "RGB+ED"] = "RGB",
    sparse_grad: bool = False,
    absgrad: bool = False,
    rasterize_mode: Literal["classic", "antialiased"] = "classic",
    channel_chunk: int = 32,
    distributed: bool = False,
    camera_model: Literal["pinhole", "ortho", "fisheye"] = "pinhole",
    covars: Optional[Tensor] = None,
) -> Tuple[Tensor, Tensor, Dict]:
    """Pure-PyTorch twin of `gsplat.rendering.rasterization` (gsplat 1.4.0).

    Same arguments and returns: render_colors [C, H, W, D(+1)], render_alphas [C, H, W, 1] and a
    meta dict with the fields gsplat's strategies read (means2d, radii, width, height,
    n_cameras, gaussian_ids, ...). `sparse_grad` and `channel_chunk` only change how gsplat's
    kernels are scheduled, so they are accepted and ignored. `distributed` is gsplat's: every rank of
    torch.distributed's process group holds its own Gaussians and renders its own cameras; each rank
    projects its Gaussians into every rank's cameras and sends each camera's splats (packed: the
    visible ones only, `exchange_visible`; else all, `exchange_splats`) to the rank that renders it,
    so gradients flow back to the Gaussians' owners. As in gsplat it needs per-Gaussian colours and no
    `absgrad`, and the meta's `means2d`, `radii` (and, packed, `camera_ids`, global, and
    `gaussian_ids`, local) are the rank's own Gaussians in every rank's cameras (what the
    densification statistics need).
    """
    if distributed:
        assert not absgrad and sh_degree is None and colors.dim() == 2, (
            "distributed rendering needs absgrad=False and per-Gaussian colours [N, D] (as gsplat's)"
        )
    N = means.shape[0]
    C = viewmats.shape[0]
    assert means.shape == (N, 3), means.shape
    assert opacities.shape == (N,), opacities.shape
    assert viewmats.shape == (C, 4, 4), viewmats.shape
    assert Ks.shape == (C, 3, 3), Ks.shape
    assert render_mode in ["RGB", "D", "ED", "RGB+D", "RGB+ED"], render_mode
    if covars is None:
        assert quats.shape == (N, 4) and scales.shape == (N, 3), (quats.shape, scales.shape)
        covars, _ = _quat_scale_to_covar_preci(quats, scales, compute_preci=False)
    assert covars is not None and covars.shape == (N, 3, 3), covars.shape

    C_local = C
    if distributed:  # project into every rank's cameras (gsplat gathers them the same way)
        viewmats, Ks = (all_gather_rows(x) for x in (viewmats, Ks))
        C = viewmats.shape[0]
    radii, means2d, depths, conics, compensations = project_gaussians(
        means,
        covars,
        viewmats,
        Ks,
        width,
        height,
        eps2d,
        near_plane,
        far_plane,
        radius_clip,
        rasterize_mode == "antialiased",
        camera_model,
    )  # [C, N], [C, N, 2], [C, N], [C, N, 3]
    opacities = opacities.expand(C, N)
    if compensations is not None:
        opacities = opacities * compensations

    if distributed and not packed:
        meta_radii, meta_means2d_world = radii, means2d  # this rank's Gaussians in every camera
        colors = colors.expand(C, N, colors.shape[-1])
        radii, means2d, depths, conics, opacities, colors = exchange_splats(
            C_local, radii, means2d, depths, conics, opacities, colors
        )
        C, N = C_local, radii.shape[1]
    elif sh_degree is None:
        assert (colors.dim() == 2 and colors.shape[0] == N) or (colors.dim() == 3 and colors.shape[:2] == (C, N)), (
            colors.shape
        )
        colors = colors.expand(C, N, colors.shape[-1])
    else:
        assert colors.shape[-1] == 3 and colors.shape[-3] == N, colors.shape
        campos = torch.inverse(viewmats)[:, None, :3, 3]  # [C, 1, 3]
        dirs = means[None] - campos  # [C, N, 3]
        shs = colors.expand(C, *colors.shape[-3:])
        colors = _spherical_harmonics(sh_degree, dirs, shs, masks=radii > 0)
        colors = torch.clamp_min(colors + 0.5, 0.0)  # as gsplat, to match Inria's backend

    if render_mode in ["RGB+D", "RGB+ED"]:
        colors = torch.cat([colors, depths[..., None]], -1)
        if backgrounds is not None:
            backgrounds = torch.cat([backgrounds, backgrounds.new_zeros(C, 1)], -1)
    elif render_mode in ["D", "ED"]:
        colors = depths[..., None]
        if backgrounds is not None:
            backgrounds = backgrounds.new_zeros(C, 1)

    camera_ids = torch.arange(C, device=means.device)[:, None].expand(C, N)
    gaussian_ids = torch.arange(N, device=means.device)[None, :].expand(C, N)
    if packed:
        sel = radii > 0  # [C, N]
        camera_ids, gaussian_ids = camera_ids[sel], gaussian_ids[sel]  # [nnz]
        means2d_flat = means2d[sel]  # [nnz, 2] is what packed gsplat hands the strategy
        radii, depths, conics, opacities, colors = radii[sel], depths[sel], conics[sel], opacities[sel], colors[sel]
        if distributed:  # the visible splats go to the ranks whose cameras see them
            meta_packed = (radii, means2d_flat, camera_ids, gaussian_ids)  # global cameras, local Gaussians
            camera_ids, gaussian_ids, radii, means2d_flat, depths, conics, opacities, colors = exchange_visible(
                C_local, N, camera_ids, gaussian_ids, radii, means2d_flat, depths, conics, opacities, colors
            )
            C = C_local
        means2d = means2d_flat
    else:
        means2d_flat = means2d.reshape(C * N, 2)
    meta_means2d = means2d
    if absgrad:
        meta_means2d.absgrad = torch.zeros_like(meta_means2d)  # filled during backward

    tile_width = math.ceil(width / tile_size)
    tile_height = math.ceil(height / tile_size)
    tiles_per_gauss, pair_tile, pair_splat = intersect_tiles(
        means2d_flat.detach(),
        radii.reshape(-1),
        depths.detach().reshape(-1),
        camera_ids.reshape(-1),
        tile_size,
        tile_width,
        tile_height,
    )
    render_colors, render_alphas = composite_tiles(
        means2d_flat,
        conics.reshape(-1, 3),
        opacities.reshape(-1),
        colors.reshape(-1, colors.shape[-1]),
        pair_tile,
        pair_splat,
        C,
        width,
        height,
        tile_size,
        absgrad_holder=meta_means2d if absgrad else None,
    )
    if backgrounds is not None:
        render_colors = render_colors + (1.0 - render_alphas) * backgrounds[:, None, None, :]
    if render_mode in ["ED", "RGB+ED"]:
        render_colors = torch.cat(
            [render_colors[..., :-1], render_colors[..., -1:] / render_alphas.clamp(min=1e-10)], -1
        )

    tiles_per_gauss = tiles_per_gauss.view(radii.shape).int()  # of the splats this rank composited
    if distributed and packed:
        radii, meta_means2d, camera_ids, gaussian_ids = meta_packed
    elif distributed:
        radii, meta_means2d = meta_radii, meta_means2d_world
    meta = {
        "camera_ids": camera_ids if packed else None,
        "gaussian_ids": gaussian_ids if packed else None,
        "radii": radii,
        "means2d": meta_means2d,
        "depths": depths,
        "conics": conics,
        "opacities": opacities,
        "tile_width": tile_width,
        "tile_height": tile_height,
        "tiles_per_gauss": tiles_per_gauss,
        "isect_ids": pair_tile,
        "flatten_ids": pair_splat.int(),
        "width": width,
        "height": height,
        "tile_size": tile_size,
        "n_cameras": C,
    }
    return render_colors, render_alphas, meta
