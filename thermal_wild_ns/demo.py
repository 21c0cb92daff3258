"""`wild-thermal-demo`: train wild-thermal on the embedded scene, evaluate, write metrics and frames.

The README's main command. On a CPU it uses the pure-torch rasterizer and a short schedule; with
a GPU, gsplat and a longer one. Outputs (under --output-dir):
  metrics.json                 test-view PSNR/SSIM (against clean ground truth), steps, wall time
  renders/test_XX.png          ground truth | render | |error| per test view (inferno colormap)
  wild-thermal/<run>/          nerfstudio's config.yml and checkpoint (usable by ns-eval/ns-render/ns-viewer)
"""

from __future__ import annotations

import copy
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import torch
import tyro

import thermal_wild_ns.compat  # noqa: F401


@dataclass
class DemoArgs:
    output_dir: Path = Path("outputs/demo")
    """Where the scene, the run and the results go."""
    steps: Optional[int] = None
    """Training steps (default: 800 on CPU, 10000 on GPU)."""
    max_gaussians: int = 10_000
    """Gaussian budget; the 128x96 demo scene needs few."""


def demo_trainer_config(output_dir: Path, steps: int, max_gaussians: int, method: str = "wild-thermal"):
    """A registered method's config (`wild-thermal` or one of its ablations), scheduled for the small demo scene."""
    from method_configs import wild_thermal as methods
    from thermal_wild_ns.data.dataparsers import ThermalDemoDataParserConfig

    specs = {"wild-thermal": methods.wild_thermal, **methods.ablation_methods}
    if method not in specs:
        raise ValueError(f"unknown method '{method}' (one of {', '.join(specs)})")
    config = copy.deepcopy(specs[method].config)
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
    return config


def _inferno(x: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.applyColorMap((np.clip(x, 0, 1) * 255).astype(np.uint8), cv2.COLORMAP_INFERNO)


def evaluate(pipeline, out_dir: Optional[Path] = None) -> dict:
    """Test-view metrics (fixed inference embedding), averaged, in the ORIGINAL radiometric space
    against the evaluation frame (clean ground truth where the scene has it). With preprocessing
    the render is mapped back through the test frame's inverse LUT (`psnr`, `ssim`); also reported:
    through the mean training LUT (`*_mean_lut`, for views no frame was captured at), against the
    raw captured frame (`*_vs_captured`, where a clean ground truth exists), and the model's own
    numbers in the preprocessed space (`*_preprocessed`). With `out_dir`, a PNG panel per view."""
    import cv2

    from thermal_wild_ns.model.losses import psnr, ssim

    def scores(pred: np.ndarray, gt: np.ndarray, suffix: str = "") -> dict:
        as_tensor = lambda x: torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32))[..., None]  # noqa: E731
        return {f"psnr{suffix}": float(psnr(as_tensor(pred), as_tensor(gt))), f"ssim{suffix}": float(ssim(as_tensor(pred), as_tensor(gt), data_range=1.0))}

    pipeline.eval()
    datamanager = pipeline.datamanager
    sequence = datamanager.preprocessed
    dataset = datamanager.eval_dataset
    train_frames = list(datamanager.train_dataset.metadata["frame_indices"])
    captured = datamanager.dataparser.capture().frames
    rows = []
    for i, (camera, batch) in enumerate(datamanager.fixed_indices_eval_dataloader):
        with torch.no_grad():
            outputs = pipeline.model.get_outputs_for_camera(camera)
            metrics, _ = pipeline.model.get_image_metrics_and_images(outputs, batch)
        pred = outputs["thermal"].cpu().numpy()[..., 0]
        gt = batch["image"].cpu().numpy()[..., 0]
        row = {"psnr": metrics["psnr"], "ssim": metrics["ssim"]}
        if sequence is not None:
            index, image_idx = int(batch["frame_index"]), int(batch["image_idx"])
            gt = dataset.thermal_range.read(dataset.image_filenames[image_idx])
            row = {**scores(sequence.to_original_normalised(pred, index), gt), **scores(sequence.to_original_normalised(pred, train_frames), gt, "_mean_lut")}
            if dataset.metadata["is_ground_truth"][image_idx]:
                raw = dataset.thermal_range.read(captured[index].image)
                row.update(scores(sequence.to_original_normalised(pred, index), raw, "_vs_captured"))
            row.update({"psnr_preprocessed": metrics["psnr"], "ssim_preprocessed": metrics["ssim"]})
            pred = sequence.to_original_normalised(pred, index)
        rows.append(row)
        if out_dir is not None:
            out_dir.mkdir(parents=True, exist_ok=True)
            err = np.abs(pred - gt) * 5  # x5 so small errors are visible
            panel = np.concatenate([_inferno(gt), _inferno(pred), _inferno(err)], 1)
            cv2.imwrite(str(out_dir / f"test_{i:02d}.png"), cv2.resize(panel, None, fx=3, fy=3, interpolation=cv2.INTER_NEAREST))
    summary = {key: float(np.mean([r[key] for r in rows])) for key in rows[0]}
    return {**summary, "per_view": rows, "gaussians": int(pipeline.model.num_points)}


def main(args: DemoArgs) -> dict:
    from nerfstudio.utils.eval_utils import eval_setup

    from thermal_wild_ns.data.demo_scene import generate_demo_scene

    device = "cuda" if torch.cuda.is_available() else "cpu"
    steps = args.steps or (10_000 if device == "cuda" else 800)
    generate_demo_scene(args.output_dir / "scene")
    config = demo_trainer_config(args.output_dir, steps, args.max_gaussians)
    config.save_config()
    trainer = config.setup(local_rank=0, world_size=1)
    trainer.setup()
    untrained = evaluate(trainer.pipeline)
    start = time.time()
    trainer.train()
    train_seconds = time.time() - start
    # evaluate from the saved checkpoint, the way ns-eval / ns-render load it
    _, pipeline, _, _ = eval_setup(config.get_base_dir() / "config.yml", test_mode="test")
    results = evaluate(pipeline, args.output_dir / "renders")
    results.update(
        {
            "device": device,
            "steps": steps,
            "train_seconds": round(train_seconds, 1),
            "untrained_psnr": untrained["psnr"],
            "config": str(config.get_base_dir() / "config.yml"),
            "ground_truth": "clean (fault-free) frames of the held-out views",
        }
    )
    with open(args.output_dir / "metrics.json", "w") as f:
        json.dump(results, f, indent=1)
    print(
        f"\nwild-thermal demo ({device}, {steps} steps, {train_seconds:.0f} s): test PSNR {results['psnr']:.2f} dB, "
        f"SSIM {results['ssim']:.3f} (untrained {untrained['psnr']:.2f} dB), {results['gaussians']} Gaussians\n"
        f"results: {args.output_dir / 'metrics.json'}, renders in {args.output_dir / 'renders'}"
    )
    return results


def entrypoint():
    main(tyro.cli(DemoArgs))


if __name__ == "__main__":
    entrypoint()
