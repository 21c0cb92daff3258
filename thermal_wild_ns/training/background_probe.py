"""Whether a capture needs the background MLP, decided by frames the model never trained on.

The background MLP gives every direction a value that follows the frame's state: a cold sky behind a façade,
its level drifting with the camera. Where the Gaussians cover every pixel (a nadir survey, a wall filling the
frame) it shows nowhere, and costs its forward and backward at every step for nothing; on both real captures it
is worth nothing measurable (docs/results/parts_dunr_h200, docs/results/parts_flight2_h200), on generated scenes
with sky several dB (docs/results/background_mlp_cpu). So a scene decides: at the automatic stop's first scored
check the held-back frames, and trained views spread over the capture (two held-back frames may miss the sky
other frames show), are scored as trained, then with a constant in the MLP's place (its mean over the pixels
the Gaussians leave uncovered in those views, at their states), the Gaussians as they are. The MLP stays where
either set scores higher with it by `min_gain`; otherwise the constant replaces it for the rest of the run,
and with it the alpha regulariser goes, which compares each frame with what the background predicts
(`WildThermalModel.use_background_constant`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Callable, Sequence, Tuple

import numpy as np


@dataclass
class BackgroundVerdict:
    """What the held-back frames and the trained views scored at `step` with the background MLP and with a
    constant in its place (PSNR, dB, as every check's: a gain and offset fitted to each frame)."""

    step: int
    with_mlp: float
    """The held-back frames' score with the background MLP."""
    with_constant: float
    """Their score with the constant `value` in its place."""
    trained_with_mlp: float
    """The trained views' score (each at its own state) with the MLP."""
    trained_with_constant: float
    value: float
    kept: bool

    def as_record(self) -> dict:
        return asdict(self)

    def why(self) -> str:
        verdict = "stays" if self.kept else f"left for the constant {self.value:.4f}"
        return (
            f"at step {self.step:,} the held-back frames scored {self.with_mlp:.2f} dB with the background MLP and "
            f"{self.with_constant:.2f} dB with a constant in its place, trained views {self.trained_with_mlp:.2f} "
            f"and {self.trained_with_constant:.2f} dB: the MLP {verdict}"
        )


def uncovered_mean(backgrounds: Sequence[np.ndarray], coverages: Sequence[np.ndarray]) -> float:
    """The backgrounds' mean ([H, W] each) weighted by what the Gaussians leave uncovered (1 - coverage, [H, W]
    each): the background's level where it shows; its plain mean where it shows nowhere."""
    values = np.concatenate([np.ravel(b) for b in backgrounds]).astype(np.float64)
    weights = np.clip(1.0 - np.concatenate([np.ravel(c) for c in coverages]).astype(np.float64), 0.0, 1.0)
    if weights.sum() < 1e-6 * len(weights):
        return float(values.mean())
    return float((values * weights).sum() / weights.sum())


def judge_background(
    model, scores: Callable[[], Tuple[float, float]], mean_background: Callable[[], float], min_gain: float, step: int
) -> BackgroundVerdict:
    """Score the held-back frames and the trained views (`scores()`) of `model` with its background MLP, then
    with the constant `mean_background()` in its place (`use_background_constant`); keep the MLP where either
    gains `min_gain` with it, else leave the constant in its place."""
    (held, trained), value = scores(), mean_background()
    model.use_background_constant(value)
    held_constant, trained_constant = scores()
    kept = held - held_constant >= min_gain or trained - trained_constant >= min_gain
    if kept:
        model.use_background_constant(None)
    return BackgroundVerdict(step, held, held_constant, trained, trained_constant, value, kept)
