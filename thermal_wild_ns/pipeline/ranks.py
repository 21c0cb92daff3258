"""Which share of a scene this process trains when one scene is trained across GPUs.

`torchrun` starts one process per GPU and torch.distributed joins them in a process group; gsplat's
distributed rasterization reads that group, and so does this: rank `r` of `world` keeps every
`world`-th Gaussian from `r` on, and trains on every `world`-th image of each step's images
(`ThermalDatamanager.next_train`). One process without a group is rank 0 of 1: the same code runs
on one GPU unchanged. The launcher is `thermal_wild_ns.training.distributed`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, List

import torch
import torch.distributed as dist
from torch import Tensor


@dataclass(frozen=True)
class RankGroup:
    rank: int = 0
    world: int = 1

    @classmethod
    def current(cls) -> "RankGroup":
        """torch.distributed's process group (started by the launcher), else one rank of one."""
        if dist.is_available() and dist.is_initialized():
            return cls(dist.get_rank(), dist.get_world_size())
        return cls()

    @property
    def split(self) -> bool:
        return self.world > 1

    def own_rows(self, tensors: Dict[str, Tensor]) -> Dict[str, Tensor]:
        """This rank's rows (every `world`-th from `rank`) of per-Gaussian tensors [N, ...]."""
        return {name: t[self.rank :: self.world].contiguous() for name, t in tensors.items()}

    def image_slot(self, step: int) -> int:
        """This rank's position in the sequence of training images at `step`: each step trains
        `world` consecutive images of the order, one per rank."""
        return step * self.world + self.rank

    def gather_rows_on_host(self, tensor: Tensor, chunk_rows: int = 1 << 22) -> Tensor:
        """Every rank's `tensor` [N_r, ...] (row counts may differ) concatenated in rank order
        [sum N_r, ...], in host memory, on rank 0 (the other ranks get an empty tensor: they take part
        in the collective only). `chunk_rows` rows of each rank travel at a time: a model split across
        GPUs because it does not fit one does not fit one GPU gathered either."""
        if not self.split:
            return tensor.cpu()
        counts = [torch.zeros((), dtype=torch.int64, device=tensor.device) for _ in range(self.world)]
        dist.all_gather(counts, torch.tensor(tensor.shape[0], dtype=torch.int64, device=tensor.device))
        sizes: List[int] = [int(c) for c in counts]
        starts = [sum(sizes[:r]) for r in range(self.world)]
        chunk_rows = max(1, min(chunk_rows, max(sizes)))  # a small model travels in one piece of its own size
        out = torch.empty((sum(sizes) if self.rank == 0 else 0, *tensor.shape[1:]), dtype=tensor.dtype)
        for first in range(0, max(sizes), chunk_rows):
            own = tensor[first : first + chunk_rows]
            piece = tensor.new_zeros((chunk_rows, *tensor.shape[1:]))
            piece[: own.shape[0]] = own
            parts = [torch.empty_like(piece) for _ in range(self.world)]
            dist.all_gather(parts, piece)
            if self.rank == 0:
                for r, part in enumerate(parts):
                    n = min(max(sizes[r] - first, 0), chunk_rows)
                    out[starts[r] + first : starts[r] + first + n] = part[:n].cpu()
        return out

    def gather_stack(self, tensor: Tensor) -> Tensor:
        """Every rank's `tensor` (one shape on every rank) stacked in rank order [world, ...]."""
        if not self.split:
            return tensor[None]
        parts = [torch.empty_like(tensor) for _ in range(self.world)]
        dist.all_gather(parts, tensor.contiguous())
        return torch.stack(parts)

    def sum_gradients(self, params: List[torch.nn.Parameter]) -> None:
        """Sum the gradients of parameters every rank holds a copy of (the networks, the frame
        embeddings) over the ranks, in one collective: each rank's copy then has the gradient of the
        sum of every rank's loss, and Adam makes the same update on every rank. A parameter without
        a gradient on this rank counts as zero (the layout must be the same on every rank)."""
        if not self.split or not params:
            return
        flat = torch.cat([(p.grad if p.grad is not None else torch.zeros_like(p)).reshape(-1) for p in params])
        dist.all_reduce(flat)
        offset = 0
        for p in params:
            n = p.numel()
            summed = flat[offset : offset + n].view_as(p)
            if p.grad is None:
                p.grad = summed.clone()
            else:
                p.grad.copy_(summed)
            offset += n

    def differing(self, params: List[torch.nn.Parameter]) -> float:
        """The largest difference between this rank's copy of `params` and rank 0's (0 on one rank):
        copies kept equal by `sum_gradients` must show 0."""
        if not self.split or not params:
            return 0.0
        flat = torch.cat([p.detach().reshape(-1) for p in params])
        reference = flat.clone()
        dist.broadcast(reference, src=0)
        gap = (flat - reference).abs().max()
        dist.all_reduce(gap, op=dist.ReduceOp.MAX)
        return float(gap)

    def from_rank_0(self, value: float) -> float:
        """Rank 0's `value` on every rank (one decision for all, whatever each rank computed)."""
        if not self.split:
            return value
        box = [value]
        dist.broadcast_object_list(box, src=0)
        return float(box[0])

    def all_agree(self, flag: Tensor) -> Tensor:
        """Whether `flag` ([] bool on the device) is set on every rank, without a host sync (every
        rank gets the same answer: one decision for all)."""
        if not self.split:
            return flag
        value = flag.float()
        dist.all_reduce(value, op=dist.ReduceOp.MIN)
        return value > 0

    def any(self, flag: bool, device: torch.device) -> bool:
        """Whether `flag` is set on any rank (every rank gets the same answer: one decision for all)."""
        if not self.split:
            return flag
        value = torch.tensor(1.0 if flag else 0.0, device=device)
        dist.all_reduce(value, op=dist.ReduceOp.MAX)
        return bool(value > 0)
