"""`python -m experiments.profile_step`: where the time of a training step goes.

Trains a method on a scene for `--warmup` steps of the full 30k schedule (densification has grown
the model as in a real run by then), then
- times `--steps` steps without the profiler (ms/step; synchronised at the two ends only);
- counts the host syncs of a few steps (`torch.cuda.set_sync_debug_mode`) by the line that made them;
- profiles `--profile-steps` steps with torch.profiler: GPU kernel time per step against wall time per
  step (a step much longer than its kernels is bound by Python and launches, not by the GPU), the
  top operators by GPU and by CPU time, and the model's own sections (`thermal/...` ranges);
- profiles `--python-steps` steps with cProfile: the host's time by Python function (trainer,
  callbacks, model, optimizers), the part of a host-bound step that operator tables do not name.
Writes `profile.json` and `profile.md` to `--output-dir` (and with `--trace` the profiled steps'
timeline, `trace.json.gz`).
"""

from __future__ import annotations

import collections
import cProfile
import gzip
import json
import shutil
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, Optional, Tuple

import torch
import tyro

from experiments import device_name, gpu_kernel_microseconds, python_profile_markdown, synchronize, train_with_hooks
from experiments.bench import BenchArgs, setup_trainer, trainer_config
from thermal_wild_ns.training.schedule import FULL_SCHEDULE


@dataclass
class ProfileArgs:
    scene: str = "demo"
    """'demo', 'stress:FAULT' or a dataset folder (as in python -m experiments.bench)."""
    method: str = "wild-thermal"
    """'splatfacto' or one of this plugin's methods."""
    warmup: int = 1500
    """Steps trained before measuring (the full 30k schedule; with `pipeline.cameras_per_step=B` set the
    schedule counts training frames, B a step)."""
    steps: int = 300
    """Steps timed without the profiler."""
    profile_steps: int = 20
    """Steps recorded by torch.profiler."""
    python_steps: int = 100
    """Steps recorded by cProfile (0: none)."""
    max_gaussians: Optional[int] = None
    auto_stop: bool = False
    """Train as the bench and `ns-train` do, with the automatic stop's held-back frames and the Gaussian
    budget they set (off: every capture frame trains, under the fixed budget). A run the stop ends before
    its measured steps are done is an error: lower `--warmup`."""
    set: Tuple[str, ...] = ()
    """Settings of the method's config, as the bench's `--set` (e.g. pipeline.model.graphed_loss=True)."""
    trace: bool = False
    """Also write the profiled steps' timeline (`trace.json.gz`, chrome://tracing or Perfetto): where the
    host waits and what it launches between kernels, which the operator tables do not show."""
    output_dir: Path = Path("outputs/profile")
    cache_dir: Optional[Path] = None


def _device_time(event) -> float:
    """Self GPU time of a profiler row, microseconds (the attribute was renamed in torch 2.4)."""
    return float(getattr(event, "self_device_time_total", getattr(event, "self_cuda_time_total", 0.0)))


def _inclusive_device_time(event) -> float:
    return float(getattr(event, "device_time_total", getattr(event, "cuda_time_total", 0.0)))


class _Phases:
    """After-step hook of one `Trainer.train` run: after `warmup` steps it times `steps` steps,
    then (CUDA) counts host syncs over `SYNC_STEPS` steps, then records `profile_steps` steps
    with torch.profiler, then `python_steps` steps with cProfile."""

    SYNC_STEPS = 5

    def __init__(self, args: ProfileArgs, cuda: bool):
        from torch.profiler import ProfilerActivity
        from torch.profiler import profile as torch_profile

        self.cuda = cuda
        self.timed = (args.warmup, args.warmup + args.steps)
        self.synced = (self.timed[1], self.timed[1] + (self.SYNC_STEPS if cuda else 0))
        self.profiled = (self.synced[1], self.synced[1] + args.profile_steps)
        self.python = (self.profiled[1], self.profiled[1] + args.python_steps)
        self.total = self.python[1]
        self.prof = torch_profile(activities=[ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if cuda else []))
        self.python_prof = cProfile.Profile()
        self.ms_per_step = self.profiled_ms = 0.0
        self.measuring = False  # no checkpoint is written while True (`train_measuring`)
        self.syncs: Dict[str, int] = collections.Counter()
        self.done = 0  # steps trained so far

    def __call__(self, step: int) -> None:
        done = self.done = step + 1
        if done == self.timed[0]:
            self.measuring = True
            synchronize()
            self.clock = time.perf_counter()
        if done == self.timed[1]:
            synchronize()
            self.ms_per_step = 1000 * (time.perf_counter() - self.clock) / (self.timed[1] - self.timed[0])
            if self.cuda:
                self._warnings = warnings.catch_warnings(record=True)
                self._caught = self._warnings.__enter__()
                warnings.simplefilter("always")
                torch.cuda.set_sync_debug_mode("warn")
        if done == self.synced[1]:
            if self.cuda:
                torch.cuda.synchronize()
                torch.cuda.set_sync_debug_mode(0)
                self._warnings.__exit__(None, None, None)
                for w in self._caught:
                    if "synchroniz" in str(w.message):
                        self.syncs[f"{w.filename}:{w.lineno}"] += 1
            self.clock = time.perf_counter()
            self.prof.start()
        if done == self.profiled[1]:
            synchronize()
            self.prof.stop()
            self.profiled_ms = 1000 * (time.perf_counter() - self.clock) / (self.profiled[1] - self.profiled[0])
            if self.python[1] > self.python[0]:
                self.python_prof.enable()
        if done == self.python[1] and self.python[1] > self.python[0]:
            synchronize()
            self.python_prof.disable()
        if done == self.total:
            self.measuring = False


def full_schedule_trainer(
    scene: str,
    method: str,
    settings: Tuple[str, ...],
    output_dir: Path,
    cache_dir: Optional[Path],
    auto_stop: bool = False,
    **bench,
):
    """A method's trainer on a scene for the full 30k schedule, as the bench builds it; the stop off
    unless `auto_stop` (off, every step asked is trained); its config saved under
    `output_dir/runs` (so `python -m experiments.render_fps` can load the run). `bench`: further
    `BenchArgs` fields."""
    output_dir.mkdir(parents=True, exist_ok=True)
    bench_args = BenchArgs(
        scenes=(scene,),
        methods=(method,),
        steps=FULL_SCHEDULE,
        schedule=FULL_SCHEDULE,
        set=settings,
        output_dir=output_dir,
        cache_dir=cache_dir,
        auto_stop=auto_stop,
        **bench,
    )
    config = trainer_config(method, scene, bench_args, output_dir / "runs")
    config.save_config()
    return setup_trainer(config)


def train_measuring(trainer, steps: int, hook) -> None:
    """`steps` steps of `trainer` with `hook(step)` after each; the run's own checkpoints are written,
    but none while `hook.measuring` is true (a short run saves every tenth of its steps)."""
    save = trainer.save_checkpoint
    trainer.save_checkpoint = lambda step: None if hook.measuring else save(step)
    train_with_hooks(trainer, steps, hook)


def measurement_header(args) -> Dict:
    """What a measurement's file says first: the scene, the method, the device, torch, the warm-up."""
    return {
        "scene": args.scene,
        "method": args.method,
        "device": device_name(),
        "torch": torch.__version__,
        "warmup": args.warmup,
    }


def profile(args: ProfileArgs) -> Dict:
    trainer = full_schedule_trainer(
        args.scene,
        args.method,
        args.set,
        args.output_dir,
        args.cache_dir,
        args.auto_stop,
        max_gaussians=args.max_gaussians,
    )
    cuda = torch.cuda.is_available()
    phases = _Phases(args, cuda)
    train_measuring(trainer, phases.total, phases)
    if phases.done < phases.total:
        raise RuntimeError(
            f"{args.scene}: the automatic stop ended the run at step {phases.done}, before the {phases.total} "
            "steps of the warm-up and the measurement; lower --warmup"
        )
    prof, ms_per_step, profiled_ms = phases.prof, phases.ms_per_step, phases.profiled_ms
    if args.trace:
        trace = args.output_dir / "trace.json"
        prof.export_chrome_trace(str(trace))
        with trace.open("rb") as raw, gzip.open(trace.with_suffix(".json.gz"), "wb") as packed:
            shutil.copyfileobj(raw, packed)
        trace.unlink()
    syncs = dict(sorted(phases.syncs.items(), key=lambda kv: -kv[1]))
    events = prof.key_averages()
    n = args.profile_steps
    gpu_ms = gpu_kernel_microseconds(prof) / 1000 / n
    by_gpu = sorted(events, key=_device_time, reverse=True)[:25]
    by_cpu = sorted(events, key=lambda e: e.self_cpu_time_total, reverse=True)[:25]
    sections = sorted((e for e in events if e.key.startswith("thermal/")), key=lambda e: e.key)

    def row(e) -> Dict:
        return {
            "name": e.key,
            "calls_per_step": e.count / n,
            "self_gpu_ms": _device_time(e) / 1000 / n,
            "self_cpu_ms": e.self_cpu_time_total / 1000 / n,
        }

    result = {
        **measurement_header(args),
        "auto_stop": args.auto_stop,
        "gaussians": int(trainer.pipeline.model.num_points),
        "ms_per_step": round(ms_per_step, 3),
        "profiled_ms_per_step": round(profiled_ms, 3),
        "gpu_kernel_ms_per_step": round(gpu_ms, 3),
        "host_syncs_per_step": {k: v / _Phases.SYNC_STEPS for k, v in syncs.items()},
        "sections": [
            {"name": e.key, "cpu_ms": e.cpu_time_total / 1000 / n, "gpu_ms": _inclusive_device_time(e) / 1000 / n}
            for e in sections
        ],
        "top_gpu": [row(e) for e in by_gpu],
        "top_cpu": [row(e) for e in by_cpu],
        "python_profile": python_profile_markdown(phases.python_prof, args.python_steps) if args.python_steps else "",
    }
    (args.output_dir / "profile.json").write_text(json.dumps(result, indent=1))
    (args.output_dir / "profile.md").write_text(_markdown(result))
    print(_markdown(result))
    return result


def _markdown(r: Dict) -> str:
    lines = [
        f"# {r['method']} on {r['scene']} ({r['device']}, torch {r['torch']}), after {r['warmup']} steps, "
        f"{r['gaussians']} Gaussians" + (", the automatic stop on" if r.get("auto_stop") else ""),
        "",
        f"- {r['ms_per_step']:.2f} ms/step unprofiled; {r['profiled_ms_per_step']:.2f} ms/step profiled, of which "
        f"GPU kernels {r['gpu_kernel_ms_per_step']:.2f} ms",
        f"- host syncs per step: {sum(r['host_syncs_per_step'].values()):.1f}",
        "",
    ]
    lines += [f"  - {v:.1f} x {k}" for k, v in r["host_syncs_per_step"].items()]
    lines += ["", "| section | CPU ms/step | GPU ms/step |", "| --- | --- | --- |"]
    lines += [f"| {s['name']} | {s['cpu_ms']:.3f} | {s['gpu_ms']:.3f} |" for s in r["sections"]]
    for title, rows in (("by GPU time", r["top_gpu"]), ("by CPU time", r["top_cpu"])):
        lines += [
            "",
            f"Top operators {title}:",
            "",
            "| operator | calls/step | self GPU ms | self CPU ms |",
            "| --- | --- | --- | --- |",
        ]
        lines += [
            f"| {x['name'][:70]} | {x['calls_per_step']:.1f} | {x['self_gpu_ms']:.3f} | {x['self_cpu_ms']:.3f} |"
            for x in rows
        ]
    if r.get("python_profile"):
        lines += ["", f"Host time by Python function (cProfile, per step, {r['method']}):", "", r["python_profile"]]
    return "\n".join(lines) + "\n"


def entrypoint():
    profile(tyro.cli(ProfileArgs))


if __name__ == "__main__":
    entrypoint()
