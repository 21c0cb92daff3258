"""A tile intersection of fixed size, the piece a whole training step needs to be one CUDA graph (docs/design.md).

gsplat 1.4.0's `isect_tiles` reads its intersection count back to the host to size its buffers, which a CUDA graph
cannot hold. `padded_isect_tiles` gives the same sorted intersections in buffers of a fixed `capacity`, with no
host read: each slot finds its Gaussian by a search of the cumulative count. The slots past the count are padding
that gsplat's `isect_offset_encode` and `rasterize_to_pixels` accept: the rasterizer's last tile of the last camera
reads to the end of the buffer (its range ends at the buffer's length, not at an offset), so the pads are that
tile's entries (sorted after its own by the largest depth bits) and point at `sentinel`, a Gaussian the caller
gives zero opacity. Where the count passes the capacity the intersections are cut short and `overflow` says so, on
the device. A prototype, not used by the package yet: `tests/test_padded_isect.py` checks it against gsplat's own
torch reference (`gsplat.cuda._torch_impl._isect_tiles`) on a CPU and against its CUDA function on a GPU.

    python -m experiments.padded_isect   # one random scene: the intersections against gsplat's reference
"""

from typing import Tuple

import torch
from torch import Tensor

from thermal_wild_ns.rendering.torch_rasterizer import tile_in_rectangle, tile_rectangles

PAD_DEPTH_BITS = 0x7FFFFFFF
"""The pads' depth bits: above every finite positive float32's (those of the Gaussians in front of the camera)."""


def padded_isect_tiles(
    means2d: Tensor,  # [C, N, 2]
    radii: Tensor,  # [C, N]
    depths: Tensor,  # [C, N], float32
    tile_size: int,
    tile_width: int,
    tile_height: int,
    capacity: int,
    sentinel: int,
) -> Tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """gsplat 1.4.0's `isect_tiles(means2d, radii, depths, ..., sort=True)` (non-packed) in buffers of `capacity`
    slots: tiles_per_gauss [C, N] (int32), isect_ids [capacity] (int64: camera | tile | depth's bits, sorted),
    flatten_ids [capacity] (int32, index into C * N), the count [] (int64) and overflow [] (bool: the count passed
    the capacity, the intersections cut short). Slots past the count: the last camera's last tile, the largest
    depth bits, `sentinel` (a flattened index the caller gives zero opacity)."""
    C, N = radii.shape
    tile_n_bits = (tile_width * tile_height).bit_length()
    lo, extent, tiles_per_gauss = tile_rectangles(
        means2d.reshape(-1, 2), radii.reshape(-1), tile_size, tile_width, tile_height
    )  # [C * N, 2], [C * N, 2], [C * N]
    cumulative = torch.cumsum(tiles_per_gauss, 0)  # [C * N]
    count = cumulative[-1]  # [], on the device: never read here
    slots = torch.arange(capacity, device=means2d.device)  # [S]
    owner = torch.searchsorted(cumulative, slots, right=True)  # [S], C * N past the count
    padded = owner >= C * N  # [S]
    owner = owner.clamp(max=C * N - 1)
    local = slots - (cumulative[owner] - tiles_per_gauss[owner])  # [S], the slot's place in its Gaussian's rectangle
    tile = tile_in_rectangle(lo, extent, owner, local, tile_width)  # [S]
    camera = owner // N  # [S]
    depth_bits = depths.reshape(-1).view(torch.int32).long()[owner]  # [S], sign-extended as gsplat's kernel
    tile = torch.where(padded, tile_width * tile_height - 1, tile)
    camera = torch.where(padded, C - 1, camera)
    depth_bits = torch.where(padded, PAD_DEPTH_BITS, depth_bits)
    isect_ids = (camera << (32 + tile_n_bits)) | (tile << 32) | depth_bits  # [S]
    flatten_ids = torch.where(padded, sentinel, owner).int()  # [S]
    isect_ids, order = torch.sort(isect_ids, stable=True)  # stable: ties in the order written, as a radix sort's
    return tiles_per_gauss.reshape(C, N).int(), isect_ids, flatten_ids[order], count, count > capacity


def main() -> None:
    import argparse

    from gsplat.cuda._torch_impl import _isect_tiles

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cameras", type=int, default=2)
    parser.add_argument("--gaussians", type=int, default=200, help="per camera")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    generator = torch.Generator().manual_seed(args.seed)
    C, N, width, height, tile_size = args.cameras, args.gaussians, 96, 64, 16
    means2d = torch.rand(C, N, 2, generator=generator) * torch.tensor([width, height])  # [C, N, 2]
    radii = (torch.rand(C, N, generator=generator) * 12).int()  # [C, N]
    depths = torch.rand(C, N, generator=generator) + 0.5  # [C, N]
    tile_width, tile_height = -(-width // tile_size), -(-height // tile_size)
    reference = _isect_tiles(means2d, radii, depths, tile_size, tile_width, tile_height)
    n = reference[1].numel()
    ours = padded_isect_tiles(means2d, radii, depths, tile_size, tile_width, tile_height, n + 64, C * N - 1)
    same = torch.equal(ours[1][:n], reference[1]) and torch.equal(ours[2][:n], reference[2])
    print(f"{n} intersections, capacity {n + 64}: count {int(ours[3])}, the same as gsplat's reference: {same}")


if __name__ == "__main__":
    main()
