"""One evaluation protocol for every variant (and stock splatfacto), so numbers are comparable.

- Space: the ORIGINAL radiometric space, dataset-normalised. Renders of variants trained on
  preprocessed frames are mapped back through the test frame's inverse LUT; the target is the
  evaluation frame as the dataset gives it (the raw held-out frame; clean ground truth for
  generated scenes). The model's own numbers in the preprocessed space are kept as
  `*_preprocessed` (what the paper most likely reported). The test frame's LUT carries that
  frame's photometric state, which no rendered novel view has: `*_median_lut` scores the same
  renders mapped back through the median training LUT instead, as `ns-render` maps every view.
- Held-out frame embedding (`EmbeddingMode`):
  `fixed`: the model's inference embedding (mean of the training frames');
  `interpolate`: linear in capture order between the neighbouring training frames' embeddings
  (thermal drift is temporal);
  `wild`: the NeRF-in-the-wild protocol: the embedding is optimised on the left half of the test
  frame, and only the right half is scored (every mode is scored on the right half then, so
  models without embeddings are comparable).
Models without frame embeddings render the same image in every mode.
"""

from __future__ import annotations

from pathlib import Path
from typing import Dict, List, Literal, Optional, Sequence, get_args

import numpy as np
import torch

from thermal_wild_ns.data.thermal_io import load_npy
from thermal_wild_ns.model.losses import psnr, ssim

EmbeddingMode = Literal["fixed", "interpolate", "wild"]
EMBEDDING_MODES = get_args(EmbeddingMode)


def interpolated_embedding(weight: torch.Tensor, train_frames: Sequence[int], frame: int) -> torch.Tensor:
    """Embedding [Df] for capture index `frame`, linear between the nearest training frames
    before and after it (`weight[k]` belongs to capture index `train_frames[k]`)."""
    order = np.asarray(train_frames)
    before, after = np.flatnonzero(order < frame), np.flatnonzero(order > frame)
    if len(before) == 0 or len(after) == 0:
        return weight[int(after[0] if len(before) == 0 else before[-1])]
    lo, hi = int(before[order[before].argmax()]), int(after[order[after].argmin()])
    t = (frame - order[lo]) / (order[hi] - order[lo])
    return (1 - t) * weight[lo] + t * weight[hi]


def _render(model, camera) -> torch.Tensor:
    """[H, W, 1] in the model's training space (grey mean of RGB for RGB models)."""
    outputs = model.get_outputs_for_camera(camera)
    return outputs["thermal"] if "thermal" in outputs else outputs["rgb"].mean(dim=-1, keepdim=True)


def _optimise_on_left_half(model, camera, target: torch.Tensor, steps: int, lr: float) -> torch.Tensor:
    """The frame embedding that best explains the left half of `target` ([H, W, 1], training space)."""
    start = model.frame_embed.weight.detach().mean(dim=0)
    embedding = start.clone().requires_grad_(True)  # a plain leaf: a Parameter would register in the model
    optimizer = torch.optim.Adam([embedding], lr=lr)
    half = target.shape[1] // 2
    model.embedding_override = embedding
    for _ in range(steps):
        optimizer.zero_grad()
        pred = model.get_outputs(camera)["thermal"]
        loss = (pred[:, :half] - target[:, :half]).abs().mean()
        loss.backward()
        optimizer.step()
    model.zero_grad(set_to_none=True)  # the Gaussians' gradients from these steps are not training's
    return embedding.detach()


def _scores(pred: np.ndarray, gt: np.ndarray, suffix: str = "") -> Dict[str, float]:
    def tensor(x):
        return torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32))[..., None]

    return {f"psnr{suffix}": float(psnr(tensor(pred), tensor(gt))), f"ssim{suffix}": float(ssim(tensor(pred), tensor(gt), data_range=1.0))}


def evaluate(
    pipeline, mode: EmbeddingMode = "fixed", out_dir: Optional[Path] = None, wild_steps: int = 100, wild_lr: float = 1e-2
) -> Dict:
    """Mean test-view PSNR/SSIM under the protocol above (per-view rows in `per_view`); with
    `out_dir`, a PNG per view: target | render | 5x error (inferno, original space)."""
    if mode not in EMBEDDING_MODES:
        raise ValueError(f"unknown embedding mode '{mode}' (one of {', '.join(EMBEDDING_MODES)})")
    model, datamanager = pipeline.model, pipeline.datamanager
    sequence = getattr(datamanager, "preprocessed", None)
    dataset = datamanager.eval_dataset
    train_frames: List[int] = list(datamanager.train_dataset.metadata["frame_indices"])
    has_embedding = hasattr(model, "frame_embed") and (model.emission_mlp is not None or model.background_mlp is not None)
    pipeline.eval()
    rows = []
    for i, (camera, batch) in enumerate(datamanager.fixed_indices_eval_dataloader):
        image_idx = int(batch["image_idx"])
        frame = int(dataset.metadata["frame_indices"][image_idx])
        if has_embedding and mode == "interpolate":
            model.embedding_override = interpolated_embedding(model.frame_embed.weight.detach(), train_frames, frame)
        elif has_embedding and mode == "wild":
            target = batch["image"].to(model.device)
            with torch.enable_grad():
                model.embedding_override = _optimise_on_left_half(model, camera, target, wild_steps, wild_lr)
        try:
            with torch.no_grad():
                rendered = _render(model, camera)[..., 0].float().cpu().numpy()
        finally:
            if has_embedding:
                model.embedding_override = None
        training_space_gt = batch["image"].float().mean(dim=-1).cpu().numpy()  # what the model was trained on
        # the evaluation frame as cached (undistorted like the render), back in the original space
        to_original = (lambda x: x) if sequence is None else (lambda x: sequence.to_original_normalised(x, frame).astype(np.float32))
        gt, pred = to_original(training_space_gt), to_original(rendered)
        if mode == "wild":  # score only what the embedding did not see
            half = gt.shape[1] // 2
            pred, gt, rendered, training_space_gt = (x[:, half:] for x in (pred, gt, rendered, training_space_gt))
        row = {"frame": frame, **_scores(pred, gt)}
        if sequence is not None:
            row.update(_scores(rendered, training_space_gt, "_preprocessed"))
            row.update(_scores(datamanager.novel_view_to_original(rendered), gt, "_median_lut"))  # per pixel: the median training LUT
        rows.append(row)
        if out_dir is not None:
            _write_panel(out_dir / f"test_{i:02d}_{mode}.png", gt, pred)
    keys = [k for k in rows[0] if k != "frame"]
    summary = {key: float(np.mean([r[key] for r in rows])) for key in keys}
    return {**summary, "mode": mode, "per_view": rows, "gaussians": int(model.num_points)}


def _write_panel(path: Path, gt: np.ndarray, pred: np.ndarray) -> None:
    import cv2

    from thermal_wild_ns.data.palettes import false_colour

    path.parent.mkdir(parents=True, exist_ok=True)
    panel = np.concatenate([false_colour(gt), false_colour(pred), false_colour(np.abs(pred - gt) * 5)], 1)  # x5: small errors visible
    scale = max(1, 384 // gt.shape[0])
    cv2.imwrite(str(path), cv2.resize(panel, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST))


def evaluate_path(pipeline, scene_root: Path, keep_frames: Sequence[int] = ()) -> Dict:
    """Renders along a generated scene's smooth camera path (`transforms.json` "path": clean views
    with true depth) with the fixed embedding, scored with the stability measures. Preprocessed
    renders are mapped back through the median training LUT (no frame was captured there).
    Returns the means, the flicker measures, and the renders and ground truth at `keep_frames`
    (original space; `kept`, `kept_truth`)."""
    import json

    from nerfstudio.cameras.cameras import Cameras, CameraType

    from thermal_wild_ns.analysis.stability import background_error, error_exceedance, flicker, floater_fraction, visible_floater_fraction

    meta = json.loads((Path(scene_root) / "transforms.json").read_text())
    if not meta.get("path"):
        raise ValueError(f"{scene_root}/transforms.json: no 'path' views (generate the scene with path_views > 0)")
    model, datamanager = pipeline.model, pipeline.datamanager
    outputs_meta = datamanager.train_dataparser_outputs
    transform, scale = outputs_meta.dataparser_transform.float(), float(outputs_meta.dataparser_scale)
    reference = datamanager.train_dataset.cameras[0]
    rng = datamanager.train_dataset.thermal_range
    pipeline.eval()
    preds, gts, rows, kept, kept_truth = [], [], [], {}, {}
    for k, view in enumerate(meta["path"]):
        c2w = torch.tensor(view["transform_matrix"], dtype=torch.float32)
        c2w = transform @ c2w  # [3, 4]
        c2w[:3, 3] *= scale
        camera = Cameras(
            camera_to_worlds=c2w[None], fx=reference.fx[None], fy=reference.fy[None], cx=reference.cx[None], cy=reference.cy[None],
            width=reference.width[None], height=reference.height[None], camera_type=CameraType.PERSPECTIVE,
        ).to(model.device)
        with torch.no_grad():
            outputs = model.get_outputs_for_camera(camera)
        pred = (outputs["thermal"] if "thermal" in outputs else outputs["rgb"].mean(-1, keepdim=True))[..., 0].float().cpu().numpy()
        pred = datamanager.novel_view_to_original(pred)
        gt = rng.read(Path(scene_root) / view["file_path"])
        true_depth = load_npy(Path(scene_root) / view["depth_npy_path"]) * scale  # scene units, like the render's
        depth = outputs["depth"][..., 0].float().cpu().numpy()
        alpha = outputs["accumulation"][..., 0].float().cpu().numpy()
        rows.append({
            **_scores(pred, gt),
            "floater_fraction": floater_fraction(depth, alpha, true_depth),
            "visible_floater_fraction": visible_floater_fraction(depth, alpha, true_depth, pred, gt, 0.1),
            "error_exceedance": error_exceedance(pred, gt, 0.1),
            "background_error": background_error(pred, gt, true_depth),
        })
        preds.append(pred)
        gts.append(gt)
        if k in keep_frames:
            kept[k], kept_truth[k] = pred, gt
    summary = {key: float(np.nanmean([r[key] for r in rows])) for key in rows[0]}
    flickers = {f"flicker_{k}": v for k, v in flicker(preds, gts).items()}
    return {**summary, **flickers, "views": len(rows), "kept": kept, "kept_truth": kept_truth}
