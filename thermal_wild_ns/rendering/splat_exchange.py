"""What the pure-PyTorch rasterizer (`torch_rasterizer.py`) sends between GPUs when one scene's Gaussians are
split across them, as gsplat's distributed rasterization does: the cameras to every rank, and each camera's
splats to the rank that renders it (differentiable: gradients go back to the Gaussians' owners)."""

from __future__ import annotations

from typing import Tuple

import torch
import torch.distributed as dist
import torch.distributed.nn.functional as dist_autograd
from torch import Tensor


def all_gather_rows(x: Tensor) -> Tensor:
    """Every rank's `x` [C, ...] stacked in rank order [world * C, ...] (the same C on every rank)."""
    parts = [torch.empty_like(x) for _ in range(dist.get_world_size())]
    dist.all_gather(parts, x.contiguous())
    return torch.cat(parts)


def exchange_splats(c_local: int, radii: Tensor, *values: Tensor) -> Tuple[Tensor, ...]:
    """Send each camera's splats to the rank that renders it: every input is [C_world, N, ...] (this
    rank's Gaussians in every rank's cameras, `c_local` cameras per rank, in rank order); every output
    is [c_local, N_world, ...] (every rank's Gaussians in this rank's cameras, ranks' Gaussians in rank
    order, as gsplat's `gaussian_ids` offsets them). Differentiable in `values` (gradients go back to
    the Gaussians' owners); `radii` is not."""
    world = dist.get_world_size()
    counts = [torch.zeros((), dtype=torch.int64) for _ in range(world)]
    dist.all_gather(counts, torch.tensor(radii.shape[1], dtype=torch.int64).to(radii.device))
    sizes = [int(n) for n in counts]

    widest = max(sizes)

    def exchange(x: Tensor) -> Tensor:
        # padded to the largest rank's count: torch's all_to_all on gloo (scatters) moves equal sizes only
        padded = torch.cat([x, x.new_zeros((x.shape[0], widest - x.shape[1], *x.shape[2:]))], dim=1)
        send = [chunk.contiguous() for chunk in padded.split(c_local, dim=0)]  # [c_local, widest, ...] per rank
        receive = [padded.new_empty((c_local, widest, *x.shape[2:])) for _ in sizes]
        received = dist_autograd.all_to_all(receive, send)
        return torch.cat([part[:, :n] for part, n in zip(received, sizes)], dim=1)

    return tuple(exchange(x) for x in (radii, *values))


def exchange_visible(c_local: int, n_local: int, camera_ids: Tensor, gaussian_ids: Tensor, *values: Tensor):
    """Packed splats [nnz, ...] of this rank's Gaussians in every rank's cameras (`camera_ids` global,
    camera-major) sent to the ranks that render those cameras. Returns camera ids (local to the
    receiving rank), Gaussian ids (global: ranks' Gaussians in rank order) and `values`, each [nnz', ...].
    Differentiable in `values`."""
    world, rank = dist.get_world_size(), dist.get_rank()
    device = camera_ids.device
    counts = torch.bincount(camera_ids // c_local, minlength=world)  # [W]: splats for each rank
    table = [torch.zeros(world + 1, dtype=torch.int64, device=device) for _ in range(world)]
    dist.all_gather(table, torch.cat([counts, torch.tensor([n_local], device=device)]))
    matrix = torch.stack(table).tolist()  # [source][destination], the source's Gaussian count last
    widest = max(max(row[:world]) for row in matrix)
    offsets = [0]
    for row in matrix[:-1]:
        offsets.append(offsets[-1] + row[world])  # first global id of each rank's Gaussians

    def exchange(x: Tensor) -> Tensor:
        # padded to the largest count: torch's all_to_all on gloo (scatters) moves equal sizes only
        send = [
            torch.cat([part, part.new_zeros((widest - part.shape[0], *part.shape[1:]))])
            for part in x.split(matrix[rank][:world])
        ]
        receive = [x.new_empty((widest, *x.shape[1:])) for _ in range(world)]
        received = dist_autograd.all_to_all(receive, send)
        return torch.cat([part[: matrix[source][rank]] for source, part in enumerate(received)])

    cameras = exchange(camera_ids) - rank * c_local
    return (cameras, exchange(gaussian_ids + offsets[rank]), *(exchange(v) for v in values))
