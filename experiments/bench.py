"""`python -m experiments.bench`: every ablation variant (and stock splatfacto) on the same scenes, under
the same schedule and evaluation protocol (`analysis/evaluation.py`).

For each scene x method it trains with nerfstudio's own Trainer components (same callbacks,
optimisers and strategies as `ns-train`), records test PSNR at the `--eval-at` steps against the
wall-clock seconds spent training (evaluation time excluded), evaluates the final model in every
embedding mode, and writes to `--output-dir`:
- `bench.json`: everything, per run: curve, final metrics per mode, seconds, ms/step, peak GPU
  memory, Gaussian count, model size;
- `bench.md`: the paper's Tab. 2 layout (PSNR / SSIM per scene and mean, fixed embedding) and a
  speed table;
- `speed_accuracy.png`: test PSNR vs training seconds, one curve per method, one panel per scene.

Stock splatfacto sees the frames as 3 equal channels without preprocessing; its LPIPS metric
(which downloads AlexNet weights) is replaced by a stub, it is never used here. It needs CUDA
(splatfacto hard-codes `.cuda()`), so it is skipped with a message on a CPU.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import gc
import json
import os
import re
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import numpy as np
import torch
import tyro

import thermal_wild_ns.compat  # noqa: F401
from thermal_wild_ns.method_configs import METHODS, method_trainer
from thermal_wild_ns.analysis.evaluation import EMBEDDING_MODES, evaluate, evaluate_path
from experiments import device_name, synchronize
from experiments.render_fps import measure_fps
from thermal_wild_ns.data.thermal_io import load_npy

RUNS_PER_GPU_VARIABLE = "THERMAL_WILD_NS_RUNS_PER_GPU"
"""How many runs share this run's GPU (set by `--runs-per-gpu`'s queues for their workers)."""

VARIANTS = ("splatfacto", *METHODS)
"""Stock splatfacto and every method this plugin registers."""
STRIP_FRAMES = (10, 20, 30, 40, 50)
"""Path views shown in the stress scenes' PNG strips (of 60)."""
FULL_SCHEDULE = 30_000
"""Splatfacto's schedule (warm-up, refinement, opacity reset, split stop) is defined for this many
steps; shorter runs scale it proportionally, the same for every method."""


@dataclass
class BenchArgs:
    scenes: Tuple[str, ...] = ("demo",)
    """'demo' (the embedded scene), 'stress:FAULT' (a stress scene, e.g. stress:outlier, stress:all;
    these are also scored along their smooth camera path) or dataset folders (any supported layout)."""
    methods: Tuple[str, ...] = VARIANTS
    steps: int = 30_000
    eval_at: Tuple[int, ...] = (1000, 2000, 5000, 10000, 20000, 30000)
    """Steps at which test PSNR (fixed embedding) is recorded for the speed-accuracy chart."""
    schedule: Optional[int] = None
    """Length of run the densification schedule is laid out for (default: --steps, i.e. a short run
    compresses the 30k schedule); e.g. 30000 with --steps 3000 trains the first 3000 steps of a full run."""
    max_gaussians: Optional[int] = None
    """Gaussian budget of the wild-thermal variants (default: their config's)."""
    equalization_strength: Optional[float] = None
    """Strength of the preprocessed variants' equalization step, 0-1 (default: their config's, the
    paper's full BBHE); see `wild-thermal-diagnose`'s error amplification for what it trades."""
    num_downscales: Optional[int] = None
    """Resolution warm-up of every method, splatfacto included: train at 1/2^n resolution first,
    halving the factor every `resolution_schedule` steps (default: the configs' 2, i.e. 1/4; a
    128x96 scene then trains at 32x24 pixels, and at full resolution only from 20 % of the schedule)."""
    wild_steps: int = 100
    """Embedding optimisation steps of the in-the-wild protocol."""
    output_dir: Path = Path("outputs/bench")
    cache_dir: Optional[Path] = None
    """Triangulation / preprocessing cache (default: `output_dir/cache`); point it at a cache made
    elsewhere to skip triangulation (e.g. on a machine without pycolmap)."""
    fps_frames: int = 300
    """Frames rendered to measure each trained model's render speed (baked vs unbaked emission, as
    `python -m experiments.render_fps`); 0 skips it."""
    seed: int = 0
    time_limit: Optional[float] = None
    """Training seconds a run may take; a run past it stops and is recorded as failed, with its step
    and Gaussian count (so one exploding method cannot use up a GPU session). Default: no limit."""
    gpus: int = 1
    """Spread the runs over this many GPUs: `--runs-per-gpu` queues per GPU, each training one run at
    a time in its own process (`CUDA_VISIBLE_DEVICES`), then their results merged into `output_dir`."""
    runs_per_gpu: int = 1
    """Runs trained at once on each GPU, each in its own process with an equal share of the CPU
    cores as its torch threads; their timings are labelled as shared. Measured not to pay: two
    per H200 made each 5,000-step stress run take 87-114 s instead of 46-70 s alone
    (results/stress_gpu_5k)."""
    merge: Tuple[Path, ...] = ()
    """Instead of training: combine these bench.json files (runs split over several commands or
    machines) into one bench.json / bench.md / speed_accuracy.png in `output_dir`."""


class _NoLPIPS(torch.nn.Module):
    """Stands in for torchmetrics' LPIPS, whose constructor downloads AlexNet weights."""

    def __init__(self, *args, **kwargs):
        super().__init__()

    def forward(self, *args, **kwargs):
        return torch.tensor(float("nan"))


@contextlib.contextmanager
def no_lpips_download():
    import torchmetrics.image.lpip as lpip

    original = lpip.LearnedPerceptualImagePatchSimilarity
    lpip.LearnedPerceptualImagePatchSimilarity = _NoLPIPS
    try:
        yield
    finally:
        lpip.LearnedPerceptualImagePatchSimilarity = original


def scale_schedule(model_config, steps: int) -> None:
    """Scale the densification schedule (defined for 30k steps) to a run of `steps` steps."""
    if steps >= FULL_SCHEDULE:
        return
    f = steps / FULL_SCHEDULE
    model_config.warmup_length = max(int(model_config.warmup_length * f), 10)
    model_config.refine_every = max(int(model_config.refine_every * f), 10)
    model_config.stop_split_at = int(model_config.stop_split_at * f)
    model_config.stop_screen_size_at = int(model_config.stop_screen_size_at * f)
    model_config.sh_degree_interval = max(int(model_config.sh_degree_interval * f), 1)
    model_config.resolution_schedule = max(int(model_config.resolution_schedule * f), 1)


def trainer_config(method: str, scene: str, args: BenchArgs, run_dir: Path):
    """The method's registered config on this scene, with the shared bench schedule."""
    from nerfstudio.configs.method_configs import method_configs

    from thermal_wild_ns.data.dataparsers import ThermalDataParserConfig, ThermalDemoDataParserConfig
    from thermal_wild_ns.data.datamanager import ThermalDatamanagerConfig
    from thermal_wild_ns.preprocessing.photometric import PhotometricConfig

    if scene == "demo":
        dataparser = ThermalDemoDataParserConfig(data=args.output_dir / "demo-scene")
    elif scene.startswith("stress:"):
        dataparser = ThermalDemoDataParserConfig(data=args.output_dir / scene_name(scene), scene=scene.split(":", 1)[1])  # type: ignore[arg-type]
    else:
        dataparser = ThermalDataParserConfig(data=Path(scene), cache_dir=args.cache_dir or args.output_dir / "cache")
    if method == "splatfacto":
        config = copy.deepcopy(method_configs["splatfacto"])
        config.pipeline.datamanager = ThermalDatamanagerConfig(
            dataparser=dataparser, preprocessing=PhotometricConfig("none"), grey_rgb=True, host_cameras=False
        )
    else:
        config = method_trainer(method)
        config.pipeline.datamanager.dataparser = dataparser
        if args.max_gaussians is not None:
            config.pipeline.model.max_gaussians = args.max_gaussians
        if args.equalization_strength is not None:
            preprocessing = config.pipeline.datamanager.preprocessing
            config.pipeline.datamanager.preprocessing = dataclasses.replace(preprocessing, equalization_strength=args.equalization_strength)
    if args.num_downscales is not None:
        config.pipeline.model.num_downscales = args.num_downscales
    config.pipeline.datamanager.preprocessing_cache = args.cache_dir or args.output_dir / "cache"
    config.output_dir = run_dir
    config.experiment_name = file_slug(run_label(method, args))
    config.timestamp = "run"
    config.vis = "tensorboard"
    config.max_num_iterations = args.steps
    config.steps_per_save = args.steps
    config.steps_per_eval_image = config.steps_per_eval_batch = config.steps_per_eval_all_images = 1 << 30
    config.save_only_latest_checkpoint = True
    config.machine.device_type = "cuda" if torch.cuda.is_available() else "cpu"
    config.machine.seed = args.seed
    scale_schedule(config.pipeline.model, args.schedule or args.steps)
    return config


def run_label(method: str, args: BenchArgs) -> str:
    """The method's name in records, tables and charts, with the settings this bench changed in it
    (warm-up; equalization strength, where the method equalizes), so that e.g. stock splatfacto and
    splatfacto with `--num-downscales 1` merge side by side instead of one hiding the other. The
    Gaussian budget is not named: a budget sweep compares one method across budgets by its args."""
    changed = [] if args.num_downscales is None else [f"num-downscales {args.num_downscales}"]
    if args.equalization_strength is not None and method in METHODS and METHODS[method].config.pipeline.datamanager.preprocessing.equalizes:
        changed.append(f"equalization-strength {args.equalization_strength:g}")
    return f"{method} ({', '.join(changed)})" if changed else method


def file_slug(label: str) -> str:
    """`label` as a file name (no spaces or brackets)."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", label).strip("_")


def scene_name(scene: str) -> str:
    return scene.replace(":", "-") if scene.startswith("stress:") else Path(scene).name


def _model_megabytes(model) -> float:
    return sum(t.numel() * t.element_size() for t in model.state_dict().values() if isinstance(t, torch.Tensor)) / 2**20


class RunTooSlow(RuntimeError):
    """A bench run went past `--time-limit`."""


def train_steps(trainer, start: int, stop: int, seconds_left: Optional[float] = None) -> torch.Tensor:
    """Steps [start, stop) exactly as `ns-train` runs them (callbacks included, no evaluation,
    no logging); returns the last loss. Once `seconds_left` have passed (checked every 100 steps)
    it raises RunTooSlow."""
    from nerfstudio.engine.callbacks import TrainingCallbackLocation

    loss = torch.tensor(float("nan"))
    deadline = None if seconds_left is None else time.perf_counter() + seconds_left
    for step in range(start, stop):
        # every 100 steps, a segment's first step included (time may be up when an evaluation ends),
        # but not the run's first step, which has trained nothing yet
        if deadline is not None and step > 0 and step % 100 == 0 and time.perf_counter() > deadline:
            gaussians = getattr(trainer.pipeline.model, "num_points", "?")
            raise RunTooSlow(f"--time-limit reached at step {step} ({gaussians} Gaussians)")
        trainer.pipeline.train()
        for callback in trainer.callbacks:
            callback.run_callback_at_location(step, location=TrainingCallbackLocation.BEFORE_TRAIN_ITERATION)
        loss, _, _ = trainer.train_iteration(step)
        for callback in trainer.callbacks:
            callback.run_callback_at_location(step, location=TrainingCallbackLocation.AFTER_TRAIN_ITERATION)
    return loss


def setup_trainer(config):
    """nerfstudio's Trainer for `config`, set up (LPIPS never built)."""
    with no_lpips_download():
        trainer = config.setup(local_rank=0, world_size=1)
        trainer.setup()
    return trainer


def run_one(method: str, scene: str, args: BenchArgs) -> Dict:
    run_dir = args.output_dir / "runs" / scene_name(scene)
    config = trainer_config(method, scene, args, run_dir)
    cuda = torch.cuda.is_available()
    if cuda:
        torch.cuda.reset_peak_memory_stats()
    config.save_config()  # ns-eval / ns-render / ns-viewer load the run from its config.yml
    trainer = setup_trainer(config)
    pipeline = trainer.pipeline
    checkpoints = sorted({s for s in args.eval_at if 0 < s <= args.steps} | {args.steps})
    curve, seconds, step = [], 0.0, 0
    losses_finite = True
    for stop in checkpoints:
        synchronize()
        start = time.perf_counter()
        loss = train_steps(trainer, step, stop, None if args.time_limit is None else args.time_limit - seconds)
        step = stop
        synchronize()
        seconds += time.perf_counter() - start
        losses_finite = losses_finite and bool(torch.isfinite(loss))
        result = evaluate(pipeline, "fixed")
        curve.append({"step": stop, "seconds": round(seconds, 3), "psnr": result["psnr"], "gaussians": result["gaussians"]})
        print(f"  {method} on {scene_name(scene)}: step {stop}, {seconds:.1f} s, test PSNR {result['psnr']:.2f} dB, {result['gaussians']} Gaussians")
    label = run_label(method, args)
    renders = args.output_dir / "renders" / scene_name(scene) / file_slug(label)
    final = {mode: evaluate(pipeline, mode, renders, wild_steps=args.wild_steps) for mode in EMBEDDING_MODES}
    path = None
    if scene.startswith("stress:"):
        path = evaluate_path(pipeline, config.pipeline.datamanager.dataparser.data, keep_frames=STRIP_FRAMES)
        strips = args.output_dir / "strips" / scene_name(scene)
        strips.mkdir(parents=True, exist_ok=True)
        for name, frames in ((file_slug(label), path.pop("kept")), ("0-ground-truth", path.pop("kept_truth"))):
            np.save(strips / f"{name}.npy", np.concatenate([frames[k] for k in STRIP_FRAMES], axis=1).astype(np.float16))
    trainer.save_checkpoint(args.steps - 1)
    fps = measure_fps(pipeline, args.fps_frames)["fps"] if args.fps_frames > 0 else None
    return {
        "method": label,
        "scene": scene_name(scene),
        "path": path,
        "steps": args.steps,
        "train_seconds": round(seconds, 2),
        "ms_per_step": round(1000 * seconds / args.steps, 3),
        "peak_gpu_memory_mb": round(torch.cuda.max_memory_allocated() / 2**20, 1) if cuda else None,
        "torch_threads": torch.get_num_threads(),
        # set by the GPU queues: a timing shared with other runs is not that of a run alone
        "runs_per_gpu": int(os.environ.get(RUNS_PER_GPU_VARIABLE, "1")),
        "gaussians": int(pipeline.model.num_points),
        "model_mb": round(_model_megabytes(pipeline.model), 2),
        "final_loss_finite": losses_finite,
        "render_fps": fps,
        "curve": curve,
        "final": final,
        "config": str(config.get_base_dir() / "config.yml"),
    }


def markdown(runs: List[Dict], scenes: List[str]) -> str:
    methods = list(dict.fromkeys(r["method"] for r in runs))
    by = {(r["method"], r["scene"]): r for r in runs}
    head = "| method | " + " | ".join(f"{s} PSNR / SSIM" for s in scenes) + " | mean PSNR / SSIM |"
    lines = ["Test views, original radiometric space, fixed inference embedding:", "", head, "|" + " --- |" * (len(scenes) + 2)]
    for m in methods:
        cells, ps, ss = [], [], []
        for s in scenes:
            r = by.get((m, s))
            if r is None or "failed" in r:
                cells.append("—" if r is None else "failed")
                continue
            f = r["final"]["fixed"]
            ps.append(f["psnr"])
            ss.append(f["ssim"])
            cells.append(f"{f['psnr']:.2f} / {f['ssim']:.3f}")
        mean = f"{np.mean(ps):.2f} / {np.mean(ss):.3f}" if ps else "—"
        lines.append(f"| {m} | " + " | ".join(cells) + f" | {mean} |")
    lines += ["", "Embedding modes (PSNR; `wild` scores the right half only; preprocessed renders mapped back through the test frame's LUT, "
              "or, in the last column, through the median training LUT, as every rendered novel view is):", "",
              "| method | scene | fixed | interpolate | wild (right half) | preprocessed space (fixed) | median training LUT (fixed) |", "| --- | --- | --- | --- | --- | --- | --- |"]
    done = [r for r in runs if "failed" not in r]
    for r in done:
        f = r["final"]
        optional = [f["fixed"].get(key) for key in ("psnr_preprocessed", "psnr_median_lut")]
        lines.append(
            f"| {r['method']} | {r['scene']} | {f['fixed']['psnr']:.2f} | {f['interpolate']['psnr']:.2f} | {f['wild']['psnr']:.2f} | "
            + " | ".join(f"{v:.2f}" if v is not None else "—" for v in optional)
            + " |"
        )
    lines += ["", "Cost (render FPS: test cameras; baked = the fixed embedding's emission cached, as the viewer renders; unbaked = emission MLP every frame):", "",
              "| method | scene | steps | train s | ms/step | peak GPU MB | Gaussians | model MB | render FPS baked / unbaked |", "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in done:
        mem = "—" if r["peak_gpu_memory_mb"] is None else f"{r['peak_gpu_memory_mb']:.0f}"
        fps = r.get("render_fps") or {}
        fps_cell = " / ".join(f"{fps[k]:.0f}" for k in ("baked", "unbaked") if k in fps) or "—"
        shared = f" ({r['runs_per_gpu']} runs per GPU)" if r.get("runs_per_gpu", 1) > 1 else ""  # not the timing of a run alone
        lines.append(f"| {r['method']} | {r['scene']} | {r['steps']} | {r['train_seconds']:.1f}{shared} | {r['ms_per_step']:.2f} | {mem} | {r['gaussians']} | {r['model_mb']:.1f} | {fps_cell} |")
    stress = [r for r in runs if r["scene"].startswith("stress-")]
    if stress:
        faults = list(dict.fromkeys(r["scene"] for r in stress))
        lines += ["", "Stress scenes along the smooth camera path (fixed embedding): PSNR dB / floater pixels % (of them, with an error "
                  "above 0.1: the visible ones) / excess flicker x1e3 (per pixel):", ""]
        lines += ["| method | " + " | ".join(f[len("stress-"):] for f in faults) + " |", "|" + " --- |" * (len(faults) + 1)]
        for m in dict.fromkeys(r["method"] for r in stress):
            cells = []
            for f in faults:
                r = by.get((m, f))
                if r is None:
                    cells.append("—")
                elif "failed" in r:
                    cells.append("diverged" if "Diverged" in r["failed"] else "failed")
                else:
                    p = r["path"]
                    visible = f"{100 * p['visible_floater_fraction']:.1f}" if "visible_floater_fraction" in p else "—"  # runs before the measure
                    cells.append(f"{p['psnr']:.2f} / {100 * p['floater_fraction']:.1f} ({visible}) / {1000 * p['flicker_pixel_excess']:.2f}")
            lines.append(f"| {m} | " + " | ".join(cells) + " |")
    failed = [r for r in runs if "failed" in r]
    if failed:
        lines += ["", "Failed runs:", ""] + [f"- {r['method']} on {r['scene']}: {r['failed']}" for r in failed]
    return "\n".join(lines) + "\n"


def chart(runs: List[Dict], scenes: List[str], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(scenes), figsize=(6 * len(scenes), 4.5), squeeze=False)
    for ax, scene in zip(axes[0], scenes):
        floor = 10.0  # a diverged run (PSNR far below) would squash every other curve
        for r in (r for r in runs if r["scene"] == scene and "failed" not in r):
            xs = [p["seconds"] for p in r["curve"]]
            ys = [p["psnr"] for p in r["curve"]]
            style = {"lw": 2.5, "color": "black"} if r["method"] == "wild-thermal" else ({"ls": "--"} if r["method"].startswith("splatfacto") else {})
            label = r["method"] + (f" (falls to {min(ys):.0f} dB)" if min(ys) < floor else "")
            ax.plot(xs, np.maximum(ys, floor), marker="o", ms=3, label=label, **style)
        ax.set(title=f"{scene}: test PSNR vs training time", xlabel="training wall-clock seconds (evaluation excluded)", ylabel="PSNR (dB, original space)")
        ax.set_xscale("log")
        ax.set_ylim(bottom=floor)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(args: BenchArgs) -> Dict:
    args.output_dir.mkdir(parents=True, exist_ok=True)
    if args.merge:
        merged = [json.loads(Path(p).read_text()) for p in args.merge]
        devices = {m["device"] for m in merged}
        if len(devices) > 1:
            raise ValueError(f"{', '.join(map(str, args.merge))}: runs come from different devices ({devices}); timings would not compare")
        _gather_strips([Path(p).parent / "strips" for p in args.merge], args.output_dir / "strips")
        return _write(args, [r for m in merged for r in m["runs"]], device=devices.pop(), torch_version=merged[0]["torch"])
    if args.gpus > 1 or args.runs_per_gpu > 1:
        return _spread_over_gpus(args)
    runs = []
    for scene in args.scenes:
        for method in args.methods:
            if method == "splatfacto" and not torch.cuda.is_available():
                print("  splatfacto skipped: stock splatfacto needs CUDA")
                continue
            try:
                runs.append(run_one(method, scene, args))
            except (torch.OutOfMemoryError, RuntimeError, ValueError) as err:  # a method failing is a result, not the end of the bench
                message = str(err).splitlines()[0][:300]
                print(f"  {method} on {Path(scene).name} FAILED: {type(err).__name__}: {message}")
                runs.append({"method": run_label(method, args), "scene": scene_name(scene), "steps": args.steps, "failed": f"{type(err).__name__}: {message}"})
                gc.collect()  # the failed trainer's tensors
                if torch.cuda.is_available():
                    torch.cuda.empty_cache()
            _write(args, runs)  # after every run: a crash later keeps what finished
    return _write(args, runs)


def _write(args: BenchArgs, runs: List[Dict], device: Optional[str] = None, torch_version: Optional[str] = None) -> Dict:
    scenes = list(dict.fromkeys(r["scene"] for r in runs))
    result = {
        "args": {k: (str(v) if isinstance(v, Path) else [str(x) for x in v] if k == "merge" else v) for k, v in vars(args).items()},
        "device": device or device_name(),
        "torch": torch_version or torch.__version__,
        "runs": runs,
    }
    (args.output_dir / "bench.json").write_text(json.dumps(result, indent=1))
    (args.output_dir / "bench.md").write_text(markdown(runs, scenes))
    if scenes:  # nothing to chart when every run was skipped (e.g. only splatfacto, on a CPU)
        chart(runs, scenes, args.output_dir / "speed_accuracy.png")
    for folder in sorted((args.output_dir / "strips").glob("stress-*")) if (args.output_dir / "strips").is_dir() else []:
        strip_png(folder, args.output_dir / f"{folder.name}_path_strip.png")
    return result


def _command_line(settings: BenchArgs) -> List[str]:
    """`settings` as this bench's command line (every field but those that spread runs or merge them)."""
    import sys

    command = [sys.executable, "-m", "experiments.bench"]
    for field in dataclasses.fields(settings):
        value = getattr(settings, field.name)
        if field.name not in ("gpus", "runs_per_gpu", "merge") and value is not None:
            command += [f"--{field.name.replace('_', '-')}", *map(str, value if isinstance(value, tuple) else (value,))]
    return command


def run_in_gpu_queues(jobs: List[BenchArgs], gpus: int, runs_per_gpu: int = 1) -> List[Path]:
    """Each job (a bench of one scene and method, in its own `output_dir`) as its own process, in
    `gpus * runs_per_gpu` queues run side by side; job k goes to queue k mod queues, on GPU k mod
    `gpus` (`CUDA_VISIBLE_DEVICES`), one job at a time per queue. Each process gets an equal share of
    the CPU cores as torch threads (`OMP_NUM_THREADS`, unless set): with torch's default, every
    process would start one thread per core. Each output folder gets the run's log.txt. Returns the
    bench.json files written, in job order (a killed or crashed run writes none)."""
    import subprocess
    import threading

    queues = gpus * runs_per_gpu
    package_root = str(Path(__file__).resolve().parents[1])  # the workers import this same code
    env = {
        "OMP_NUM_THREADS": str(max(1, (os.cpu_count() or 1) // queues)),
        **os.environ,
        RUNS_PER_GPU_VARIABLE: str(runs_per_gpu),  # each run labels its own record, so one finished before a kill is labelled too
        "PYTHONPATH": os.pathsep.join(filter(None, (package_root, os.environ.get("PYTHONPATH")))),
    }
    written: Dict[int, Path] = {}

    def work(queue: int) -> None:
        gpu = queue % gpus
        for k in range(queue, len(jobs), queues):
            job, folder = jobs[k], jobs[k].output_dir
            folder.mkdir(parents=True, exist_ok=True)
            with open(folder / "log.txt", "w") as log:
                code = subprocess.call(_command_line(job), env={**env, "CUDA_VISIBLE_DEVICES": str(gpu)}, stdout=log, stderr=subprocess.STDOUT)
            what = f"{', '.join(job.methods)} on {', '.join(map(scene_name, job.scenes))}"
            print(f"  GPU {gpu}: {what} {'done' if code == 0 else f'exited with {code}'} ({folder / 'log.txt'})")
            if (folder / "bench.json").is_file():
                written[k] = folder / "bench.json"

    threads = [threading.Thread(target=work, args=(queue,)) for queue in range(min(queues, len(jobs)))]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    return [written[k] for k in sorted(written)]


def _spread_over_gpus(args: BenchArgs) -> Dict:
    """Every scene x method run in `output_dir/gpuI/NN_SCENE_METHOD/`, over `args.gpus` GPUs, then merged."""
    pairs = [(scene, method) for scene in args.scenes for method in args.methods]
    cache = args.cache_dir or args.output_dir / "cache"  # one cache for all (triangulation once)
    jobs = [
        dataclasses.replace(args, scenes=(scene,), methods=(method,), cache_dir=cache, gpus=1, runs_per_gpu=1,
                            output_dir=args.output_dir / f"gpu{k % args.gpus}" / f"{k:02d}_{scene_name(scene)}_{method}")
        for k, (scene, method) in enumerate(pairs)
    ]
    done = run_in_gpu_queues(jobs, args.gpus, args.runs_per_gpu)
    if not done:
        raise RuntimeError(f"no run finished; see the logs under {args.output_dir}/gpu*/")
    merged = main(BenchArgs(merge=tuple(done), output_dir=args.output_dir))
    finished = {(r["scene"], r["method"]) for r in merged["runs"]}
    lost = [(scene, method) for scene, method in pairs if (scene_name(scene), run_label(method, args)) not in finished]
    if lost:
        print("  no result (see its log.txt): " + ", ".join(f"{m} on {scene_name(s)}" for s, m in lost))
    return merged


def _gather_strips(sources: List[Path], target: Path) -> None:
    """The stress scenes' path frames of merged runs (`strips/SCENE/METHOD.npy` beside each
    bench.json), so the merged output draws every method's strip."""
    import shutil

    for source in sources:
        if not source.is_dir() or source.resolve() == target.resolve():
            continue
        for npy in source.glob("*/*.npy"):
            (target / npy.parent.name).mkdir(parents=True, exist_ok=True)
            shutil.copy2(npy, target / npy.parent.name / npy.name)


def strip_png(folder: Path, path: Path) -> None:
    """The ground truth, then one row per method: renders at STRIP_FRAMES along the path (inferno, original space)."""
    import cv2

    from thermal_wild_ns.data.palettes import false_colour

    rows = []
    for npy in sorted(folder.glob("*.npy")):
        strip = load_npy(npy).astype(np.float32)
        row = false_colour(strip)
        row = cv2.resize(row, None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST)
        label = np.zeros((row.shape[0], 260, 3), np.uint8)
        cv2.putText(label, npy.stem, (6, row.shape[0] // 2 + 5), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1)
        rows.append(np.concatenate([label, row], axis=1))
    if rows:
        cv2.imwrite(str(path), np.concatenate(rows, axis=0))


def entrypoint():
    main(tyro.cli(BenchArgs))


if __name__ == "__main__":
    entrypoint()
