"""`python -m experiments.step_floor`: the floor under a training step, gsplat's own.

How much of the full method's step would any Gaussian-splatting step in Python pay, on the host and on
the GPU, and how much is the method's own? This trains a method on a scene for
`--warmup` steps of the full 30k schedule (as `profile_step`), then alternates, `--rounds` times,
`--steps` of the method's own steps (nerfstudio's loop, as the bench runs it) with `--steps` of the least
a splatting step does on the same Gaussians, training cameras, frames and resolution: gsplat's
`rasterization` (through `thermal_wild_ns.rendering`, as the model calls it) of a learnable scalar per
Gaussian, an L1 loss against the frame, backward, and torch's fused Adam over the five tensors. No
emission MLP, background, camera model, SSIM, divergence guard, densification or logging: what is left
over between the two arms is what the method adds on top of that floor. Both arms' GPU kernel time per
step comes from torch.profiler over `--profile-steps` steps after the last round.

Writes `step_floor.json` and `step_floor.md` to `--output-dir`.

    python -m experiments.step_floor --scene .data/dunr --cache-dir .data/cache --output-dir OUT
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import torch
import torch.nn.functional as F
import tyro

from experiments import gpu_kernel_microseconds, mean_range, synchronize, write_report
from experiments.profile_step import full_schedule_trainer, measurement_header, train_measuring
from thermal_wild_ns.model.renders import training_view
from thermal_wild_ns.rendering import FAR_PLANE, NEAR_PLANE, rasterization


@dataclass
class FloorArgs:
    scene: str = "demo"
    """'demo', 'stress:FAULT' or a dataset folder (as in python -m experiments.bench)."""
    method: str = "wild-thermal"
    """The method whose step is set against the floor."""
    warmup: int = 3000
    """Steps of the method trained before the first round (densification has grown the model by then)."""
    steps: int = 500
    """Steps per arm per round, timed with the GPU synchronised at their two ends only."""
    rounds: int = 3
    """Rounds of the two arms, alternated (the host's pace drifts within a call)."""
    profile_steps: int = 20
    """Steps of each arm recorded by torch.profiler after the last round, for GPU kernel time (0: none)."""
    cameras: int = 8
    """Training cameras the floor cycles through (each with its frame at the step's resolution)."""
    set: Tuple[str, ...] = ()
    """Settings of the method's config, as the bench's `--set`."""
    output_dir: Path = Path("outputs/step_floor")
    cache_dir: Optional[Path] = None


class SplattingFloor:
    """The least step of Gaussian splatting on a model's current Gaussians: its means, rotations, log
    scales and opacity logits copied as fresh leaf tensors, a scalar colour per Gaussian (starting at the
    frames' mean, so the loss has something to fit), fused Adam (torch's; plain Adam off CUDA)."""

    LEARNING_RATES = {"means": 1.6e-4, "quats": 1e-3, "scales": 5e-3, "opacities": 5e-2, "colors": 2.5e-3}
    """Splatfacto's learning rates (its colour's for the scalar)."""

    def __init__(self, model, views: List[Tuple[torch.Tensor, torch.Tensor, torch.Tensor]]):
        """`views`: (viewmat [1, 4, 4], K [1, 3, 3], frame [H, W, 1]) per camera, all at one size."""
        self.views = views
        self.height, self.width = views[0][2].shape[:2]
        mean_level = torch.stack([frame.mean() for _, _, frame in views]).mean()
        n = model.num_points
        self.params = {
            "means": model.means.detach().clone(),  # [N, 3]
            "quats": model.quats.detach().clone(),  # [N, 4]
            "scales": model.scales.detach().clone(),  # [N, 3]
            "opacities": model.opacities.detach().clone().reshape(n),  # [N]
            "colors": mean_level.expand(n, 1).clone(),  # [N, 1]
        }
        for tensor in self.params.values():
            tensor.requires_grad_(True)
        cuda = self.params["means"].is_cuda
        self.optimizer = torch.optim.Adam(
            [{"params": [p], "lr": self.LEARNING_RATES[name]} for name, p in self.params.items()],
            eps=1e-15,
            fused=cuda or None,
        )
        self.losses: List[torch.Tensor] = []  # [] each, read back after the timed steps

    def step(self, index: int) -> None:
        viewmat, K, frame = self.views[index % len(self.views)]
        p = self.params
        render, _, _ = rasterization(
            means=p["means"],
            quats=p["quats"],
            scales=torch.exp(p["scales"]),
            opacities=torch.sigmoid(p["opacities"]),
            colors=p["colors"],
            viewmats=viewmat,
            Ks=K,
            width=self.width,
            height=self.height,
            packed=False,
            near_plane=NEAR_PLANE,
            far_plane=FAR_PLANE,
            render_mode="RGB",
        )  # [1, H, W, 1]
        loss = (render[0] - frame).abs().mean()
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        self.losses.append(loss.detach())


def floor_views(trainer, cameras: int, step: int) -> List[Tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
    """The next `cameras` training cameras of the run as its step sees them (pose, intrinsics at the
    step's resolution) with their frames resized to that size (area averaging)."""
    model, datamanager = trainer.pipeline.model, trainer.pipeline.datamanager
    views = []
    with torch.no_grad():
        for k in range(cameras):
            camera, data = datamanager.next_train(step + k)
            view = training_view(model.parts, model.scene(), camera)  # as the step poses it
            frame = data["image"].to(model.device).float()  # [H0, W0, 1]
            if frame.shape[:2] != (view.height, view.width):
                frame = F.interpolate(frame.permute(2, 0, 1)[None], size=(view.height, view.width), mode="area")
                frame = frame[0].permute(1, 2, 0)  # [H, W, 1]
            views.append((view.viewmat, view.K, frame.contiguous()))
    return views


class _Rounds:
    """After-step hook of one `Trainer.train` run: after `warmup` steps, `rounds` windows of `steps` of
    the method's steps, each followed (inside the hook, the run paused) by `steps` floor steps on the
    model as it is then; then `profile_steps` of each arm under torch.profiler."""

    def __init__(self, trainer, args: FloorArgs):
        self.trainer, self.args = trainer, args
        self.cuda = torch.cuda.is_available()
        self.rows: List[Dict] = []
        self.kernel_ms: Dict[str, float] = {}
        self.measuring = False
        self.prof = None
        self.window_end = args.warmup + args.steps
        self.last_round_end = args.warmup + args.rounds * args.steps
        self.total = self.last_round_end + (args.profile_steps if self.cuda else 0)

    def __call__(self, step: int) -> None:
        done = step + 1
        if done == self.args.warmup:
            self.measuring = True
            synchronize()
            self.clock = time.perf_counter()
        elif done == self.window_end and done <= self.last_round_end:
            synchronize()
            method_ms = 1000 * (time.perf_counter() - self.clock) / self.args.steps
            floor = SplattingFloor(self.trainer.pipeline.model, floor_views(self.trainer, self.args.cameras, done))
            floor_ms = self._time_floor(floor, self.args.steps)
            losses = torch.stack(floor.losses).tolist()
            self.rows.append(
                {
                    "round": len(self.rows) + 1,
                    "last_step": step,
                    "gaussians": int(self.trainer.pipeline.model.num_points),
                    "resolution": [floor.width, floor.height],
                    "method_ms_per_step": round(method_ms, 3),
                    "floor_ms_per_step": round(floor_ms, 3),
                    "floor_loss_first_last": [losses[0], losses[-1]],
                }
            )
            self.window_end += self.args.steps
            if done == self.last_round_end and self.cuda and self.args.profile_steps:
                self.floor = floor
                self.prof = self._profiler()
                self.prof.start()
            synchronize()
            self.clock = time.perf_counter()
        if done == self.total and self.prof is not None:
            synchronize()
            self.prof.stop()
            self.kernel_ms["method"] = gpu_kernel_microseconds(self.prof) / 1000 / self.args.profile_steps
            with self._profiler() as prof:
                self._time_floor(self.floor, self.args.profile_steps)
            self.kernel_ms["floor"] = gpu_kernel_microseconds(prof) / 1000 / self.args.profile_steps
        if done == self.total:
            self.measuring = False

    @staticmethod
    def _time_floor(floor: SplattingFloor, steps: int) -> float:
        for k in range(3):  # gsplat's and Adam's first calls (kernel loads, allocations) are not the floor
            floor.step(k)
        floor.losses.clear()
        synchronize()
        start = time.perf_counter()
        for k in range(steps):
            floor.step(k)
        synchronize()
        return 1000 * (time.perf_counter() - start) / steps

    @staticmethod
    def _profiler():
        from torch.profiler import ProfilerActivity, profile

        return profile(activities=[ProfilerActivity.CPU, ProfilerActivity.CUDA])


def main(args: FloorArgs) -> Dict:
    trainer = full_schedule_trainer(args.scene, args.method, args.set, args.output_dir, args.cache_dir)
    rounds = _Rounds(trainer, args)
    train_measuring(trainer, rounds.total, rounds)
    method = [r["method_ms_per_step"] for r in rounds.rows]
    floor = [r["floor_ms_per_step"] for r in rounds.rows]
    result = {
        **measurement_header(args),
        "steps_per_round": args.steps,
        "rounds": rounds.rows,
        "method_ms_per_step": mean_range(method),
        "floor_ms_per_step": mean_range(floor),
        "gpu_kernel_ms_per_step": {k: round(v, 3) for k, v in rounds.kernel_ms.items()},
    }
    (args.output_dir / "step_floor.json").write_text(json.dumps(result, indent=1))
    write_report(args.output_dir / "step_floor.md", _markdown(result))
    return result


def _markdown(r: Dict) -> str:
    kernels = r["gpu_kernel_ms_per_step"]
    lines = [
        f"# {r['method']}'s step against gsplat's floor on {r['scene']} ({r['device']}, torch {r['torch']})",
        "",
        f"After {r['warmup']} steps; {r['steps_per_round']} steps per arm per round, the arms alternated.",
        "",
        "| round | last step | Gaussians | resolution | method ms/step | floor ms/step |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    lines += [
        f"| {x['round']} | {x['last_step']} | {x['gaussians']:,} | {x['resolution'][0]}x{x['resolution'][1]} | "
        f"{x['method_ms_per_step']:.2f} | {x['floor_ms_per_step']:.2f} |"
        for x in r["rounds"]
    ]
    lines += ["", f"Mean (min–max): method {r['method_ms_per_step']}, floor {r['floor_ms_per_step']} ms/step."]
    if kernels:
        lines += [f"GPU kernels per step: method {kernels['method']:.2f} ms, floor {kernels['floor']:.2f} ms."]
    return "\n".join(lines) + "\n"


def entrypoint():
    main(tyro.cli(FloorArgs))


if __name__ == "__main__":
    entrypoint()
