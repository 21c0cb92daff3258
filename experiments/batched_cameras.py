"""`python -m experiments.batched_cameras`: what several cameras per training step could save.

The training step is bound by host work (Python, launches, a few syncs), not by the GPU: one camera per step pays
the host's share once per camera. gsplat renders a batch of cameras in one call (`viewmats` [C, 4, 4]), so C cameras
per step would pay it once per C. Before the model learns to train on batches, this measures the part that is pure
splatting: the scene's training cameras and seed points (the Gaussians sampled from them with jitter up to
`--gaussians`), scalar emission, an L1 loss against each camera's frame and its backward, for each batch size C:
- ms per step and per camera, timed over `--steps` steps synchronised at the two ends only (host and GPU
  overlapping, as in training);
- on CUDA, the GPU's own time per step (CUDA events around each step);
- the largest difference between a batch's renders and the same cameras rendered one at a time (a batch must
  render what single cameras do, or it is not the same training).
Writes `batched_cameras.json` and `batched_cameras.md` to `--output-dir`. The model's MLPs, per-frame state,
background and densification are not in it: what batching costs or saves there is the model's own question.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import torch
import tyro
from torch import Tensor

from experiments import device_name, synchronize, write_report
from experiments.scenes import scene_dataparser
from thermal_wild_ns.data.thermal_io import read_raw_frame
from thermal_wild_ns.rendering import world_to_camera
from thermal_wild_ns.rendering.backend import NEAR_PLANE, rasterization


@dataclass
class BatchedArgs:
    scene: str = "demo"
    """'demo', 'stress:FAULT' or a dataset folder (as in python -m experiments.bench)."""
    gaussians: int = 100_000
    """Gaussians to render (near the full method's at its fixed budget: `--auto-stop.grow-budget False`)."""
    batch_sizes: Tuple[int, ...] = (1, 2, 4, 8)
    """Cameras per step."""
    steps: int = 200
    """Timed steps per batch size (after `warmup_steps`)."""
    warmup_steps: int = 20
    downscale: int = 1
    """Render at 1/downscale of the frames' size (1: full size)."""
    output_dir: Path = Path("outputs/batched_cameras")
    cache_dir: Optional[Path] = None


def scene_views(args: BatchedArgs) -> Tuple[Tensor, Tensor, Tensor, int, int, Tensor]:
    """The scene's training views and seed points: (world-to-camera [F, 4, 4], K [F, 3, 3], frames [F, H, W, 1],
    width, height, points [P, 3]) at 1/`downscale` of the frames' size."""
    config = scene_dataparser(args.scene, args.output_dir, args.cache_dir or args.output_dir / "cache")
    outputs = config.setup().get_dataparser_outputs("train")
    cameras = outputs.cameras
    cameras.rescale_output_resolution(1.0 / args.downscale)
    width, height = int(cameras.width[0]), int(cameras.height[0])
    viewmats = world_to_camera(cameras.camera_to_worlds)  # [F, 4, 4]
    Ks = cameras.get_intrinsics_matrices()  # [F, 3, 3]
    frames = []
    for path in outputs.image_filenames:
        frame = torch.as_tensor(read_raw_frame(Path(path)), dtype=torch.float32)[None, None]  # [1, 1, H0, W0]
        frames.append(torch.nn.functional.interpolate(frame, size=(height, width), mode="area")[0, 0, :, :, None])
    frames = torch.stack(frames)
    frames = (frames - frames.amin()) / (frames.amax() - frames.amin()).clamp_min(1e-6)  # [F, H, W, 1] in [0, 1]
    points = torch.as_tensor(outputs.metadata["points3D_xyz"], dtype=torch.float32)  # [P, 3]
    return viewmats, Ks, frames, width, height, points


def random_gaussians(points: Tensor, count: int, seed: int = 0) -> Dict[str, Tensor]:
    """`count` Gaussians about the seed points [P, 3]: each a point with jitter of a tenth of the points' median
    spacing, isotropic at that scale, opacity 0.5, a random scalar emission (leaves that take gradients)."""
    g = torch.Generator().manual_seed(seed)
    spacing = float(torch.cdist(points[:512], points[:512]).topk(2, largest=False).values[:, 1].median())
    picked = points[torch.randint(len(points), (count,), generator=g)]
    return {
        "means": picked + torch.randn(count, 3, generator=g) * spacing * 0.1,  # [N, 3]
        "quats": torch.nn.functional.normalize(torch.randn(count, 4, generator=g), dim=1),  # [N, 4]
        "scales": torch.full((count, 3), max(spacing, 1e-4)),  # [N, 3]
        "opacities": torch.full((count,), 0.5),  # [N]
        "colors": torch.rand(count, 1, generator=g),  # [N, 1]
    }


def render(gaussians: Dict[str, Tensor], viewmats: Tensor, Ks: Tensor, width: int, height: int) -> Tensor:
    """The cameras' renders [C, H, W, 1] in one rasterization call (gsplat's on CUDA, the torch one elsewhere)."""
    colors, _, _ = rasterization(
        means=gaussians["means"],
        quats=gaussians["quats"],
        scales=gaussians["scales"],
        opacities=gaussians["opacities"],
        colors=gaussians["colors"],
        viewmats=viewmats,
        Ks=Ks,
        width=width,
        height=height,
        near_plane=NEAR_PLANE,
        packed=False,
    )
    return colors


def batch_difference(gaussians: Dict[str, Tensor], viewmats: Tensor, Ks: Tensor, width: int, height: int) -> float:
    """Largest |render| difference between the cameras rendered in one call and one at a time."""
    with torch.no_grad():
        together = render(gaussians, viewmats, Ks, width, height)
        one_at_a_time = [render(gaussians, viewmats[i : i + 1], Ks[i : i + 1], width, height) for i in range(len(Ks))]
        alone = torch.cat(one_at_a_time)
    return float((together - alone).abs().max())


def time_batch(gaussians, viewmats, Ks, frames, width, height, size: int, steps: int, warmup: int) -> Dict[str, float]:
    """ms per step and per camera of `size` cameras a step (render, L1 loss, backward), cycling over the views."""
    params = {k: v.clone().requires_grad_(True) for k, v in gaussians.items()}
    cuda = viewmats.is_cuda

    def step(i: int) -> None:
        pick = torch.arange(i * size, (i + 1) * size, device=viewmats.device) % len(Ks)
        loss = (render(params, viewmats[pick], Ks[pick], width, height) - frames[pick]).abs().mean()
        loss.backward()
        for p in params.values():
            p.grad = None

    for i in range(warmup):
        step(i)
    synchronize()
    events = []
    start = time.perf_counter()
    for i in range(steps):
        if cuda:
            begin, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
            begin.record()
        step(warmup + i)
        if cuda:
            end.record()
            events.append((begin, end))
    synchronize()
    wall_ms = (time.perf_counter() - start) * 1000 / steps
    gpu_ms: List[float] = [b.elapsed_time(e) for b, e in events]
    result = {"cameras": size, "ms_per_step": wall_ms, "ms_per_camera": wall_ms / size}
    if gpu_ms:
        result["gpu_ms_per_step"] = sum(gpu_ms) / len(gpu_ms)
    return result


def report(result: dict) -> str:
    lines = [
        f"# Several cameras per step, splatting alone ({result['device']})",
        "",
        f"Scene `{result['scene']}`, {result['gaussians']:,} Gaussians, {result['width']}x{result['height']}, "
        f"{result['steps']} steps per batch size; a batch against its cameras one at a time: largest difference "
        f"{result['batch_difference']:.2e}.",
        "",
        "| cameras per step | ms per step | ms per camera | GPU ms per step | per camera against one a step |",
        "| --- | --- | --- | --- | --- |",
    ]
    single = result["rows"][0]["ms_per_camera"]
    for row in result["rows"]:
        gpu = f"{row['gpu_ms_per_step']:.2f}" if "gpu_ms_per_step" in row else "—"
        lines.append(
            f"| {row['cameras']} | {row['ms_per_step']:.2f} | {row['ms_per_camera']:.2f} | {gpu} | "
            f"{row['ms_per_camera'] / single:.2f}x |"
        )
    return "\n".join(lines) + "\n"


def main(args: BatchedArgs) -> dict:
    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    viewmats, Ks, frames, width, height, points = scene_views(args)
    viewmats, Ks, frames = viewmats.to(device), Ks.to(device), frames.to(device)
    gaussians = {k: v.to(device) for k, v in random_gaussians(points, args.gaussians).items()}
    checked = min(max(args.batch_sizes), len(Ks))
    result = {
        "device": device_name(),
        "scene": args.scene,
        "gaussians": args.gaussians,
        "width": width,
        "height": height,
        "steps": args.steps,
        "batch_difference": batch_difference(gaussians, viewmats[:checked], Ks[:checked], width, height),
        "rows": [
            time_batch(gaussians, viewmats, Ks, frames, width, height, size, args.steps, args.warmup_steps)
            for size in args.batch_sizes
        ],
    }
    args.output_dir.mkdir(parents=True, exist_ok=True)
    (args.output_dir / "batched_cameras.json").write_text(json.dumps(result, indent=1))
    write_report(args.output_dir / "batched_cameras.md", report(result))
    return result


if __name__ == "__main__":
    main(tyro.cli(BatchedArgs))
