"""`python -m experiments.bench`: the methods (and stock splatfacto) on the same scenes, under
the same schedule and the same leak-free evaluation protocols (`pipeline/evaluation.py`), with
several seeds per configuration.

Each run trains with nerfstudio's own `Trainer.train` (its loop, callbacks and logging, as
`ns-train` runs it; `experiments.train_with_hooks`), records the `novel`, `time` and `aligned`
held-out PSNR at the `--eval-at` steps against the training seconds spent (evaluation excluded),
then scores the final model under every protocol in the same process, and writes to `--output-dir`:
- `bench.json`: everything, per run (one per seed): curve, final scores per protocol, seconds,
  ms/step, peak GPU memory, Gaussian count, model size;
- `bench.md`: per protocol, the mean over seeds and the min-max spread per scene and method;
  `oracle` (the held-out frame's own state) apart and labelled; each run's best checkpoint (chosen on the
  held-out views: an oracle choice, labelled) beside its final, and each method's time to the strongest
  splatfacto row's best; the cost table;
- `speed_accuracy.png`: `aligned` PSNR (a gain and offset fitted on each held-out view) vs training seconds,
  mean over seeds with the spread as a band, a star where a method first reaches the strongest splatfacto
  row's best checkpoint; `speed_time.png`: the same for `time`, which fits nothing.

Stock splatfacto sees the frames as 3 equal channels without preprocessing; its LPIPS metric
(which downloads AlexNet weights) is replaced by a stub, it is never used here. It needs CUDA
(splatfacto hard-codes `.cuda()`), so it is skipped with a message on a CPU.
"""

from __future__ import annotations

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

from experiments import device_name, synchronize, train_with_hooks
from experiments.camera_path import evaluate_path
from experiments.render_fps import measure_fps
from experiments.scenes import scene_dataparser, scene_name
from thermal_wild_ns._upstream import no_lpips_download, prepare_checkpoint_commands
from thermal_wild_ns.data.thermal_io import load_npy
from thermal_wild_ns.method_configs import METHODS, method_trainer
from thermal_wild_ns.model.wild_thermal import WildThermalModel
from thermal_wild_ns.pipeline.datamanager import NOT_PREPROCESSED
from thermal_wild_ns.pipeline.evaluation import CHEAP_PROTOCOLS, evaluate
from thermal_wild_ns.state_names import CANONICAL
from thermal_wild_ns.training.schedule import FULL_SCHEDULE, cameras_per_step, scale_schedule, steps_for
from thermal_wild_ns.training.trainer import seeded_trainer

RUNS_PER_GPU_VARIABLE = "THERMAL_WILD_NS_RUNS_PER_GPU"
"""How many runs share this run's GPU (set by `--runs-per-gpu`'s queues for their workers)."""

VARIANTS = ("splatfacto", *METHODS)
"""Stock splatfacto and every method this plugin registers."""
STRIP_FRAMES = (10, 20, 30, 40, 50)
"""Path views shown in the stress scenes' PNG strips (of 60)."""
HEADLINE_PROTOCOLS = ("novel", "time", "aligned", "half")
"""The leak-free protocols the tables lead with; `oracle` is shown apart."""
SCORE_PREFIXES = ("psnr_", "ssim_", "celsius_")
"""The keys of a run's final evaluation the bench keeps: PSNR, SSIM and, where the scene converts to °C, its errors."""


@dataclass
class BenchArgs:
    scenes: Tuple[str, ...] = ("demo",)
    """'demo' (the embedded scene), 'stress:FAULT' (a stress scene, e.g. stress:outlier, stress:all;
    these are also scored along their smooth camera path), 'survey:FRAMES' (the synthetic drone survey
    of that many frames, its held-out frames clean) or dataset folders (any supported layout,
    detected; 'LAYOUT:FOLDER' reads the folder with that layout, e.g. exif-gps:DATA)."""
    methods: Tuple[str, ...] = VARIANTS
    steps: int = 30_000
    """Training frames of each run, as `--max-num-iterations` counts them (steps, where a step trains one;
    with `pipeline.cameras_per_step=B` set, B a step)."""
    eval_at: Tuple[int, ...] = (1000, 2000, 5000, 10000, 20000, 30000)
    """Training frames at which the `novel`, `time` and `aligned` scores are recorded for the speed-accuracy
    chart (as `--steps`; the curve's points are the trainer's steps)."""
    seeds: int = 1
    """Runs per scene and method, with seeds `seed`, `seed` + 1, ...: tables give their mean and spread."""
    seed: int = 0
    """First seed (torch/numpy/random, and the order training frames are visited in)."""
    schedule: Optional[int] = None
    """Length of run (training frames, as --steps) the densification schedule is laid out for (default:
    --steps, i.e. a short run compresses the 30k schedule); e.g. 30000 with --steps 3000 trains the first
    3000 frames of a full run."""
    max_gaussians: Optional[int] = None
    """Gaussian budget of the wild-thermal variants (default: their config's): the budget the held-back
    frames start from where they set it (`auto_stop.grow_budget`, the default), else the fixed one."""
    equalization_strength: Optional[float] = None
    """Strength of the preprocessed variants' equalization step, 0-1 (default: their config's)."""
    num_downscales: Optional[int] = None
    """Resolution warm-up of every method, splatfacto included: train at 1/2^n resolution first,
    halving the factor every `resolution_schedule` steps (default: the configs' 2, i.e. 1/4; a
    128x96 scene then trains at 32x24 pixels, and at full resolution only from 20 % of the schedule)."""
    set: Tuple[str, ...] = ()
    """Settings of every method's config as dotted paths, e.g. `pipeline.model.heat_aware_ssim=False`,
    `pipeline.datamanager.preprocessing.variant=none`, splatfacto's `pipeline.model.sh_degree=0` or an
    optimizer's `optimizers.emission.optimizer.lr=7e-4` (values read as Python literals, else as
    text); named in the run's label."""
    auto_stop: bool = True
    """The automatic stop of this plugin's methods (`training/auto_stop.py`, its check interval scaled
    with the schedule like the densification's); off: every run trains `--steps` steps."""
    fit_steps: int = 100
    """Embedding optimisation steps per view of the `half` and `oracle` protocols."""
    output_dir: Path = Path("outputs/bench")
    cache_dir: Optional[Path] = None
    """Triangulation / preprocessing cache (default: `output_dir/cache`); point it at a cache made
    elsewhere to skip triangulation (e.g. on a machine without pycolmap)."""
    fps_frames: int = 300
    """Frames rendered to measure each trained model's render speed (baked vs unbaked emission, as
    `python -m experiments.render_fps`); 0 skips it."""
    time_limit: Optional[float] = None
    """Training seconds a run may take; a run past it stops and is recorded as failed, with its step
    and Gaussian count (so one exploding method cannot use up a GPU session). Default: no limit."""
    gpus: int = 1
    """Spread the runs over this many GPUs: `--runs-per-gpu` queues per GPU, each training one run at
    a time in its own process (`CUDA_VISIBLE_DEVICES`), then their results merged into `output_dir`."""
    runs_per_gpu: int = 1
    """Runs trained at once on each GPU, each in its own process with an equal share of the CPU
    cores as its torch threads; their timings are labelled as shared (docs/ says what it cost)."""
    merge: Tuple[Path, ...] = ()
    """Instead of training: combine these bench.json files (runs split over several commands or
    machines) into one bench.json / bench.md / speed_accuracy.png / speed_time.png in `output_dir`."""


def trainer_config(method: str, scene: str, args: BenchArgs, run_dir: Path, seed: Optional[int] = None):
    """The method's registered config on this scene, with the shared bench schedule and `seed`
    (default: `args.seed`) for torch and for the order the training frames are visited in."""
    from nerfstudio.configs.method_configs import method_configs

    from thermal_wild_ns.pipeline.datamanager import ThermalDatamanagerConfig
    from thermal_wild_ns.preprocessing.photometric import PhotometricConfig

    seed = args.seed if seed is None else seed
    dataparser = scene_dataparser(scene, args.output_dir, args.cache_dir or args.output_dir / "cache")
    if method == "splatfacto":
        config = copy.deepcopy(method_configs["splatfacto"])
        config.pipeline.datamanager = ThermalDatamanagerConfig(
            dataparser=dataparser, preprocessing=PhotometricConfig("none"), grey_rgb=True, host_cameras=False
        )
    else:
        config = method_trainer(method)
        config.pipeline.datamanager.dataparser = dataparser
        if args.max_gaussians is not None:
            config.pipeline.model.max_gaussians = config.auto_stop.budget_start = args.max_gaussians
        if args.equalization_strength is not None:
            preprocessing = config.pipeline.datamanager.preprocessing
            config.pipeline.datamanager.preprocessing = dataclasses.replace(
                preprocessing, equalization_strength=args.equalization_strength
            )
    if args.num_downscales is not None:
        config.pipeline.model.num_downscales = args.num_downscales
    for setting in args.set:
        apply_setting(config, setting)
    config.pipeline.datamanager.preprocessing_cache = args.cache_dir or args.output_dir / "cache"
    config.pipeline.datamanager.train_order_seed = seed
    config.output_dir = run_dir
    config.experiment_name = file_slug(run_label(method, args)) + f"_seed{seed}"
    config.timestamp = "run"
    config.vis = "tensorboard"
    config.max_num_iterations = args.steps
    config.steps_per_save = args.steps
    config.steps_per_eval_image = config.steps_per_eval_batch = config.steps_per_eval_all_images = 1 << 30
    config.save_only_latest_checkpoint = True
    config.machine.device_type = "cuda" if torch.cuda.is_available() else "cpu"
    config.machine.seed = seed
    scale_schedule(config.pipeline.model, (args.schedule or args.steps) / FULL_SCHEDULE)
    if hasattr(config, "auto_stop"):
        config.auto_stop.enabled = args.auto_stop
        config.auto_stop.scale_to(args.schedule or args.steps, FULL_SCHEDULE)
    return config


def apply_setting(config, setting: str) -> None:
    """Set `path.to.field=value` on a config (frozen dataclasses along the path are replaced)."""
    import ast

    path, _, text = setting.partition("=")
    if not text:
        raise ValueError(f"--set {setting!r}: expected path.to.field=value")
    try:
        value = ast.literal_eval(text)
    except (ValueError, SyntaxError):
        value = text
    *parents, name = path.split(".")

    def has(owner, key: str) -> bool:  # dataclass fields, or keys of a dict (the trainer's `optimizers`)
        return key in owner if isinstance(owner, dict) else hasattr(owner, key)

    chain = [config]
    for depth, part in enumerate(path.split(".")):
        if not has(chain[-1], part):
            raise ValueError(f"--set {setting!r}: {type(chain[-1]).__name__} has no field {part!r}")
        if depth < len(parents):
            chain.append(chain[-1][part] if isinstance(chain[-1], dict) else getattr(chain[-1], part))
    for owner, attribute in zip(reversed(chain), [name, *reversed(parents)]):
        if isinstance(owner, dict):
            owner[attribute] = value
            return
        if not getattr(type(owner), "__dataclass_params__", None) or not owner.__dataclass_params__.frozen:
            setattr(owner, attribute, value)
            return
        value = dataclasses.replace(owner, **{attribute: value})  # frozen: a new owner, set one level up


def run_label(method: str, args: BenchArgs) -> str:
    """The method's name in records, tables and charts, with the settings this bench changed in it
    (warm-up; equalization strength, where the method equalizes), so that e.g. stock splatfacto and
    splatfacto with `--num-downscales 1` merge side by side instead of one hiding the other. The
    Gaussian budget is not named: a budget sweep compares one method across budgets by its args."""
    changed = [] if args.num_downscales is None else [f"num-downscales {args.num_downscales}"]
    if (
        args.equalization_strength is not None
        and method in METHODS
        and METHODS[method].config.pipeline.datamanager.preprocessing.equalizes
    ):
        changed.append(f"equalization-strength {args.equalization_strength:g}")
    # a setting is named by its field, an optimizer's by its parameter group too ("emission.optimizer.lr=...")
    for setting in args.set:  # split at '=' first: a value may hold dots (0.0004)
        path, _, value = setting.partition("=")
        name = path.removeprefix("optimizers.") if path.startswith("optimizers.") else path.rsplit(".", 1)[-1]
        changed.append(f"{name}={value}")
    return f"{method} ({', '.join(changed)})" if changed else method


def file_slug(label: str) -> str:
    """`label` as a file name (no spaces or brackets)."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", label).strip("_")


def _model_megabytes(model) -> float:
    return sum(t.numel() * t.element_size() for t in model.state_dict().values() if isinstance(t, torch.Tensor)) / 2**20


def negative_emission(model) -> Optional[Dict[str, float]]:
    """How much of a thermal model emits below zero at its canonical state, view term left out (the
    growth question of issue 33): the share of Gaussians, and of their summed opacity; None for
    other models."""
    if not isinstance(model, WildThermalModel) or model.num_points == 0:
        return None
    with torch.no_grad():
        emission = model.gaussian_emission(model.state_embedding(CANONICAL))[:, 0]  # [N]
        opacity = torch.sigmoid(model.opacities.detach())[:, 0]  # [N]
        below = emission < 0
        return {
            "share": round(float(below.float().mean()), 4),
            "opacity_share": round(float(opacity[below].sum() / opacity.sum().clamp_min(1e-12)), 4),
        }


class RunTooSlow(RuntimeError):
    """A bench run went past `--time-limit`."""


def setup_trainer(config):
    """nerfstudio's Trainer for `config`, set up (LPIPS never built)."""
    prepare_checkpoint_commands()  # stock splatfacto's checkpoints too
    with no_lpips_download():
        trainer = seeded_trainer(config)
    return trainer


class CurveRecorder:
    """Called after every training step (`train_with_hooks`): keeps the training clock (paused
    while it evaluates), scores the cheap protocols at the checkpoint steps, and stops a run past
    its time limit (checked every 100 steps)."""

    def __init__(self, pipeline, checkpoints, time_limit: Optional[float], describe: str):
        self.pipeline, self.checkpoints, self.time_limit, self.describe = (
            pipeline,
            set(checkpoints),
            time_limit,
            describe,
        )
        self.seconds, self.started, self.curve = 0.0, None, []
        self.trained_seconds = 0.0
        """Training seconds up to the last step trained (a run the automatic stop ends between two
        checkpoints trains past the last one)."""

    def start(self) -> None:
        synchronize()
        self.started = time.perf_counter()

    def elapsed(self) -> float:
        return self.seconds + (time.perf_counter() - self.started if self.started is not None else 0.0)

    def __call__(self, step: int) -> None:
        done = step + 1  # steps trained so far
        if self.time_limit is not None and done % 100 == 0 and self.elapsed() > self.time_limit:
            raise RunTooSlow(
                f"--time-limit reached at step {done} ({getattr(self.pipeline.model, 'num_points', '?')} Gaussians)"
            )
        if done not in self.checkpoints:
            self.trained_seconds = self.elapsed()  # host time: the GPU is at most a step or two behind
            return
        synchronize()
        self.seconds, self.started = self.elapsed(), None
        self.trained_seconds = self.seconds
        result = evaluate(self.pipeline, protocols=CHEAP_PROTOCOLS)
        self.pipeline.train()
        point = {"step": done, "seconds": round(self.seconds, 3), "gaussians": result["gaussians"]}
        point.update({f"psnr_{p}": result[f"psnr_{p}"] for p in CHEAP_PROTOCOLS})
        self.curve.append(point)
        print(
            f"  {self.describe}: step {done}, {self.seconds:.1f} s, PSNR novel {point['psnr_novel']:.2f} / time "
            f"{point['psnr_time']:.2f} / aligned {point['psnr_aligned']:.2f} dB, {point['gaussians']} Gaussians",
            flush=True,
        )
        self.start()


def run_one(method: str, scene: str, args: BenchArgs, seed: int) -> Dict:
    run_dir = args.output_dir / "runs" / scene_name(scene)
    config = trainer_config(method, scene, args, run_dir, seed)
    cuda = torch.cuda.is_available()
    if cuda:
        torch.cuda.reset_peak_memory_stats()
    config.save_config()  # ns-eval / ns-render / ns-viewer load the run from its config.yml
    trainer = setup_trainer(config)
    pipeline = trainer.pipeline
    label = run_label(method, args)
    # --steps and --eval-at count training frames, as the schedule: the trainer's steps (each of
    # `count` frames) hold them
    count, steps_asked = cameras_per_step(config), trainer.config.max_num_iterations
    checkpoints = sorted({steps_for(s, count) for s in args.eval_at if 0 < s <= args.steps} | {steps_asked})
    recorder = CurveRecorder(pipeline, checkpoints, args.time_limit, f"{label} on {scene_name(scene)} (seed {seed})")
    train_with_hooks(trainer, steps_asked, recorder, recorder.start)
    renders = args.output_dir / "renders" / scene_name(scene) / f"{file_slug(label)}_seed{seed}"
    final = evaluate(pipeline, renders, fit_steps=args.fit_steps)
    path = None
    if scene.startswith("stress:"):
        path = evaluate_path(pipeline, config.pipeline.datamanager.dataparser.data, keep_frames=STRIP_FRAMES)
        strips = args.output_dir / "strips" / scene_name(scene)
        strips.mkdir(parents=True, exist_ok=True)
        kept, truth = path.pop("kept"), path.pop("kept_truth")
        if seed == args.seed:  # one strip per method: the first seed's
            for name, frames in ((file_slug(label), kept), ("0-ground-truth", truth)):
                np.save(
                    strips / f"{name}.npy", np.concatenate([frames[k] for k in STRIP_FRAMES], axis=1).astype(np.float16)
                )
    rendered = measure_fps(pipeline, args.fps_frames) if args.fps_frames > 0 else {}
    seconds = recorder.trained_seconds  # to the last step trained, checkpoint or not
    steps = trainer.step + 1  # fewer than asked where the automatic stop ended the run
    record = config.get_base_dir() / "auto_stop.json"
    return {
        "method": label,
        "scene": scene_name(scene),
        "seed": seed,
        "path": path,
        "steps": steps,
        "auto_stop": json.loads(record.read_text()) if record.exists() else None,
        # what the training frames went through (the full method decides from the capture)
        "preprocessing": getattr(pipeline.datamanager, "preprocessing_used", "") or None,
        "train_seconds": round(seconds, 2),
        "ms_per_step": round(1000 * seconds / steps, 3),
        "peak_gpu_memory_mb": round(torch.cuda.max_memory_allocated() / 2**20, 1) if cuda else None,
        "torch_threads": torch.get_num_threads(),
        # set by the GPU queues: a timing shared with other runs is not that of a run alone
        "runs_per_gpu": int(os.environ.get(RUNS_PER_GPU_VARIABLE, "1")),
        "gaussians": int(pipeline.model.num_points),
        "negative_emission": negative_emission(pipeline.model),
        "model_mb": round(_model_megabytes(pipeline.model), 2),
        "render_fps": rendered.get("fps"),
        # wild-thermal-render's cheap camera slices against nerfstudio's: 0.0, the same renders
        "render_fast_slices_difference": rendered.get("max_abs_difference_fast_slices"),
        "curve": recorder.curve,
        **{key: value for key, value in final.items() if key.startswith(SCORE_PREFIXES)},
        "per_view": final["per_view"],
        "config": str(config.get_base_dir() / "config.yml"),
    }


def spread(values: List[float]) -> Dict[str, float]:
    """Mean, min and max of one score over seeds."""
    return {
        "mean": float(np.mean(values)),
        "min": float(np.min(values)),
        "max": float(np.max(values)),
        "n": len(values),
    }


def aggregate(runs: List[Dict]) -> Dict[Tuple[str, str], Dict]:
    """(method, scene) -> per score key, its spread over the finished runs (seeds); 'failed': count."""
    groups: Dict[Tuple[str, str], List[Dict]] = {}
    for r in runs:
        groups.setdefault((r["method"], r["scene"]), []).append(r)
    out = {}
    for key, group in groups.items():
        done = [r for r in group if "failed" not in r]
        keys = [
            k
            for k in (done[0] if done else {})
            if k.startswith(SCORE_PREFIXES) or k in ("steps", "ms_per_step", "train_seconds", "gaussians", "model_mb")
        ]
        out[key] = {k: spread([r[k] for r in done]) for k in keys}
        out[key]["failed"] = len(group) - len(done)
    return out


def best_checkpoint(run: Dict, protocol: str) -> Optional[Dict]:
    """The run's highest held-out `protocol` PSNR over its scored checkpoints and its final model, with the
    step and training seconds it came at. The checkpoint is chosen on the held-out views themselves: an
    oracle choice, reported beside the final, never as a result a user gets."""
    key = f"psnr_{protocol}"
    points = [p for p in run.get("curve") or [] if key in p]
    if key in run:
        points.append({"step": run["steps"], "seconds": run["train_seconds"], key: run[key]})
    if not points:
        return None
    best = max(points, key=lambda p: p[key])
    return {"psnr": float(best[key]), "step": int(best["step"]), "seconds": float(best["seconds"])}


def strongest_baseline(runs: List[Dict], scene: str, protocol: str) -> Optional[Tuple[str, float, float]]:
    """Of the splatfacto rows on `scene` (stock, bilateral grid, ...), the one whose best checkpoints reach the
    highest mean `protocol` PSNR over seeds: (method, that mean, the mean seconds to it); None without one."""
    rows = {}
    for r in runs:
        best = best_checkpoint(r, protocol) if r["scene"] == scene and r["method"].startswith("splatfacto") else None
        if best is not None and "failed" not in r:
            rows.setdefault(r["method"], []).append(best)
    if not rows:
        return None
    method, bests = max(rows.items(), key=lambda item: np.mean([b["psnr"] for b in item[1]]))
    return method, float(np.mean([b["psnr"] for b in bests])), float(np.mean([b["seconds"] for b in bests]))


def mean_curve(runs: List[Dict], key: str) -> List[Tuple[int, float, float]]:
    """(step, mean seconds, mean `key`) at each checkpoint step every one of `runs` scored."""
    curves = [[p for p in r["curve"] if key in p] for r in runs]
    steps = sorted(set.intersection(*({p["step"] for p in c} for c in curves))) if curves else []
    at = lambda name, step: float(np.mean([p[name] for c in curves for p in c if p["step"] == step]))
    return [(step, at("seconds", step), at(key, step)) for step in steps]


def best_checkpoint_lines(runs: List[Dict], scenes: List[str]) -> List[str]:
    """The best-checkpoint table (an oracle choice, labelled) and each method's time to the strongest splatfacto
    row's best: the baseline at its best point, not its final."""
    done = [r for r in runs if "failed" not in r and r.get("curve")]
    if not done:
        return []
    protocols = [p for p in ("novel", "time", "aligned") if any(f"psnr_{p}" in r for r in done)]
    lines = [
        "Best checkpoint — the scored checkpoint (or final model) with the highest held-out PSNR, **chosen on the "
        "held-out views themselves: an oracle choice, not a result**; mean (min–max) over seeds, the steps it came "
        "at, and the final beside it:",
        "",
        "| method | scene | protocol | best (oracle choice) | at steps | final |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    stats = aggregate(done)
    for m in dict.fromkeys(r["method"] for r in done):
        for s in scenes:
            group = [r for r in done if r["method"] == m and r["scene"] == s]
            for protocol in protocols:
                bests = [b for b in (best_checkpoint(r, protocol) for r in group) if b is not None]
                if not bests:
                    continue
                best = {"psnr": spread([b["psnr"] for b in bests]), "failed": 0}
                steps = ", ".join(f"{b['step']:,}" for b in bests)
                lines.append(
                    f"| {m} | {s} | `{protocol}` | {_cell(best, 'psnr')} | {steps} | "
                    f"{_cell(stats.get((m, s)), f'psnr_{protocol}')} |"
                )
    lines += [
        "",
        "Time to the strongest splatfacto row's best checkpoint (its mean over seeds): the first scored step at "
        "which a method's mean reaches it, and the mean training seconds there:",
        "",
        "| scene | protocol | splatfacto row, best mean | its seconds to it | method | reached at step | seconds |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for s in scenes:
        for protocol in protocols:
            baseline = strongest_baseline(done, s, protocol)
            if baseline is None:
                continue
            name, target, seconds = baseline
            for m in dict.fromkeys(r["method"] for r in done if r["scene"] == s):
                if m.startswith("splatfacto"):
                    continue
                curve = mean_curve([r for r in done if r["method"] == m and r["scene"] == s], f"psnr_{protocol}")
                reached = next(((step, sec) for step, sec, psnr in curve if psnr >= target), None)
                where = (f"{reached[0]:,}", f"{reached[1]:.1f}") if reached else ("not reached", "—")
                lines.append(
                    f"| {s} | `{protocol}` | {name}, {target:.2f} | {seconds:.1f} | {m} | {where[0]} | {where[1]} |"
                )
    return lines + [""]


def _cell(stats: Optional[Dict], key: str, digits: int = 2) -> str:
    if stats is None or key not in stats:
        return "—" if stats is None or not stats.get("failed") else "failed"
    s = stats[key]
    text = f"{s['mean']:.{digits}f}"
    low, high = f"{s['min']:.{digits}f}", f"{s['max']:.{digits}f}"
    if s["n"] > 1 and low != high:
        text += f" ({low}–{high})"
    return text + (f", {stats['failed']} failed" if stats.get("failed") else "")


def markdown(runs: List[Dict], scenes: List[str]) -> str:
    methods = list(dict.fromkeys(r["method"] for r in runs))
    stats = aggregate(runs)
    seeds = sorted({r.get("seed", 0) for r in runs})
    lines = [
        f"Held-out views, original radiometric space; mean over seeds (min–max) where a configuration ran more than "
        f"once (seeds here: {', '.join(map(str, seeds))}). Protocols: pipeline/evaluation.py.",
        "",
    ]
    titles = {
        "novel": "`novel` (canonical state: what a rendered novel view is)",
        "time": "`time` (state predicted from the neighbouring training frames)",
        "aligned": "`aligned` (novel + per-view least-squares gain/offset)",
        "half": "`half` (NeRF-W: state fitted on the left half, right half scored)",
        "oracle": "`oracle` — uses the held-out frame's own pixels (its LUT, an embedding fitted on all of it): an "
        "upper bound, not a result",
        "oracle_lut": "`oracle_lut` — the `time` state with the held-out frame's own LUT (built from its pixels): "
        "`oracle_lut` − `time` is the LUT prediction's share of the `time`–`oracle` gap, `oracle` − `oracle_lut` the "
        "embedding's; not a result",
    }
    bounds = ["oracle"] + (["oracle_lut"] if any("psnr_oracle_lut" in r for r in runs) else [])
    for protocol in (*HEADLINE_PROTOCOLS, *bounds):
        lines += [
            f"PSNR / SSIM, {titles[protocol]}:",
            "",
            "| method | " + " | ".join(scenes) + " |",
            "|" + " --- |" * (len(scenes) + 1),
        ]
        for m in methods:
            cells = []
            for s in scenes:
                st = stats.get((m, s))
                cells.append(
                    _cell(st, f"psnr_{protocol}")
                    + (" / " + _cell(st, f"ssim_{protocol}", 3) if st and f"ssim_{protocol}" in st else "")
                )
            lines.append(f"| {m} | " + " | ".join(cells) + " |")
        lines.append("")
    celsius = [p for p in (*HEADLINE_PROTOCOLS, "oracle") if any(f"celsius_mae_{p}" in st for st in stats.values())]
    if celsius:  # scenes whose camera converts to °C (a calibration, or documented bounds)
        lines += [
            "Held-out error in °C, MAE / RMSE / p95 of |error| over each view's pixels (scenes with a calibration):",
            "",
            "| method | protocol | " + " | ".join(scenes) + " |",
            "|" + " --- |" * (len(scenes) + 2),
        ]
        for m in methods:
            for protocol in celsius:
                cells = [
                    " / ".join(_cell(stats.get((m, s)), f"celsius_{k}_{protocol}") for k in ("mae", "rmse", "p95"))
                    for s in scenes
                ]
                lines.append(f"| {m} | `{protocol}` | " + " | ".join(cells) + " |")
        lines.append("")
    lines += best_checkpoint_lines(runs, scenes)
    lines += [
        "Cost (mean over seeds; render FPS: test cameras, first seed; baked = the canonical emission cached, as the "
        "viewer renders; "
        "unbaked = emission MLP every frame):",
        "",
        "| method | scene | seeds | steps | train s | ms/step | peak GPU MB | Gaussians | model MB | render FPS "
        "baked / unbaked |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    first = {}
    for r in runs:
        if "failed" not in r:
            first.setdefault((r["method"], r["scene"]), r)
    for (m, s), r in first.items():
        st = stats[(m, s)]
        mem = "—" if r["peak_gpu_memory_mb"] is None else f"{r['peak_gpu_memory_mb']:.0f}"
        fps = r.get("render_fps") or {}
        fps_cell = " / ".join(f"{fps[k]:.0f}" for k in ("baked", "unbaked") if k in fps) or "—"
        shared = (
            f" ({r['runs_per_gpu']} runs per GPU)" if r.get("runs_per_gpu", 1) > 1 else ""
        )  # not the timing of a run alone
        lines.append(
            f"| {m} | {s} | {st['ms_per_step']['n']} | {_cell(st, 'steps', 0)} | "
            f"{_cell(st, 'train_seconds', 1)}{shared} | "
            f"{_cell(st, 'ms_per_step')} | {mem} | {_cell(st, 'gaussians', 0)} | {_cell(st, 'model_mb', 1)} | "
            f"{fps_cell} |"
        )
    stops = [r for r in runs if r.get("auto_stop")]
    if stops:
        lines += ["", "Automatic stop (`training/auto_stop.py`): steps trained of those asked, model kept, why:", ""]
        for r in stops:
            a = r["auto_stop"]
            why = a["reason"] or "no plateau"
            lines.append(
                f"- {r['method']} on {r['scene']} (seed {r.get('seed', 0)}): {a['last_step'] + 1} of "
                f"{a['steps_asked']} steps, model of step {a['kept_step']} kept; {why}"
            )
    first_seed = min((r.get("seed", 0) for r in runs), default=0)
    decided = [
        r
        for r in runs
        if r.get("seed", 0) == first_seed and (r.get("preprocessing") or NOT_PREPROCESSED) != NOT_PREPROCESSED
    ]
    if decided:
        lines += ["", "Preprocessing of the training frames (first seed's runs):", ""]
        lines += [f"- {r['method']} on {r['scene']}: {r['preprocessing']}" for r in decided]
    stress = [r for r in runs if r["scene"].startswith("stress-") and "failed" not in r and r.get("path")]
    if stress:
        faults = list(dict.fromkeys(r["scene"] for r in runs if r["scene"].startswith("stress-")))
        lines += [
            "",
            "Stress scenes along the smooth camera path (canonical state), mean over seeds: PSNR dB / floater pixels % "
            "(of them, with an error above 0.1: the visible ones) / excess flicker x1e3 (per pixel):",
            "",
        ]
        lines += [
            "| method | " + " | ".join(f[len("stress-") :] for f in faults) + " |",
            "|" + " --- |" * (len(faults) + 1),
        ]
        for m in dict.fromkeys(r["method"] for r in stress):
            cells = []
            for f in faults:
                paths = [r["path"] for r in stress if r["method"] == m and r["scene"] == f]
                if not paths:
                    cells.append("failed" if any(r["method"] == m and r["scene"] == f for r in runs) else "—")
                    continue
                mean = {
                    k: float(np.mean([p[k] for p in paths]))
                    for k in ("psnr", "floater_fraction", "visible_floater_fraction", "flicker_pixel_excess")
                }
                cells.append(
                    f"{mean['psnr']:.2f} / {100 * mean['floater_fraction']:.1f} "
                    f"({100 * mean['visible_floater_fraction']:.1f}) / "
                    f"{1000 * mean['flicker_pixel_excess']:.2f}"
                )
            lines.append(f"| {m} | " + " | ".join(cells) + " |")
    failed = [r for r in runs if "failed" in r]
    if failed:
        lines += ["", "Failed runs:", ""] + [
            f"- {r['method']} on {r['scene']} (seed {r.get('seed', 0)}): {r['failed']}" for r in failed
        ]
    return "\n".join(lines) + "\n"


def chart(runs: List[Dict], scenes: List[str], path: Path, protocol: str = "aligned") -> None:
    """`protocol` PSNR against training seconds per scene: per method the mean over seeds at each
    checkpoint step, the min-max over seeds as a band."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter

    # seconds as plain numbers; of the minor ticks only 2 and 5 labelled (matplotlib labels every minor tick in
    # "3x10^0" form where the axis spans under a decade, and they overlap)
    plain = FuncFormatter(lambda value, _: f"{value:g}")
    two_and_five = FuncFormatter(lambda value, _: f"{value:g}" if f"{value:e}"[0] in "25" else "")
    fig, axes = plt.subplots(1, len(scenes), figsize=(6 * len(scenes), 4.5), squeeze=False)
    for ax, scene in zip(axes[0], scenes):
        floor = 10.0  # a diverged run (PSNR far below) would squash every other curve
        minima = []
        done = [
            r
            for r in runs
            if r["scene"] == scene and "failed" not in r and r["curve"] and f"psnr_{protocol}" in r["curve"][0]
        ]
        baseline = strongest_baseline(done, scene, protocol)  # time to quality: against its best, not its final
        target = None if baseline is None else baseline[1]
        for method in dict.fromkeys(r["method"] for r in done):
            curves = [r["curve"] for r in done if r["method"] == method]
            # every checkpoint step some seed reached (a run the automatic stop ended has fewer)
            steps = sorted(set.union(*({p["step"] for p in c} for c in curves)))
            at = lambda key, s, curves=curves: [p[key] for c in curves for p in c if p["step"] == s]
            xs = np.array([np.mean(at("seconds", s)) for s in steps])
            ys = [np.array(at(f"psnr_{protocol}", s)) for s in steps]
            mean = np.array([y.mean() for y in ys])
            style = (
                {"lw": 2.5, "color": "black"}
                if method == "wild-thermal"
                else ({"ls": "--"} if method.startswith("splatfacto") else {})
            )
            low = min(float(y.min()) for y in ys)
            label = f"{method} ({len(curves)} seed{'s' if len(curves) > 1 else ''})" + (
                f" (falls to {low:.0f} dB)" if low < floor else ""
            )
            (line,) = ax.plot(xs, np.maximum(mean, floor), marker="o", ms=3, label=label, **style)
            if len(curves) > 1:
                ax.fill_between(
                    xs,
                    np.maximum([y.min() for y in ys], floor),
                    np.maximum([y.max() for y in ys], floor),
                    color=line.get_color(),
                    alpha=0.2,
                    lw=0,
                )
            reached = np.flatnonzero(mean >= target) if target is not None else []
            if len(reached) and not method.startswith("splatfacto"):  # where it first reaches splatfacto's best
                k = int(reached[0])
                ax.plot(xs[k], mean[k], marker="*", ms=14, color=line.get_color(), mec="black", zorder=5)
            minima.append(low)
        if baseline is not None:
            label = f"{baseline[0]}'s best checkpoint, chosen on the held-out views (star: first reached)"
            ax.axhline(target, color="grey", lw=0.8, ls=":", label=label)
        fitted = " (a fit on each view)" if protocol == "aligned" else ""  # a gain and offset fitted on the view
        ax.set(
            title=f"{scene}: held-out {protocol}{fitted} PSNR\nvs training time",
            xlabel="training wall-clock seconds (evaluation excluded)",
            ylabel=f"PSNR (dB, original space, {protocol})",
        )
        ax.set_xscale("log")
        ax.xaxis.set_major_formatter(plain)
        ax.xaxis.set_minor_formatter(two_and_five)
        ax.set_ylim(bottom=max([floor, min(minima) - 1.0] if minima else [floor]))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.15))  # below the axes: no curve hidden
    fig.tight_layout()
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)


def main(args: BenchArgs) -> Dict:
    args.output_dir.mkdir(parents=True, exist_ok=True)
    if args.merge:
        merged = [json.loads(Path(p).read_text()) for p in args.merge]
        devices = {m["device"] for m in merged}
        if len(devices) > 1:
            raise ValueError(
                f"{', '.join(map(str, args.merge))}: runs come from different devices ({devices}); timings would "
                f"not compare"
            )
        _gather_strips([Path(p).parent / "strips" for p in args.merge], args.output_dir / "strips")
        return _write(
            args, [r for m in merged for r in m["runs"]], device=devices.pop(), torch_version=merged[0]["torch"]
        )
    if args.gpus > 1 or args.runs_per_gpu > 1:
        return _spread_over_gpus(args)
    runs = []
    for scene in args.scenes:
        for method in args.methods:
            if method == "splatfacto" and not torch.cuda.is_available():
                print("  splatfacto skipped: stock splatfacto needs CUDA")
                continue
            for seed in range(args.seed, args.seed + args.seeds):
                try:
                    runs.append(run_one(method, scene, args, seed))
                except (
                    torch.OutOfMemoryError,
                    RuntimeError,
                    ValueError,
                ) as err:  # a method failing is a result, not the end of the bench
                    message = str(err).splitlines()[0][:300]
                    print(f"  {method} on {scene_name(scene)} (seed {seed}) FAILED: {type(err).__name__}: {message}")
                    runs.append(
                        {
                            "method": run_label(method, args),
                            "scene": scene_name(scene),
                            "seed": seed,
                            "steps": args.steps,
                            "failed": f"{type(err).__name__}: {message}",
                        }
                    )
                    gc.collect()  # the failed trainer's tensors
                    if torch.cuda.is_available():
                        torch.cuda.empty_cache()
                _write(args, runs)  # after every run: a crash later keeps what finished
    return _write(args, runs)


def _write(
    args: BenchArgs, runs: List[Dict], device: Optional[str] = None, torch_version: Optional[str] = None
) -> Dict:
    scenes = list(dict.fromkeys(r["scene"] for r in runs))
    result = {
        "args": {
            k: (str(v) if isinstance(v, Path) else [str(x) for x in v] if k == "merge" else v)
            for k, v in vars(args).items()
        },
        "device": device or device_name(),
        "torch": torch_version or torch.__version__,
        "runs": runs,
    }
    # compact: benches are committed under docs/results, and the tree travels to the GPU machine beside the data
    (args.output_dir / "bench.json").write_text(json.dumps(result, separators=(",", ":")))
    (args.output_dir / "bench.md").write_text(markdown(runs, scenes))
    if scenes:  # nothing to chart when every run was skipped (e.g. only splatfacto, on a CPU)
        chart(runs, scenes, args.output_dir / "speed_accuracy.png")
        chart(runs, scenes, args.output_dir / "speed_time.png", protocol="time")
    for folder in (
        sorted((args.output_dir / "strips").glob("stress-*")) if (args.output_dir / "strips").is_dir() else []
    ):
        strip_png(folder, args.output_dir / f"{folder.name}_path_strip.png")
    return result


def _command_line(settings: BenchArgs) -> List[str]:
    """`settings` as this bench's command line (every field but those that spread runs or merge them)."""
    import sys

    command = [sys.executable, "-m", "experiments.bench"]
    for field in dataclasses.fields(settings):
        value = getattr(settings, field.name)
        if field.name not in ("gpus", "runs_per_gpu", "merge") and isinstance(value, bool):
            command.append(f"--{'' if value else 'no-'}{field.name.replace('_', '-')}")
        elif field.name not in ("gpus", "runs_per_gpu", "merge") and value is not None:
            command += [f"--{field.name.replace('_', '-')}", *map(str, value if isinstance(value, tuple) else (value,))]
    return command


def gpu_devices(gpus: int) -> List[str]:
    """The `CUDA_VISIBLE_DEVICES` value of each of `gpus` GPUs: the first `gpus` the parent may see where it
    is limited (so two benches can share one host, `CUDA_VISIBLE_DEVICES=2,3` for the second), else 0..gpus-1."""
    visible = [d.strip() for d in os.environ.get("CUDA_VISIBLE_DEVICES", "").split(",") if d.strip()]
    if not visible:
        return [str(gpu) for gpu in range(gpus)]
    if len(visible) < gpus:
        raise ValueError(f"--gpus {gpus} asks more GPUs than CUDA_VISIBLE_DEVICES={','.join(visible)} lets it see")
    return visible[:gpus]


def run_in_gpu_queues(jobs: List[BenchArgs], gpus: int, runs_per_gpu: int = 1) -> List[Path]:
    """Each job (a bench of one scene and method, in its own `output_dir`) as its own process, in
    `gpus * runs_per_gpu` queues run side by side; job k goes to queue k mod queues, on GPU k mod
    `gpus` (`CUDA_VISIBLE_DEVICES`, `gpu_devices`), one job at a time per queue. Each process gets an equal share of
    the CPU cores as torch threads (`OMP_NUM_THREADS`, unless set): with torch's default, every
    process would start one thread per core. Each output folder gets the run's log.txt. Returns the
    bench.json files written, in job order (a killed or crashed run writes none)."""
    import subprocess
    import threading

    queues = gpus * runs_per_gpu
    devices = gpu_devices(gpus)
    package_root = str(Path(__file__).resolve().parents[1])  # the workers import this same code
    env = {
        "OMP_NUM_THREADS": str(max(1, (os.cpu_count() or 1) // queues)),
        **os.environ,
        RUNS_PER_GPU_VARIABLE: str(
            runs_per_gpu
        ),  # each run labels its own record, so one finished before a kill is labelled too
        "PYTHONPATH": os.pathsep.join(filter(None, (package_root, os.environ.get("PYTHONPATH")))),
    }
    written: Dict[int, Path] = {}

    def work(queue: int) -> None:
        gpu = queue % gpus
        for k in range(queue, len(jobs), queues):
            job, folder = jobs[k], jobs[k].output_dir
            folder.mkdir(parents=True, exist_ok=True)
            with open(folder / "log.txt", "w") as log:
                code = subprocess.call(
                    _command_line(job),
                    env={**env, "CUDA_VISIBLE_DEVICES": devices[gpu]},
                    stdout=log,
                    stderr=subprocess.STDOUT,
                )
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
    """Every scene x method x seed run in `output_dir/gpuI/NN_SCENE_METHOD_seedS/` over `args.gpus` GPUs, merged."""
    triples = [
        (scene, method, seed)
        for scene in args.scenes
        for method in args.methods
        for seed in range(args.seed, args.seed + args.seeds)
    ]
    cache = args.cache_dir or args.output_dir / "cache"  # one cache for all (triangulation once)
    jobs = [
        dataclasses.replace(
            args,
            scenes=(scene,),
            methods=(method,),
            seed=seed,
            seeds=1,
            cache_dir=cache,
            gpus=1,
            runs_per_gpu=1,
            output_dir=args.output_dir / f"gpu{k % args.gpus}" / f"{k:02d}_{scene_name(scene)}_{method}_seed{seed}",
        )
        for k, (scene, method, seed) in enumerate(triples)
    ]
    done = run_in_gpu_queues(jobs, args.gpus, args.runs_per_gpu)
    if not done:
        raise RuntimeError(f"no run finished; see the logs under {args.output_dir}/gpu*/")
    merged = main(BenchArgs(merge=tuple(done), output_dir=args.output_dir))
    finished = {(r["scene"], r["method"], r.get("seed")) for r in merged["runs"]}
    lost = [(s, m, seed) for s, m, seed in triples if (scene_name(s), run_label(m, args), seed) not in finished]
    if lost:
        print(
            "  no result (see its log.txt): "
            + ", ".join(f"{m} on {scene_name(s)} (seed {seed})" for s, m, seed in lost)
        )
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
