"""Experiments beside the plugin (not installed): accuracy vs speed, training-step profiles,
render speed, Gaussian budget, preprocessing sweeps. Run from a checkout: `python -m experiments.NAME --help`."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, List, Optional, Tuple


def device_name() -> str:
    """What the numbers were measured on (written beside every benchmark result)."""
    import torch

    return torch.cuda.get_device_name() if torch.cuda.is_available() else "cpu"


def synchronize() -> None:
    """Wait for the GPU's queued work (a no-op on CPU): timings must end where the work does."""
    import torch

    if torch.cuda.is_available():
        torch.cuda.synchronize()


def mean_range(values) -> str:
    """A score over seeds as the tables print it: mean (min–max), two decimals."""
    values = [float(v) for v in values]
    return f"{sum(values) / len(values):.2f} ({min(values):.2f}–{max(values):.2f})"


def write_report(path, text: str) -> None:
    """Write a Markdown report (its folder made if missing) and print it."""
    from pathlib import Path

    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(text)
    print(text)


def offset_fitted(render, target) -> Tuple[float, float]:
    """(mean error of `render` against `target` [H, W], the render's PSNR with that mean taken out): an
    offset fitted on the scored view itself, so the second number is a fit, not a result."""
    import numpy as np

    from thermal_wild_ns.pipeline.evaluation import scores

    bias = float(np.mean(render - target))
    return bias, scores(render - bias, target)["psnr"]


def held_out_views(config: Path):
    """A trained run's held-out views, loaded from its config.yml: (pipeline, camera, index in the eval
    dataset, capture frame) per view, in the evaluation's order."""
    from nerfstudio.utils.eval_utils import eval_setup

    _, pipeline, _, _ = eval_setup(config, test_mode="test")
    frames = pipeline.datamanager.eval_dataset.metadata["frame_indices"]
    for camera, batch in pipeline.datamanager.fixed_indices_eval_dataloader:
        index = int(batch["image_idx"])
        yield pipeline, camera, batch, index, int(frames[index])


def json_from_module(module: str, *args: str) -> dict:
    """The JSON object `python -m module args` prints on its last line, run in a process of its own (each
    checkpoint scored in a fresh process, so no state of one run's model reaches the next)."""
    import json
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-m", module, *args], check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def score_checkpoints(description: str, score_run: Callable[[Path], dict], line: Callable[[dict], str]) -> List[dict]:
    """The command line of a script that scores trained runs one by one: `score_run(config.yml)` per run
    given, `line(result)` printed for each, every result written to `--output` (JSON) if asked."""
    import argparse
    import json

    from thermal_wild_ns._upstream import prepare_checkpoint_commands

    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("configs", type=Path, nargs="+", help="runs' config.yml")
    parser.add_argument("--output", type=Path, help="write every run's scores here (JSON)")
    args = parser.parse_args()
    prepare_checkpoint_commands()
    results = []
    for config in args.configs:
        results.append(score_run(config))
        print(f"{config}: {line(results[-1])}")
    if args.output:
        args.output.parent.mkdir(parents=True, exist_ok=True)
        args.output.write_text(json.dumps(results, indent=1))
    return results


def gpu_kernel_microseconds(prof) -> float:
    """Time the GPU spent in kernels and copies under the torch profiler `prof` (not in the ranges named by
    record_function, which the profiler also reports on the GPU timeline and which overlap the kernels)."""
    from torch.autograd import DeviceType

    return sum(
        e.time_range.elapsed_us()
        for e in prof.events()
        if e.device_type == DeviceType.CUDA
        and not getattr(e, "is_user_annotation", False)
        and not e.name.startswith(("thermal/", "Optimizer.", "ProfilerStep"))
    )


def python_profile_markdown(profiler, per: int, rows: int = 30) -> str:
    """Markdown tables of a `cProfile.Profile`'s functions by cumulative time and by own time, per step
    or frame (`per`: how many the profile covered): where the host's time goes, by Python function.
    Times are inflated by the profiler itself; the ranking is what to read."""
    import pstats

    stats = pstats.Stats(profiler).stats  # {(file, line, name): (calls, primitive, tottime, cumtime, callers)}
    tables = []
    for title, column in (("by cumulative time", 3), ("by own time (where the host's time is spent)", 2)):
        top = sorted(stats.items(), key=lambda kv: kv[1][column], reverse=True)[:rows]
        lines = [title, "", "| function | calls each | own ms each | cumulative ms each |", "| --- | --- | --- | --- |"]
        for (path, line, name), (calls, _, own, cumulative, _) in top:
            where = f"{path.split('site-packages/')[-1]}:{line}({name})" if line else name
            each = f"{calls / per:.1f} | {1000 * own / per:.3f} | {1000 * cumulative / per:.3f}"
            lines.append(f"| {where[-90:]} | {each} |")
        tables.append("\n".join(lines) + "\n")
    return "\n".join(tables)


def train_with_hooks(
    trainer, steps: int, after_step: Callable[[int], None], before_first_step: Optional[Callable[[], None]] = None
) -> None:
    """`steps` steps of nerfstudio's own `Trainer.train` (its loop, callbacks, logging and final
    checkpoint, as `ns-train` runs them), with `after_step(step)` called after every training
    iteration and `before_first_step()` before the first (e.g. to start a clock)."""
    from nerfstudio.engine.callbacks import TrainingCallback, TrainingCallbackLocation

    hooks = [TrainingCallback([TrainingCallbackLocation.AFTER_TRAIN_ITERATION], lambda step: after_step(step))]
    if before_first_step is not None:
        start = trainer._start_step

        def before(step: int) -> None:
            if step == start:
                before_first_step()

        hooks.append(TrainingCallback([TrainingCallbackLocation.BEFORE_TRAIN_ITERATION], before))
    trainer.config.max_num_iterations = steps
    trainer.callbacks = [*trainer.callbacks, *hooks]
    try:
        trainer.train()
    finally:
        trainer.callbacks = [c for c in trainer.callbacks if c not in hooks]


def read_capture(scene, cache_dir):
    """A dataset folder read as the full method reads it (any layout; `cache_dir` holds its
    triangulation): (its data parser, its capture, its radiometric range)."""
    from pathlib import Path

    from thermal_wild_ns.data.dataparsers import ThermalDataParserConfig

    parser = ThermalDataParserConfig(data=Path(scene).resolve(), cache_dir=Path(cache_dir).resolve()).setup()
    return parser, parser.capture(), parser.radiometric_range()


@dataclass
class SceneStudyArgs:
    """The arguments of a study of dataset folders without a model (`experiments.lut_prediction`,
    `experiments.canonical_lut`)."""

    scenes: List[Path] = field(default_factory=list)
    """Scene folders (any layout the data parser reads)."""
    output_dir: Path = Path("outputs/study")
    """Where the study's JSON and Markdown go."""
    cache_dir: Path = Path(".cache/study")
    """Where the triangulation and preprocessing caches go."""


def split_luts(scene, cache_dir):
    """A dataset folder's capture, radiometric range, training frames of its default split (sorted)
    and the full method's LUTs of every frame (`full_method_luts`)."""
    parser, capture, rng = read_capture(scene, cache_dir)
    train = sorted(parser.get_dataparser_outputs("train").metadata["frame_indices"])
    chosen = set(train)
    sequence = full_method_luts(capture, rng, cache_dir, [t in chosen for t in range(len(capture.frames))])
    return capture, rng, train, sequence


def full_method_luts(capture, rng, cache_dir, train):
    """The `PreprocessedSequence` (each frame's LUT) of the paper's preprocessing (stab+bbhe) with the full
    method's settings, forced on (the full method trains on the raw frames unless asked, and its rule may
    skip it then); `train` [frames]: which are training frames."""
    import dataclasses
    from pathlib import Path

    from thermal_wild_ns.method_configs import method_trainer
    from thermal_wild_ns.preprocessing.stage import preprocess

    config = dataclasses.replace(method_trainer("wild-thermal").pipeline.datamanager.preprocessing, variant="stab+bbhe")
    return preprocess(capture.frames, rng, config, Path(cache_dir).resolve(), train=list(train))
