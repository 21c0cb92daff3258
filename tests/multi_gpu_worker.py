"""One rank of test_multi_gpu's two-process check (run by torchrun on CPU, gloo): renders its camera of
a small scene with its half of the Gaussians through the pure-torch rasterizer's distributed mode, and
saves its render and gradients to OUT/rank{R}.pt."""

import sys
from pathlib import Path

import torch
import torch.distributed as dist

from thermal_wild_ns.pipeline.ranks import RankGroup
from thermal_wild_ns.rendering.torch_rasterizer import rasterization


def scene():
    """24 Gaussians in front of two cameras (the same on every rank), per-pixel loss weights [2, H, W, 2]."""
    g = torch.Generator().manual_seed(0)
    n = 24
    means = torch.randn(n, 3, generator=g) * 0.6 + torch.tensor([0.0, 0.0, 4.0])
    quats = torch.randn(n, 4, generator=g)
    scales = torch.rand(n, 3, generator=g) * 0.3 + 0.05
    opacities = torch.rand(n, generator=g) * 0.8 + 0.1
    colors = torch.rand(n, 2, generator=g)  # one channel per rank's camera, as the model gives them
    viewmats = torch.eye(4).repeat(2, 1, 1)
    viewmats[1, 0, 3] = 0.3  # the second camera a little to the side
    Ks = torch.tensor([[40.0, 0.0, 24.0], [0.0, 40.0, 16.0], [0.0, 0.0, 1.0]]).repeat(2, 1, 1)
    weights = torch.rand(2, 32, 48, 2, generator=g)
    return (
        {"means": means, "quats": quats, "scales": scales, "opacities": opacities, "colors": colors},
        viewmats,
        Ks,
        weights,
    )


def main(out: Path) -> None:
    dist.init_process_group("gloo")
    rank, world = dist.get_rank(), dist.get_world_size()
    params, viewmats, Ks, weights = scene()
    for packed in (False, True):
        own = {k: v[rank::world].clone().requires_grad_() for k, v in params.items()}
        render, alpha, meta = rasterization(
            **own,
            viewmats=viewmats[rank : rank + 1],
            Ks=Ks[rank : rank + 1],
            width=48,
            height=32,
            packed=packed,
            distributed=True,
        )
        meta["means2d"].retain_grad()
        loss = (render[0] * weights[rank]).sum() + alpha.sum()
        loss.backward()
        saved = {k: v.grad for k, v in own.items()}
        saved.update(render=render.detach(), means2d_grad=meta["means2d"].grad, n_cameras=meta["n_cameras"])
        saved.update({k: meta[k] for k in ("radii", "camera_ids", "gaussian_ids")})
        torch.save(saved, out / f"rank{rank}-packed{packed}.pt")
    ranks = RankGroup.current()  # the decisions taken once for all ranks (the guard's, the automatic stop's)
    decisions = {"any": ranks.any(rank == 1, torch.device("cpu")), "from_rank_0": ranks.from_rank_0(10.0 + rank)}
    decisions["all_agree"] = bool(ranks.all_agree(torch.tensor(rank == 0)))  # the guard's verdict: rank 1 rejects
    # a checkpoint's gather: rank 0 holds 5 rows, rank 1 holds 3, two rows of each rank at a time
    rows = torch.arange(5 if rank == 0 else 3, dtype=torch.float32)[:, None] + 100 * rank
    decisions["gathered"] = ranks.gather_rows_on_host(rows.repeat(1, 2), chunk_rows=2)
    torch.save(decisions, out / f"rank{rank}-decisions.pt")
    dist.destroy_process_group()


if __name__ == "__main__":
    main(Path(sys.argv[1]))
