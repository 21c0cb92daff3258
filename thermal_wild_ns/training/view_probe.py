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
vignetting scene's gain but did not remove it (the rule still keeps the term there), so the rule is off
by default. That scene loses with the term at the canonical state (`novel`, `aligned`), not at the
frames' own (`time`: docs/results/view_defaults_h200); scoring the held-back frames at the canonical
state too was tried, and at the first check it moved with their own states' score on every scene,
vignetting included (docs/results/view_verdict_cpu): it would decide nothing, so it is not part of the
rule. The reason: that scene is scored against its clean truth (no camera in it), and the term takes
part of the camera's vignetting into the scene; every recorded frame, held back or not, is explained as
well either way, so no score against recorded frames can see it (the same folder).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Callable


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

    def as_record(self) -> dict:
        return asdict(self)

    def why(self) -> str:
        change = "raised" if self.with_term > self.without else "did not raise"
        return (
            f"trained on every other step until step {self.step:,}, the view term {change} the held-back "
            f"frames' PSNR beyond what a radial fall-off explains ({self.without:.2f} -> {self.with_term:.2f} dB)"
        )


def judge_view_term(model, score: Callable[[], float], min_gain: float, step: int) -> ViewTermVerdict:
    """Score the held-back frames (`score()`) of `model`, whose view term is on trial
    (`try_view_term`: left out of renders outside training), without the term and with it; keep the
    term where it gains `min_gain`, else zero it (`use_view_term`)."""
    without = score()
    model.use_view_term(True)
    with_term = score()
    kept = with_term >= without + min_gain
    if not kept:
        model.use_view_term(False)
    return ViewTermVerdict(step, without, with_term, kept)


def verdict_check(checks: int) -> str:
    """The scored check where the view term's trial ends, in words."""
    return "the first scored check" if checks <= 1 else f"scored check {checks}"
