"""Scores along a generated scene's smooth camera path: renders at the canonical state between the
training views, with the stability measures (floaters, flicker, background error) that need the
scene's true depth. Generated scenes only (`transforms.json` "path" views); the bench calls it."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Dict

import numpy as np
import torch
from nerfstudio.cameras.cameras import Cameras, CameraType

from thermal_wild_ns.analysis.stability import (
    background_error,
    error_exceedance,
    flicker,
    floater_fraction,
    visible_floater_fraction,
)
from thermal_wild_ns.data.thermal_io import load_npy
from thermal_wild_ns.pipeline.evaluation import scores
from thermal_wild_ns.pipeline.photometric_state import canonical_state, outputs_at, thermal_output, to_original


def evaluate_path(pipeline, scene_root: Path, keep_frames=()) -> Dict:
    """Renders along a generated scene's smooth camera path (`transforms.json` "path": clean views
    with true depth) at the canonical state, scored with the stability measures. Returns the means,
    the flicker measures, and the renders and ground truth at `keep_frames` (original space;
    `kept`, `kept_truth`)."""
    meta = json.loads((Path(scene_root) / "transforms.json").read_text())
    if not meta.get("path"):
        raise ValueError(f"{scene_root}/transforms.json: no 'path' views (generate the scene with path_views > 0)")
    model, datamanager = pipeline.model, pipeline.datamanager
    outputs_meta = datamanager.train_dataparser_outputs
    transform, scale = outputs_meta.dataparser_transform.float(), float(outputs_meta.dataparser_scale)
    reference = datamanager.train_dataset.cameras[0]
    rng = datamanager.train_dataset.thermal_range
    pipeline.eval()
    canonical = canonical_state(pipeline)
    preds, gts, rows, kept, kept_truth = [], [], [], {}, {}
    for k, view in enumerate(meta["path"]):
        c2w = torch.tensor(view["transform_matrix"], dtype=torch.float32)
        c2w = transform @ c2w  # [3, 4]
        c2w[:3, 3] *= scale
        camera = Cameras(
            camera_to_worlds=c2w[None],
            fx=reference.fx[None],
            fy=reference.fy[None],
            cx=reference.cx[None],
            cy=reference.cy[None],
            width=reference.width[None],
            height=reference.height[None],
            camera_type=CameraType.PERSPECTIVE,
        ).to(model.device)
        with torch.no_grad():
            outputs = outputs_at(model, camera, canonical)
        pred = to_original(pipeline, thermal_output(outputs)[..., 0].float().cpu().numpy(), canonical)
        gt = rng.read(Path(scene_root) / view["file_path"])
        true_depth = load_npy(Path(scene_root) / view["depth_npy_path"]) * scale  # scene units, like the render's
        depth = outputs["depth"][..., 0].float().cpu().numpy()
        alpha = outputs["accumulation"][..., 0].float().cpu().numpy()
        rows.append(
            {
                **scores(pred, gt),
                "floater_fraction": floater_fraction(depth, alpha, true_depth),
                "visible_floater_fraction": visible_floater_fraction(depth, alpha, true_depth, pred, gt, 0.1),
                "error_exceedance": error_exceedance(pred, gt, 0.1),
                "background_error": background_error(pred, gt, true_depth),
            }
        )
        preds.append(pred)
        gts.append(gt)
        if k in keep_frames:
            kept[k], kept_truth[k] = pred, gt
    summary = {key: float(np.nanmean([r[key] for r in rows])) for key in rows[0]}
    flickers = {f"flicker_{k}": v for k, v in flicker(preds, gts).items()}
    return {**summary, **flickers, "views": len(rows), "kept": kept, "kept_truth": kept_truth}
