"""`wild-thermal-demo`: train wild-thermal on the embedded scene, evaluate, write metrics and frames.

The README's main command. On a CPU it uses the pure-torch rasterizer and a short schedule; with
a GPU, gsplat and a longer one. Outputs (under --output-dir):
  metrics.json                 held-out PSNR/SSIM under every protocol (pipeline/evaluation.py: novel and
                               aligned against the clean frames, the others the recorded); steps, wall time
  renders/test_XX.png          recorded frame | render at its time state | 5x error (inferno colormap)
  renders/test_XX_celsius.png  the same in °C (the demo's documented bounds), the error on a fixed 0-2 °C scale
  wild-thermal/<run>/          nerfstudio's config.yml and checkpoint (usable by ns-eval/ns-render/ns-viewer)
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import torch
import tyro
from nerfstudio.utils.eval_utils import eval_setup

from thermal_wild_ns.data.dataparsers import ThermalDemoDataParserConfig
from thermal_wild_ns.data.demo_scene import generate_demo_scene
from thermal_wild_ns.errors import report_input_errors_briefly
from thermal_wild_ns.method_configs import method_trainer
from thermal_wild_ns.pipeline.evaluation import evaluate
from thermal_wild_ns.training.trainer import seeded_trainer


@dataclass
class DemoArgs:
    output_dir: Path = Path("outputs/demo")
    """Where the scene, the run and the results go."""
    steps: Optional[int] = None
    """Training steps at most (default: 800 on CPU, 10000 on GPU); the automatic stop may end the run sooner."""
    max_gaussians: int = 10_000
    """Gaussian budget the run starts from (the held-back frames may double it); the 128x96 demo scene needs few."""
    seed: Optional[int] = None
    """Seed of the random generators and of the order the training frames are visited in (default: the method's
    config's); runs of several seeds show the spread of a score."""


def demo_trainer_config(output_dir: Path, steps: int, max_gaussians: int, method: str = "wild-thermal"):
    """A registered method's config (`wild-thermal` or one of its ablations), scheduled for the small demo scene."""

    config = method_trainer(method)
    config.output_dir = output_dir
    config.experiment_name = "demo"
    config.timestamp = "run"
    config.vis = "tensorboard"
    config.max_num_iterations = steps
    config.steps_per_save = steps
    config.steps_per_eval_image = max(steps // 5, 1)
    config.save_only_latest_checkpoint = True
    config.pipeline.datamanager.dataparser = ThermalDemoDataParserConfig(data=output_dir / "scene")
    config.pipeline.datamanager.preprocessing_cache = output_dir / ".thermal_cache"
    model = config.pipeline.model
    model.num_downscales = 0  # 128x96 frames: no coarse-to-fine needed
    model.max_gaussians = max_gaussians
    model.warmup_length = min(model.warmup_length, steps // 10)
    model.refine_every = min(model.refine_every, max(steps // 30, 10))
    model.reset_alpha_every = 30
    model.stop_split_at = int(steps * 0.6)
    model.stop_screen_size_at = int(steps * 0.3)
    config.auto_stop.scale_to(steps)
    config.auto_stop.budget_start = max_gaussians  # the demo's budget, whoever sets it
    return config


def main(args: DemoArgs) -> dict:
    device = "cuda" if torch.cuda.is_available() else "cpu"
    steps = args.steps or (10_000 if device == "cuda" else 800)
    generate_demo_scene(args.output_dir / "scene")
    config = demo_trainer_config(args.output_dir, steps, args.max_gaussians)
    if args.seed is not None:
        config.machine.seed = config.pipeline.datamanager.train_order_seed = args.seed
    config.save_config()
    trainer = seeded_trainer(config)
    untrained = evaluate(trainer.pipeline, protocols=("novel",))
    start = time.time()
    trainer.train()
    train_seconds = time.time() - start
    trained = trainer.step + 1
    record = config.get_base_dir() / "auto_stop.json"
    auto_stop = json.loads(record.read_text()) if record.is_file() else None
    # evaluate from the saved checkpoint, the way ns-eval / ns-render load it
    _, pipeline, _, _ = eval_setup(config.get_base_dir() / "config.yml", test_mode="test")
    start = time.time()
    results = evaluate(pipeline, args.output_dir / "renders")
    score_seconds = time.time() - start
    results.update(
        {
            "device": device,
            "steps": trained,
            "steps_asked": steps,
            "auto_stop": auto_stop,
            "train_seconds": round(train_seconds, 1),
            "score_seconds": round(score_seconds, 1),
            "untrained_psnr_novel": untrained["psnr_novel"],
            "config": str(config.get_base_dir() / "config.yml"),
            "ground_truth": "novel, aligned: clean (fault-free) frames of the held-out views; "
            "time, half, oracle: the held-out frames as recorded",
        }
    )
    with open(args.output_dir / "metrics.json", "w") as f:
        json.dump(results, f, indent=1)
    print(
        f"\nwild-thermal demo ({device}, {trained} of {steps} steps, {train_seconds:.0f} s"
        + (f", model of step {auto_stop['kept_step']} kept" if auto_stop else "")
        + f"; {len(results['per_view'])} held-out views scored in {score_seconds:.0f} s"
        + "), held-out views against the clean frames:\n"
        f"  novel (canonical state)        PSNR {results['psnr_novel']:.2f} dB, SSIM {results['ssim_novel']:.3f}"
        f" (untrained {untrained['psnr_novel']:.2f} dB)\n"
        f"  time (state from neighbours)   PSNR {results['psnr_time']:.2f} dB, SSIM {results['ssim_time']:.3f}\n"
        f"  aligned (novel + gain/offset)  PSNR {results['psnr_aligned']:.2f} dB, SSIM {results['ssim_aligned']:.3f}\n"
        f"  {results['gaussians']} Gaussians\n"
        f"results: {args.output_dir / 'metrics.json'}, renders in {args.output_dir / 'renders'}"
    )
    return results


def entrypoint():
    report_input_errors_briefly()
    main(tyro.cli(DemoArgs))


if __name__ == "__main__":
    entrypoint()
