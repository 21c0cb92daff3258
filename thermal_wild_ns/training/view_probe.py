"""Whether a capture needs view-dependent emission, decided by frames the model never trained on.

Switched on for every scene, the view term (`model/view_emission.py`) helps a drone survey and
costs a scene with vignetting (docs/results/view_term_gpu); on that survey it is also what keeps a
larger model from losing new views (docs/results/growth). A fair test compares the same model with
and without the term: zeroing a term the Gaussians grew up with damages the model rather than
removing the term (the rule tried first, docs/results/view_term_gpu). So the term is held at zero
until the automatic stop's first scored check; there it is fitted alone to the training frames
(every other parameter frozen: the model without it is exactly the one trained so far), and it
stays, fitted, where the held-back frames then score higher by `min_gain`; otherwise it stays zero
for the rest of the run. The held-back frames are views the term was not fitted on: a term that
explains the training views by something else than the view does not carry over to them (each
frame's own noise: tests/test_view_probe.py; vignetting, on a GPU: not yet measured). Its first runs
on generated scenes found no gain on the one made to need the term either (docs/results/view_probe_cpu):
off by default, a first design.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Callable

import torch
from torch import Tensor


@dataclass
class ViewTermVerdict:
    """What the probe measured at `step`, and what it decided."""

    step: int
    without: float
    """The held-back frames' score (PSNR, dB) of the model as trained, without the term."""
    with_term: float
    """Their score with the term fitted alone to the training frames."""
    kept: bool

    def as_record(self) -> dict:
        return asdict(self)

    def why(self) -> str:
        change = "raised" if self.with_term > self.without else "did not raise"
        return (
            f"fitted alone to the training frames at step {self.step:,}, the view term {change} the held-back "
            f"frames' PSNR ({self.without:.2f} -> {self.with_term:.2f} dB)"
        )


def probe_view_term(
    coefficients: Tensor,
    training_loss: Callable[[], Tensor],
    score: Callable[[], float],
    steps: int,
    lr: float,
    min_gain: float,
    step: int,
) -> ViewTermVerdict:
    """Fit the view term's `coefficients` [N, K] alone (Adam at `lr`, `steps` steps of
    `training_loss()`, one training frame's loss each; no other parameter gets a gradient or
    moves), and compare `score()` (held-back frames) before and after. The caller's model must render
    the term from now on; where it is not kept the caller zeroes it (`use_view_term(False)`)."""
    without = score()
    optimizer = torch.optim.Adam([coefficients], lr=lr, eps=1e-15)
    for _ in range(steps):
        (grad,) = torch.autograd.grad(training_loss(), [coefficients])  # the coefficients' gradient only
        coefficients.grad = grad
        optimizer.step()
        coefficients.grad = None
    with_term = score()
    return ViewTermVerdict(step, without, with_term, kept=with_term >= without + min_gain)
