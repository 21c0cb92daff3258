"""What a person sees in a video, as numbers: floaters, flicker, background collapse.

All functions take renders and ground truth in the same (dataset-normalised) space; depths are
along the optical axis with `inf` where the true ray hits nothing (sky/background).
"""

from __future__ import annotations

from typing import Dict, Sequence

import numpy as np


def floater_mask(
    depth: np.ndarray, accumulation: np.ndarray, true_depth: np.ndarray, rel_tol: float = 0.1, min_alpha: float = 0.5
) -> np.ndarray:
    """Pixels with something rendered in front of the true surface: rendered depth more than
    `rel_tol` nearer than the truth, or (against the empty background) accumulated opacity above
    `min_alpha`. [H, W] each -> [H, W] bool."""
    surface = np.isfinite(true_depth)
    in_front = surface & (accumulation > min_alpha) & (depth < (1.0 - rel_tol) * np.where(surface, true_depth, 0.0))
    over_sky = ~surface & (accumulation > min_alpha)
    return in_front | over_sky


def floater_fraction(
    depth: np.ndarray, accumulation: np.ndarray, true_depth: np.ndarray, rel_tol: float = 0.1, min_alpha: float = 0.5
) -> float:
    """Share of pixels of `floater_mask`: geometry in the wrong place, seen or not (a sky painted
    by Gaussians in the right colour counts)."""
    return float(floater_mask(depth, accumulation, true_depth, rel_tol, min_alpha).mean())


def visible_floater_fraction(
    depth: np.ndarray,
    accumulation: np.ndarray,
    true_depth: np.ndarray,
    pred: np.ndarray,
    gt: np.ndarray,
    threshold: float = 0.1,
) -> float:
    """Share of pixels that are floaters (`floater_mask`) AND whose error exceeds `threshold`
    (normalised units): the floaters a person sees."""
    return float((floater_mask(depth, accumulation, true_depth) & (np.abs(pred - gt) > threshold)).mean())


def error_exceedance(pred: np.ndarray, gt: np.ndarray, threshold: float = 0.1) -> float:
    """Share of pixels whose absolute error exceeds `threshold` (normalised units)."""
    return float((np.abs(pred - gt) > threshold).mean())


def flicker(preds: Sequence[np.ndarray], gts: Sequence[np.ndarray]) -> Dict[str, float]:
    """Frame-to-frame change along a path, beyond the ground truth's own change:
    `mean_excess`: mean over t of | |m(pred_t) - m(pred_t-1)| - |m(gt_t) - m(gt_t-1)| | (m: image mean);
    `pixel_excess`: mean over t of max(0, mean|pred_t - pred_t-1| - mean|gt_t - gt_t-1|).
    A render equal to the truth has zero of both."""
    if len(preds) != len(gts) or len(preds) < 2:
        raise ValueError(
            f"flicker needs two or more renders and as many ground-truth frames (got {len(preds)} and {len(gts)})"
        )
    p_means = np.array([p.mean() for p in preds])
    g_means = np.array([g.mean() for g in gts])
    mean_excess = np.abs(np.abs(np.diff(p_means)) - np.abs(np.diff(g_means)))
    pixel_excess = [
        max(0.0, float(np.abs(p1 - p0).mean() - np.abs(g1 - g0).mean()))
        for p0, p1, g0, g1 in zip(preds[:-1], preds[1:], gts[:-1], gts[1:])
    ]
    return {"mean_excess": float(mean_excess.mean()), "pixel_excess": float(np.mean(pixel_excess))}


def background_error(pred: np.ndarray, gt: np.ndarray, true_depth: np.ndarray) -> float:
    """Mean absolute error on the background (true depth inf) alone; NaN if the view has none."""
    sky = ~np.isfinite(true_depth)
    return float(np.abs(pred - gt)[sky].mean()) if sky.any() else float("nan")
