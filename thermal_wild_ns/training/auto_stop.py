"""Training that stops when the scene stops improving.

A few training frames are held back from the gradient (evenly spread, never the first or last, so
their photometric state can be interpolated from their neighbours). Every `check_every` steps, once
the schedule's start-up is over (full resolution, past the first opacity reset), the model renders
them at that interpolated state and is scored against them as captured (PSNR, original space), after
a least-squares gain + offset fit per frame: the `time` render, scored as the `aligned` protocol
scores, on frames that are not the test views. The fit keeps a frame's global level, which nothing
before it predicts when the camera jumped (an AGC step, one bright frame), from swamping the
score's changes: they are the scene's (docs/results/issue16_defaults_gpu: a held-back bright frame
ended runs at their first checks without it).
When the score has not risen by `min_improvement` dB in `patience` checks in a row, training stops,
and the best-scoring model is kept. Quality on new views can fall after an early peak; the
held-back frames see that fall, which no measure of the frames being fitted can.

`PlateauRule` is the decision alone; `held_back_images` picks the frames; `held_back_score` scores.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import List, Optional, Sequence, Tuple

import numpy as np
import torch

from thermal_wild_ns.image_metrics import psnr
from thermal_wild_ns.pipeline.evaluation import fit_gain_offset
from thermal_wild_ns.pipeline.photometric_state import (
    PhotometricState,
    check_same_geometry,
    preprocessed_sequence,
    render,
)
from thermal_wild_ns.training.model_interface import GuardedModel


@dataclass
class AutoStopConfig:
    enabled: bool = True
    """Stop once the held-back frames' score stops improving (off: train every step asked for)."""
    held_back_frames: int = 2
    """Training frames held back from the gradient to score the model on."""
    check_every: int = 500
    """Steps between two scores of the held-back frames."""
    patience: int = 4
    """Checks in a row without an improvement after which training stops."""
    min_improvement: float = 0.05
    """Rise of the score (PSNR, dB) over the best so far that counts as an improvement."""
    keep_best: bool = True
    """At a stop, and at the end of a run, go back to the model of the best-scoring check when the
    last check scored lower."""

    def scale_to(self, schedule: int, full_schedule: int = 30_000) -> None:
        """Check as often, relative to the schedule, in a run whose schedule is `schedule` steps
        long instead of `full_schedule` (the one `check_every` is given for)."""
        self.check_every = max(self.check_every * min(schedule, full_schedule) // full_schedule, 10)


@dataclass
class PlateauRule:
    """Whether a run's scores have stopped improving. `update` takes one score per check."""

    patience: int
    min_improvement: float
    best: float = -math.inf
    best_step: Optional[int] = None
    since_best: int = 0
    history: List[Tuple[int, float]] = field(default_factory=list)

    def update(self, step: int, score: float) -> bool:
        """Record the score of `step`; True when it is a new best (worth keeping)."""
        self.history.append((step, float(score)))
        if math.isfinite(score) and score > self.best + self.min_improvement:
            self.best, self.best_step, self.since_best = float(score), step, 0
            return True
        self.since_best += 1
        return False

    @property
    def plateaued(self) -> bool:
        return self.since_best >= self.patience

    def reason(self, check_every: int) -> str:
        return (
            f"the held-back frames' PSNR has not risen by {self.min_improvement:g} dB in {self.patience} checks "
            f"({self.patience * check_every} steps); best {self.best:.2f} dB at step {self.best_step}"
        )


def held_back_images(num_images: int, count: int) -> Tuple[int, ...]:
    """`count` image indices spread evenly over the interior of `num_images` training images in
    capture order (never the first or the last: their state is interpolated between neighbours).
    Empty for fewer than 10 images per held-back frame: a small capture cannot spare them."""
    if count <= 0 or num_images < 10 * count:
        return ()
    return tuple(int(round((k + 1) * (num_images - 1) / (count + 1))) for k in range(count))


def held_back_score(pipeline, images: Sequence[int]) -> float:
    """Mean PSNR (original radiometric space, dataset-normalised, range 1: as the evaluation's) of
    the held-back images rendered at the photometric state interpolated from the trained frames
    around them, embedding and LUT alike, after a least-squares gain + offset fit to each frame."""

    datamanager, model = pipeline.datamanager, pipeline.model
    dataset, sequence = datamanager.train_dataset, preprocessed_sequence(pipeline)
    held_frames = [dataset.frame_index(image) for image in images]  # capture positions
    fill = isinstance(model, GuardedModel)
    if fill:
        model.interpolate_embeddings(images)
    values = []
    for image in images:
        t = dataset.frame_index(image)
        lut = None if sequence is None else sequence.lut_at(t, without=held_frames)
        embedding = model.frame_embed.weight[image].detach() if fill else None
        camera = dataset.cameras[image : image + 1].to(model.device)
        _, pred = render(pipeline, camera, PhotometricState(f"held-back:{t}", embedding, lut))  # [H, W]
        truth = datamanager.held_back_truth(image)  # [H, W]
        check_same_geometry(pred, truth, f"held-back frame {t}")
        finite = np.isfinite(truth)
        a, b = fit_gain_offset(pred[finite], truth[finite])
        values.append(float(psnr(torch.from_numpy(a * pred[finite] + b), torch.from_numpy(truth[finite]))))
    return float(np.mean(values))
