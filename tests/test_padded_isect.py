"""The fixed-size tile intersection (`experiments.padded_isect`) against gsplat 1.4.0's own: its torch reference on
a CPU (the same sorted intersections, then padding the rasterizer reads as the last tile's, and the same tile
offsets), and on a GPU its CUDA functions, with no host read and the same render where the pads point at a
Gaussian of zero opacity."""

import pytest
import torch
from gsplat.cuda._torch_impl import _isect_offset_encode, _isect_tiles

from experiments.padded_isect import PAD_DEPTH_BITS, padded_isect_tiles

TILE = 16


def _scene(cameras, n, width, height, seed, device="cpu"):
    """Gaussians on and around an image of width x height: some off it, some culled (radius 0), some large."""
    generator = torch.Generator().manual_seed(seed)
    span = torch.tensor([width, height])
    means2d = torch.rand(cameras, n, 2, generator=generator) * span * 1.4 - span * 0.2  # [C, N, 2]
    radii = (torch.rand(cameras, n, generator=generator) ** 3 * 40).int()  # [C, N], a few over two tiles
    radii[torch.rand(cameras, n, generator=generator) < 0.1] = 0
    depths = torch.rand(cameras, n, generator=generator) * 5 + 0.2  # [C, N], distinct
    return means2d.to(device), radii.to(device), depths.to(device)


def _tiles(width, height):
    return -(-width // TILE), -(-height // TILE)


@pytest.mark.parametrize("cameras, seed", [(1, 0), (2, 1), (3, 2)])
def test_the_intersections_are_gsplats_then_pads_of_the_last_tile(cameras, seed):
    width, height = 100, 70
    tile_width, tile_height = _tiles(width, height)
    means2d, radii, depths = _scene(cameras, 300, width, height, seed)
    reference_tiles, reference_ids, reference_flatten = _isect_tiles(
        means2d, radii, depths, TILE, tile_width, tile_height
    )
    n = reference_ids.numel()
    capacity, sentinel = n + 97, cameras * 300 - 1
    tiles, ids, flatten, count, overflow = padded_isect_tiles(
        means2d, radii, depths, TILE, tile_width, tile_height, capacity, sentinel
    )
    assert int(count) == n and not bool(overflow)
    assert torch.equal(tiles, reference_tiles)
    assert torch.equal(ids[:n], reference_ids) and torch.equal(flatten[:n], reference_flatten)
    tile_n_bits = (tile_width * tile_height).bit_length()
    last_tile = ((cameras - 1) << (32 + tile_n_bits)) | ((tile_width * tile_height - 1) << 32)
    assert torch.all(ids[n:] == last_tile | PAD_DEPTH_BITS) and torch.all(flatten[n:] == sentinel)
    # every tile starts where it did: the pads lengthen only the last tile, which reads to the buffer's end
    assert torch.equal(
        _isect_offset_encode(ids, cameras, tile_width, tile_height),
        _isect_offset_encode(reference_ids, cameras, tile_width, tile_height),
    )


def test_a_count_past_the_capacity_is_flagged_and_stays_within_the_tiles():
    width, height, cameras = 80, 64, 2
    tile_width, tile_height = _tiles(width, height)
    means2d, radii, depths = _scene(cameras, 200, width, height, 3)
    _, reference_ids, reference_flatten = _isect_tiles(means2d, radii, depths, TILE, tile_width, tile_height)
    n = reference_ids.numel()
    _, ids, flatten, count, overflow = padded_isect_tiles(
        means2d, radii, depths, TILE, tile_width, tile_height, n // 2, 0
    )
    assert int(count) == n and bool(overflow)
    assert torch.all(ids[1:] >= ids[:-1])
    # each kept intersection is one of gsplat's: a step cut short loses some, invents none
    reference = set(zip(reference_ids.tolist(), reference_flatten.tolist()))
    assert set(zip(ids.tolist(), flatten.tolist())) <= reference
    offsets = _isect_offset_encode(ids, cameras, tile_width, tile_height)  # in range: no camera past the last
    assert offsets.shape == (cameras, tile_height, tile_width) and int(offsets.max()) <= n // 2


def test_no_gaussian_drawn_gives_only_pads():
    width, height = 64, 48
    tile_width, tile_height = _tiles(width, height)
    means2d, radii, depths = _scene(1, 50, width, height, 4)
    _, ids, flatten, count, overflow = padded_isect_tiles(
        means2d, torch.zeros_like(radii), depths, TILE, tile_width, tile_height, 32, 49
    )
    assert int(count) == 0 and not bool(overflow)
    assert torch.all(flatten == 49)
    offsets = _isect_offset_encode(ids, 1, tile_width, tile_height)
    assert torch.all(offsets == 0)  # every tile empty; the last one's range is the pads, which draw nothing


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA for gsplat's kernels")
def test_on_the_gpu_no_host_read_and_the_render_of_gsplats_intersection():
    from gsplat.cuda._wrapper import isect_offset_encode, isect_tiles, rasterize_to_pixels

    width, height, cameras, n = 128, 96, 2, 2000
    tile_width, tile_height = _tiles(width, height)
    means2d, radii, depths = _scene(cameras, n, width, height, 5, "cuda")
    generator = torch.Generator().manual_seed(6)
    conics = torch.tensor([0.05, 0.0, 0.05]).repeat(cameras, n, 1).cuda()  # [C, N, 3]
    colors = torch.rand(cameras, n, 2, generator=generator).cuda()  # [C, N, 2]
    opacities = torch.rand(cameras, n, generator=generator).cuda()  # [C, N]
    tiles, ids, flatten = isect_tiles(means2d, radii, depths, TILE, tile_width, tile_height)
    count = ids.numel()
    expected, expected_alpha = rasterize_to_pixels(
        means2d, conics, colors, opacities, width, height, TILE,
        isect_offset_encode(ids, cameras, tile_width, tile_height), flatten,
    )  # fmt: skip
    # the sentinel: one more Gaussian per camera, zero opacity, drawing no tile of its own
    pad = lambda t, value: torch.cat((t, torch.full_like(t[:, :1], value)), dim=1)  # noqa: E731
    means2d_s, radii_s, depths_s = pad(means2d, 0.0), pad(radii, 0), pad(depths, 1.0)
    sentinel = (cameras - 1) * (n + 1) + n
    torch.cuda.synchronize()
    torch.cuda.set_sync_debug_mode("error")  # any host read in the intersection raises
    try:
        padded = padded_isect_tiles(means2d_s, radii_s, depths_s, TILE, tile_width, tile_height, count + 500, sentinel)
    finally:
        torch.cuda.set_sync_debug_mode("default")
    assert int(padded[3]) == count and not bool(padded[4])
    assert torch.equal(padded[0][:, :n], tiles)
    render, alpha = rasterize_to_pixels(
        means2d_s, pad(conics, 0.05), pad(colors, 0.0), pad(opacities, 0.0), width, height, TILE,
        isect_offset_encode(padded[1], cameras, tile_width, tile_height), padded[2],
    )  # fmt: skip
    assert torch.allclose(render, expected, atol=1e-6) and torch.allclose(alpha, expected_alpha, atol=1e-6)
