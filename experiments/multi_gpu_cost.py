"""`torchrun --nproc-per-node N -m experiments.multi_gpu_cost`: one scene's training step on N GPUs.

The synthetic survey of `--frames` frames, trained as `thermal_wild_ns.multi_gpu` trains it (the
Gaussians split across the ranks, one image per rank per step); for each total Gaussian count the
model is resampled to it (each rank its share, densification off so the count holds) and `--steps`
steps are timed: ms per step, images per second (N per step), and each GPU's peak memory, until the
first count that does not fit (recorded). Run it with N = 1 and N = 2 on one host: the same counts,
the same code. Rank 0 writes `multi_gpu_cost_{N}.json` to `--output-dir` and prints it.

`--train-at G --train-steps K` then trains the survey at G Gaussians (e.g. a count one GPU does not
hold) for K steps at full resolution, with the divergence guard as the launcher runs it, scores the
automatic stop's held-back frames with every rank rendering (before, and every `--score-every` steps)
and writes the run's checkpoint (gathered on rank 0's host): `multi_gpu_train_{N}.json`.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, Tuple

import torch
import torch.distributed as dist
import tyro

from experiments import device_name
from experiments.survey_cost import initial_gaussians, resample_gaussians, timed_steps, training_step
from thermal_wild_ns.data.dataparsers import ThermalDemoDataParserConfig
from thermal_wild_ns.data.survey_scene import SurveySceneConfig, generate_survey_scene
from thermal_wild_ns.method_configs import method_trainer
from thermal_wild_ns.multi_gpu import join_process_group, multi_gpu_config
from thermal_wild_ns.pipeline.ranks import RankGroup
from thermal_wild_ns.training.held_back import held_back_score
from thermal_wild_ns.training.trainer import seeded_trainer


@dataclass
class MultiGpuCostArgs:
    frames: int = 1000
    gaussians: Tuple[int, ...] = (4_000_000, 16_000_000, 32_000_000, 48_000_000, 64_000_000)
    """Total Gaussian counts (over every GPU), in increasing order."""
    steps: int = 20
    output_dir: Path = Path("outputs/multi_gpu_cost")
    train_at: int = 0
    """Total Gaussian count to train at after the sweep (0: no training)."""
    train_steps: int = 1000
    score_every: int = 250


def main(args: MultiGpuCostArgs) -> Dict:
    ranks = join_process_group("cuda" if torch.cuda.is_available() else "cpu")
    data = args.output_dir / f"survey_{args.frames}"
    if ranks.rank == 0:
        generate_survey_scene(data, SurveySceneConfig(num_frames=args.frames))
    dist.barrier()
    config = method_trainer("wild-thermal")
    config.output_dir = args.output_dir / "runs"
    config.max_num_iterations = 10**9
    config.pipeline.datamanager.dataparser = ThermalDemoDataParserConfig(
        data=data, scene="survey", survey_frames=args.frames
    )
    config.pipeline.datamanager.preprocessing_cache = args.output_dir / "cache"
    config.pipeline.model.max_gaussians = max(args.gaussians)
    config.auto_stop.grow_budget = False  # the sizes measured are fixed ones
    split = multi_gpu_config(config, ranks.world)
    split.timestamp = "cost"
    start = time.perf_counter()
    if ranks.rank != 0:  # rank 0 first: it preprocesses and caches what the others read (as multi_gpu.main)
        dist.barrier()
    trainer = seeded_trainer(split, local_rank=int(os.environ.get("LOCAL_RANK", 0)))
    if ranks.rank == 0:
        dist.barrier()
    setup = time.perf_counter() - start
    strategy = trainer.pipeline.model.strategy
    settled = trainer.pipeline.model.settled_step  # the schedule's, before densification is switched off
    strategy.refine_start_iter = strategy.reset_every = 10**9
    seeds = initial_gaussians(trainer)
    rows, step, limit = [], 0, None
    for n in args.gaussians:
        fits = torch.ones(())
        try:
            resample_gaussians(trainer, seeds, n // ranks.world, seed=ranks.rank)
            if torch.cuda.is_available():
                torch.cuda.empty_cache()
                torch.cuda.reset_peak_memory_stats()
            ms = timed_steps(trainer, step, args.steps)
            step += args.steps + 5
        except torch.OutOfMemoryError as err:
            fits = torch.zeros(())
            limit = f"GPU memory at {n:,} Gaussians: {str(err).splitlines()[0][:160]}"
        device = trainer.pipeline.model.device
        if ranks.split:  # every rank learns whether all fitted (an OOM on one rank ends the sweep on all)
            fits = fits.to(device)
            dist.all_reduce(fits, op=dist.ReduceOp.MIN)
        if float(fits) == 0:
            break
        peak = torch.tensor(torch.cuda.max_memory_allocated() / 2**30 if torch.cuda.is_available() else 0.0)
        peaks = ranks.gather_stack(peak.to(device)).tolist()
        rows.append(
            {
                "gaussians": n,
                "ms_per_step": round(ms, 2),
                "images_per_s": round(1000 * ranks.world / ms, 1),
                "gpu_peak_gib_per_rank": [round(p, 2) for p in peaks],
            }
        )
        if ranks.rank == 0:
            print(json.dumps(rows[-1]), flush=True)
    result = {
        "device": device_name(),
        "gpus": ranks.world,
        "frames": args.frames,
        "setup_s": round(setup, 1),
        "steps": args.steps,
        "counts": rows,
        "first_limit": limit,
    }
    if ranks.rank == 0:
        args.output_dir.mkdir(parents=True, exist_ok=True)
        (args.output_dir / f"multi_gpu_cost_{ranks.world}.json").write_text(json.dumps(result, indent=1))
        print(json.dumps(result, indent=1))
    if args.train_at:
        if ranks.rank == 0:
            split.save_config()  # config.yml beside the checkpoint: ns-viewer, ns-render, score_checkpoint load it
        trained = train_and_score(trainer, ranks, seeds, args, first=settled)
        if ranks.rank == 0:
            (args.output_dir / f"multi_gpu_train_{ranks.world}.json").write_text(json.dumps(trained, indent=1))
            print(json.dumps(trained, indent=1))
    dist.destroy_process_group()
    return result


def train_and_score(
    trainer, ranks: RankGroup, seeds: Dict[str, torch.Tensor], args: MultiGpuCostArgs, first: int
) -> Dict:
    """Train `args.train_steps` steps at `args.train_at` Gaussians (drawn from the survey's seeds, as
    the sweep draws them; densification stays off so the count holds) from step `first`, the schedule's
    settled step (full resolution), scoring the held-back frames on the way; then the run's checkpoint."""
    model = trainer.pipeline.model
    held_back = trainer.pipeline.datamanager.held_back
    trainer.auto_stop = None  # its frames stay held back; the scores below are its scores, without a stop
    resample_gaussians(trainer, seeds, args.train_at // ranks.world, seed=ranks.rank)
    if torch.cuda.is_available():
        torch.cuda.empty_cache()
        torch.cuda.reset_peak_memory_stats()
    scores = [{"step": first, "held_back_psnr": round(held_back_score(trainer.pipeline, held_back), 3)}]
    start = time.perf_counter()
    for step in range(first, first + args.train_steps):
        training_step(trainer, step)
        if (step + 1 - first) % args.score_every == 0:
            scores.append({"step": step + 1, "held_back_psnr": round(held_back_score(trainer.pipeline, held_back), 3)})
            if ranks.rank == 0:
                print(json.dumps(scores[-1]), flush=True)
    seconds = time.perf_counter() - start
    save_start = time.perf_counter()
    trainer.save_checkpoint(first + args.train_steps - 1)
    peak = torch.tensor(torch.cuda.max_memory_allocated() / 2**30 if torch.cuda.is_available() else 0.0)
    return {
        "device": device_name(),
        "gpus": ranks.world,
        "frames": args.frames,
        "gaussians": int(ranks.gather_stack(torch.tensor(model.num_points, device=model.device)).sum()),
        "steps": args.train_steps,
        "train_s": round(seconds, 1),
        "checkpoint_s": round(time.perf_counter() - save_start, 1),
        "checkpoint": str(trainer.checkpoint_dir),
        "held_back_frames": [trainer.pipeline.datamanager.train_dataset.frame_index(k) for k in held_back],
        "scores": scores,
        "guard_skipped_steps": trainer.guard.skipped,
        "guard_rollbacks": trainer.guard.rollbacks,
        "gpu_peak_gib_per_rank": [round(p, 2) for p in ranks.gather_stack(peak.to(model.device)).tolist()],
    }


if __name__ == "__main__":
    main(tyro.cli(MultiGpuCostArgs))
