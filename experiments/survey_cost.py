"""`python -m experiments.survey_cost`: how a survey's cost grows on one GPU, and where it stops.

For each survey size (frames of the synthetic drone survey, `data/survey_scene.py`, 640x512):
- generation and setup time (reading, preprocessing, caching the frames) and the host's peak memory;
- then, for each Gaussian count (the model resampled from its seeds to that count, densification
  off so the count holds): ms per training step of the full method (its lean step, as ns-train
  runs it) and the GPU's peak memory, until the first count that does not fit (the out-of-memory
  error is caught and recorded: the first limit hit).
Writes `cost.json` and `cost.md` to `--output-dir` and prints the table.
"""

from __future__ import annotations

import gc
import json
import re
import resource
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Tuple

import torch
import tyro
from nerfstudio.engine.callbacks import TrainingCallbackLocation

from experiments import device_name, synchronize, write_report
from experiments.bench import setup_trainer
from thermal_wild_ns._upstream import replace_gaussians
from thermal_wild_ns.data.dataparsers import ThermalDemoDataParserConfig
from thermal_wild_ns.data.survey_scene import SurveySceneConfig, generate_survey_scene
from thermal_wild_ns.method_configs import method_trainer
from thermal_wild_ns.training.checkpoints import snapshot


@dataclass
class CostArgs:
    frames: Tuple[int, ...] = (250, 1000, 4000)
    """Survey sizes (frames)."""
    gaussians: Tuple[int, ...] = (1_000_000, 4_000_000, 16_000_000, 32_000_000, 64_000_000)
    """Gaussian counts to time at each size, in increasing order (stops at the first that does not fit)."""
    steps: int = 20
    """Timed steps per count (after 5 untimed)."""
    method: str = "wild-thermal"
    output_dir: Path = Path("outputs/survey_cost")
    growth_steps: int = 0
    """After the sweep: train this many steps from the largest count that fitted with densification on
    and every Gaussian a candidate (refining every 10 steps, unbounded budget): does growth stop at the
    memory the device has, with its message (`BudgetedDefaultStrategy.memory_room`), or run out?"""


def _host_peak_gib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # KiB on Linux


def survey_trainer(args: CostArgs, frames: int):
    config = method_trainer(args.method)
    config.output_dir = args.output_dir / "runs"
    config.vis = "tensorboard"
    config.auto_stop.enabled = False
    config.max_num_iterations = 10**9
    config.pipeline.datamanager.dataparser = ThermalDemoDataParserConfig(
        data=args.output_dir / f"survey_{frames}", scene="survey", survey_frames=frames
    )
    config.pipeline.datamanager.preprocessing_cache = args.output_dir / "cache"
    config.pipeline.model.max_gaussians = max(args.gaussians)
    return setup_trainer(config)


def resample_gaussians(trainer, seeds: Dict[str, torch.Tensor], n: int, seed: int = 0) -> None:
    """Replace the model's Gaussians by `n` copies drawn from `seeds` (its Gaussians at setup; positions
    jittered by their size), with fresh optimizer moments and densification statistics. The old ones,
    and the guard's copy of them, are freed first."""
    model = trainer.pipeline.model
    trainer._healthy = None
    empty = {name: value[:0].clone() for name, value in seeds.items()}
    replace_gaussians(trainer.pipeline, trainer.optimizers, empty)  # the old ones freed before the new exist
    gc.collect()
    if torch.cuda.is_available():
        torch.cuda.empty_cache()
    g = torch.Generator(device=model.device).manual_seed(n + seed)
    pick = torch.randint(seeds["means"].shape[0], (n,), device=model.device, generator=g)
    values = {name: value[pick] for name, value in seeds.items()}
    values["means"] += torch.randn(values["means"].shape, device=model.device, generator=g) * torch.exp(
        values["scales"]
    )
    replace_gaussians(trainer.pipeline, trainer.optimizers, values)


def initial_gaussians(trainer) -> Dict[str, torch.Tensor]:
    """A copy of the model's Gaussians as set up (what `resample_gaussians` draws from)."""
    return {name: p.detach().clone() for name, p in trainer.pipeline.model.gauss_params.items()}


def training_step(trainer, step: int) -> None:
    """One training step with nerfstudio's callbacks around it, as its loop runs them."""
    for callback in trainer.callbacks:
        callback.run_callback_at_location(step, location=TrainingCallbackLocation.BEFORE_TRAIN_ITERATION)
    trainer.train_iteration(step)
    for callback in trainer.callbacks:
        callback.run_callback_at_location(step, location=TrainingCallbackLocation.AFTER_TRAIN_ITERATION)


def timed_steps(trainer, first: int, steps: int) -> float:
    """ms per step of `steps` training steps (after 5 untimed)."""
    for s in range(first, first + 5):
        training_step(trainer, s)
    synchronize()
    start = time.perf_counter()
    for s in range(first + 5, first + 5 + steps):
        training_step(trainer, s)
    synchronize()
    return 1000 * (time.perf_counter() - start) / steps


def growth_to_the_limit(trainer, seeds: Dict[str, torch.Tensor], start: int, step: int, steps: int) -> Dict:
    """Train `steps` steps from `start` Gaussians, every Gaussian a growth candidate at every 10th step
    (the guard's healthy copy taken first, as a run would have one): the memory estimate's cap, and the
    rollbacks of steps that ran out of memory anyway (`GuardedTrainer`), are what it reports."""
    model = trainer.pipeline.model
    strategy = model.strategy
    resample_gaussians(trainer, seeds, start)
    trainer._healthy = snapshot(trainer.pipeline, trainer.optimizers, step)
    strategy.max_gaussians = 10**10
    strategy.grow_grad2d = 1e-12
    strategy.refine_start_iter, strategy.refine_every, strategy.pause_refine_after_reset = step, 10, 0
    rollbacks, counts = trainer.guard.rollbacks, []
    try:
        for s in range(step, step + steps):
            training_step(trainer, s)
            counts.append(model.num_points)
        outcome = "trained every step"
    except (torch.OutOfMemoryError, SystemExit) as err:
        frames = traceback.extract_tb(err.__traceback__)[-6:]  # where it ran out: the frames nearest the error
        where = " < ".join(f"{Path(f.filename).name}:{f.lineno} {f.name}" for f in reversed(frames))
        outcome = f"stopped at {model.num_points:,} Gaussians: {str(err).splitlines()[0][:160]} (in {where})"
    return {
        "start": start,
        "end": model.num_points,
        "largest": max(counts, default=start),
        "memory_stopped_at": strategy.memory_stopped_at,
        "out_of_memory_rollbacks": trainer.guard.rollbacks - rollbacks,
        "outcome": outcome,
    }


def measure_survey(args: CostArgs, frames: int) -> Dict:
    start = time.perf_counter()
    generate_survey_scene(args.output_dir / f"survey_{frames}", SurveySceneConfig(num_frames=frames))
    generated = time.perf_counter() - start
    start = time.perf_counter()
    trainer = survey_trainer(args, frames)
    setup = time.perf_counter() - start
    model = trainer.pipeline.model
    strategy = model.strategy
    strategy.refine_start_iter = strategy.reset_every = 10**9  # the count holds while timed
    seeds = initial_gaussians(trainer)
    row: Dict = {
        "frames": frames,
        "site_m": [round(x) for x in SurveySceneConfig(num_frames=frames).site_size],
        "generate_s": round(generated, 1),
        "setup_s": round(setup, 1),
        "host_peak_gib_after_setup": round(_host_peak_gib(), 2),
        "gpu_gib_after_setup": round(torch.cuda.memory_allocated() / 2**30, 2) if torch.cuda.is_available() else None,
        "seeds": model.num_points,
        "counts": [],
    }
    step = 0
    for n in args.gaussians:
        try:
            resample_gaussians(trainer, seeds, n)
            if torch.cuda.is_available():
                torch.cuda.empty_cache()
                torch.cuda.reset_peak_memory_stats()
            ms = timed_steps(trainer, step, args.steps)
            step += args.steps + 5
            peak = torch.cuda.max_memory_allocated() / 2**30 if torch.cuda.is_available() else None
            row["counts"].append({"gaussians": n, "ms_per_step": round(ms, 2), "gpu_peak_gib": peak and round(peak, 2)})
            print(json.dumps({"frames": frames, **row["counts"][-1]}), flush=True)
        except (torch.OutOfMemoryError, SystemExit) as err:  # the trainer's own message, where it stops the run
            row["first_limit"] = f"GPU memory at {n:,} Gaussians: {str(err).splitlines()[0][:160]}"
            print(row["first_limit"], flush=True)
            break
    if args.growth_steps and row["counts"]:
        row["growth"] = growth_to_the_limit(trainer, seeds, row["counts"][-1]["gaussians"], step, args.growth_steps)
        print(json.dumps({"frames": frames, "growth": row["growth"]}), flush=True)
    row["host_peak_gib"] = round(_host_peak_gib(), 2)
    del trainer, model
    if torch.cuda.is_available():
        torch.cuda.empty_cache()
    return row


def markdown(result: Dict) -> str:
    lines = [
        f"Device: {result['device']}; method {result['method']}; {result['steps']} timed steps per count.",
        "",
        "| frames | site (m) | generate s | setup s | host peak GiB | Gaussians | ms/step | GPU peak GiB |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for row in result["surveys"]:
        head = (
            f"| {row['frames']} | {row['site_m'][0]} x {row['site_m'][1]} | {row['generate_s']} | {row['setup_s']} "
            f"| {row['host_peak_gib']} "
        )
        for i, c in enumerate(row["counts"]):
            lead = head if i == 0 else "| | | | | "
            lines.append(f"{lead}| {c['gaussians']:,} | {c['ms_per_step']} | {c['gpu_peak_gib']} |")
        if row.get("first_limit"):
            limit = re.split(r":? \(?CUDA", row["first_limit"])[0]  # the count and the step, not torch's text
            lines.append(f"| | | | | | {limit if 'out of' in limit else limit + ': out of memory'} | | |")
    for row in result["surveys"]:
        if "growth" in row:
            lines.append("\n" + growth_line(row["frames"], row["growth"]))
    return "\n".join(lines) + "\n"


def growth_line(frames: int, growth: Dict) -> str:
    """One sentence on `growth_to_the_limit`'s outcome."""
    stopped = growth["memory_stopped_at"]
    rollbacks = growth.get("out_of_memory_rollbacks")
    return (
        f"Growth from {growth['start']:,} ({frames:,} frames): message at "
        f"{'none' if stopped is None else f'{stopped:,}'}, largest {growth['largest']:,}; "
        f"{growth['outcome'].split('. GPU 0')[0]}"
        + ("." if rollbacks is None else f"; {rollbacks} rollbacks after running out.")
    )


def main(args: CostArgs) -> Dict:
    args.output_dir.mkdir(parents=True, exist_ok=True)
    surveys: List[Dict] = [measure_survey(args, frames) for frames in args.frames]
    result = {"device": device_name(), "method": args.method, "steps": args.steps, "surveys": surveys}
    (args.output_dir / "cost.json").write_text(json.dumps(result, indent=1))
    write_report(args.output_dir / "cost.md", markdown(result))
    return result


def entrypoint() -> None:
    main(tyro.cli(CostArgs))


if __name__ == "__main__":
    entrypoint()
