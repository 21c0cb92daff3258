"""One evaluation protocol for every variant (and stock splatfacto), so numbers are comparable.

- Space: the ORIGINAL radiometric space, dataset-normalised. Renders of variants trained on
  preprocessed frames are mapped back through the test frame's inverse LUT; the target is the
  evaluation frame as the dataset gives it (the raw held-out frame; clean ground truth for
  generated scenes). The model's own numbers in the preprocessed space are kept as
  `*_preprocessed` (what the paper most likely reported).
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
from typing import Dict, List, Literal, Optional, Sequence

import numpy as np
import torch

from thermal_wild_ns.model.losses import psnr, ssim

EmbeddingMode = Literal["fixed", "interpolate", "wild"]
EMBEDDING_MODES = ("fixed", "interpolate", "wild")


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
        gt = dataset.thermal_range.read(dataset.image_filenames[image_idx])
        pred = rendered if sequence is None else sequence.to_original_normalised(rendered, frame).astype(np.float32)
        if mode == "wild":  # score only what the embedding did not see
            half = gt.shape[1] // 2
            pred, gt, rendered, training_space_gt = (x[:, half:] for x in (pred, gt, rendered, training_space_gt))
        row = {"frame": frame, **_scores(pred, gt)}
        if sequence is not None:
            row.update(_scores(rendered, training_space_gt, "_preprocessed"))
        rows.append(row)
        if out_dir is not None:
            _write_panel(out_dir / f"test_{i:02d}_{mode}.png", gt, pred)
    keys = [k for k in rows[0] if k != "frame"]
    summary = {key: float(np.mean([r[key] for r in rows])) for key in keys}
    return {**summary, "mode": mode, "per_view": rows, "gaussians": int(model.num_points)}


def _write_panel(path: Path, gt: np.ndarray, pred: np.ndarray) -> None:
    import cv2

    def inferno(x):
        return cv2.applyColorMap((np.clip(x, 0, 1) * 255).astype(np.uint8), cv2.COLORMAP_INFERNO)

    path.parent.mkdir(parents=True, exist_ok=True)
    panel = np.concatenate([inferno(gt), inferno(pred), inferno(np.abs(pred - gt) * 5)], 1)  # x5: small errors visible
    scale = max(1, 384 // gt.shape[0])
    cv2.imwrite(str(path), cv2.resize(panel, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST))
