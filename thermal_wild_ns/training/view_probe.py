"""Whether a capture needs view-dependent emission, decided by frames the model never trained on.

Switched on for every scene, the view term (`model/view_emission.py`) helps a drone survey and costs a
scene with vignetting (docs/results/view_term_gpu); on that survey it is also what keeps a larger model
from losing new views (docs/results/growth). A fair test compares the same model with and without the
term. Zeroing a term the Gaussians grew up with damages the model rather than removing the term (the
rule tried first, docs/results/view_term_gpu); fitting the term late and alone to a model trained
without it did not find the gain even on a scene made to need it (the second,
docs/results/view_probe_cpu). So the term is on trial from the start: training renders alternate between
with it and without it (`WildThermalModel.try_view_term`), the Gaussians learn to render both ways, and
at the automatic stop's first scored check (`view_trial_checks`: a later one) the held-back frames are
scored both ways. The term stays where they score higher with it by `min_gain`; otherwise it is zeroed
for the rest of the run. The held-back frames are views the model never trained on: a term that explains
the training views by something else than the view (each frame's own noise) does not carry over to them.
A camera's vignetting does carry over (every frame has it), and the term can mimic it (it did on the
generated vignetting scene, where the held-back frames rose with it: docs/results/view_trial_gpu); so
both scores are taken after fitting each held-back frame a radial fall-off as well as its gain and
offset: the term is credited only with what the camera's own fall-off cannot explain. That shrank the
vignetting scene's gain but did not remove it. That scene loses with the term against its clean truth
(`novel`, `aligned`), not against its recorded frames (`time`: docs/results/view_defaults_h200): the term
takes part of the camera's vignetting into the scene, and the camera model keeps less of it
(docs/results/view_split_h200); every recorded frame, held back or not, is explained as well either way,
so no score against recorded frames can see it, at the canonical state or at a later check either
(docs/results/view_verdict_cpu). So the verdict also looks at the split itself: the term's contribution to
renders of training views (with it minus without it), and how much of it one radial camera response (a
gain and an offset fall-off about the image centre, the same in every view) explains (`radial_share`).
A term that the camera model could have taken is the camera's, not the scene's: above `max_share` it is
zeroed whatever the held-back frames score. Radiance that changes with the view is tied to surfaces
seen from different sides, not to a place on the sensor, so little of it is radial in every view
(docs/results/view_share_h200). Where the two look alike (a nadir survey over flat ground, whose
emissivity falls with the angle off the optical axis), the camera model takes it, and the scene keeps
each surface's temperature seen square-on.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Callable, List, Optional, Sequence

import numpy as np
import torch

from thermal_wild_ns.image_metrics import radial_fit
from thermal_wild_ns.pipeline.evaluation import centre_r2


@dataclass
class ViewTermVerdict:
    """What the held-back frames scored at `step`, and what was decided."""

    step: int
    without: float
    """The held-back frames' score (PSNR, dB, after a gain, offset and radial fall-off fit to each frame)
    of the model rendered without the term."""
    with_term: float
    """Their score of the same model rendered with it."""
    kept: bool
    radial_share: Optional[float] = None
    """The share of the term's contribution to training views that one radial camera response explains
    (`radial_share`; None in records written before the rule looked at it)."""
    max_share: Optional[float] = None
    """The largest share the term may have and stay (`AutoStopConfig.view_max_radial_share`)."""

    def as_record(self) -> dict:
        return asdict(self)

    def why(self) -> str:
        change = "raised" if self.with_term > self.without else "did not raise"
        scores = (
            f"trained on every other step until step {self.step:,}, the view term {change} the held-back "
            f"frames' PSNR beyond what a radial fall-off explains ({self.without:.2f} -> {self.with_term:.2f} dB)"
        )
        if self.radial_share is None:
            return scores
        radial = self.max_share is not None and self.radial_share > self.max_share
        verdict = "above the" if radial else "within the"
        camera = ": the camera model's part, not the scene's" if radial else ""
        share = (
            f"{self.radial_share:.0%} of what it adds to the training views is one radial fall-off about the "
            f"image centre ({verdict} {self.max_share:.0%} a view effect may have{camera})"
        )
        return f"{scores}; {share}"


def radial_share(without: Sequence[np.ndarray], with_term: Sequence[np.ndarray]) -> float:
    """How much of the view term's contribution one camera response explains: over renders of several
    views without the term and with it ([H, W] each, the same views in the same order), their differences
    fitted by one gain and one offset fall-off about the image centre (`image_metrics.radial_fit`, r^2 as
    `centre_r2`), the same in every view; the fitted part's energy / the differences' energy (0: nothing
    radial, 1: a camera's fall-off and nothing else; 0 where the term adds nothing)."""
    if len(without) != len(with_term) or not without:
        raise ValueError("radial_share needs the same views rendered both ways, at least one")
    differences, plains, r2s = [], [], []
    for plain, termed in zip(without, with_term):
        plain, termed = (np.asarray(x, dtype=np.float64) for x in (plain, termed))  # [H, W]
        if plain.shape != termed.shape:
            raise ValueError(f"radial_share: a view rendered at {plain.shape} and {termed.shape}")
        differences.append((termed - plain).reshape(-1, 1))  # [HW, 1]
        plains.append(plain.reshape(-1, 1))
        r2s.append(centre_r2(*plain.shape).reshape(-1, 1))
    difference, plain, r2 = (torch.from_numpy(np.concatenate(x)) for x in (differences, plains, r2s))  # [M, 1]
    energy = float(difference.square().sum())
    if energy == 0.0:
        return 0.0
    return float(radial_fit(difference, plain, r2).square().sum()) / energy


def judge_view_term(
    model,
    score: Callable[[], float],
    views: Callable[[], List[np.ndarray]],
    min_gain: float,
    max_share: float,
    step: int,
) -> ViewTermVerdict:
    """Score the held-back frames (`score()`) of `model`, whose view term is on trial
    (`try_view_term`: left out of renders outside training), and render training views (`views()`),
    without the term and with it; keep the term where it gains `min_gain` and no more than `max_share`
    of what it adds to the views is radial (`radial_share`), else zero it (`use_view_term`)."""
    without, plain = score(), views()
    model.use_view_term(True)
    with_term, termed = score(), views()
    share = radial_share(plain, termed)
    kept = with_term >= without + min_gain and share <= max_share
    if not kept:
        model.use_view_term(False)
    return ViewTermVerdict(step, without, with_term, kept, share, max_share)


def verdict_check(checks: int) -> str:
    """The scored check where the view term's trial ends, in words."""
    return "the first scored check" if checks <= 1 else f"scored check {checks}"
