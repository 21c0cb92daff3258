"""What passes between the trainer's parts (the divergence guard, the automatic stop) and a model:
a declared interface, not attributes set from outside. `WildThermalModel` offers it; a model that
does not (stock splatfacto, benchmarked through the same trainer) trains without these parts'
model-side checks: no loss check per step, scores from step 0, no embeddings to interpolate."""

from __future__ import annotations

from typing import Dict, List, Optional, Protocol, Sequence, Tuple, runtime_checkable

from torch import Tensor

from thermal_wild_ns.decisions import Decision


@runtime_checkable
class GuardedModel(Protocol):
    settled_step: int
    """The first step past the schedule's start-up (full resolution, first opacity reset): the
    automatic stop scores no earlier."""

    def last_training_losses(self) -> Tuple[Optional[Dict[str, Tensor]], Optional[int]]:
        """The last training step's losses (its loss dict, on the device; None before the first step) and its
        training image (None where the step had no one image)."""
        ...

    def discard_step_statistics(self) -> None:
        """This step's gradients must not enter the densification statistics (the guard rolled the
        model back)."""
        ...

    def weigh_step_statistics(self, accepted: Tensor) -> None:
        """This step's gradients enter the densification statistics only where `accepted` ([] bool on
        the device, the divergence guard's verdict) is True."""
        ...

    def schedule_moves_loss(self, step: int) -> bool:
        """Whether the training schedule itself moves the loss at `step` (the guard rebaselines)."""
        ...

    def interpolate_embeddings(self, rows: Sequence[int]) -> None:
        """Set the embeddings of held-back training images to the state their neighbours give."""
        ...

    def decisions(self) -> List[Decision]:
        """The model's size and parts for this run, and why (`training/decisions.py` reports them)."""
        ...

    def gaussian_budget(self) -> Tuple[int, int]:
        """(Gaussians now, the most densification may grow them to), on this GPU."""
        ...

    def start_budget(self, count: int) -> None:
        """Densification grows the model to `count` Gaussians (on this GPU) at most, in place of the
        config's `max_gaussians` (the budget the automatic stop's held-back frames start from)."""
        ...

    def raise_budget(self, count: int) -> None:
        """Densification may grow the model to `count` Gaussians (on this GPU) from now on (the
        automatic stop's answer to held-back frames that plateau at the budget)."""
        ...

    def densifies(self, step: int) -> bool:
        """Whether densification still grows the model after `step` (a raised budget can still be used)."""
        ...

    def limit_growth(self, count: int) -> None:
        """Densification never grows the model past `count` Gaussians from now on (the trainer's answer
        to a step that ran out of GPU memory)."""
        ...

    def has_view_term(self) -> bool:
        """Whether the model was built with a view-dependent emission term."""
        ...

    def use_view_term(self, on: bool) -> None:
        """Whether the view term takes part in renders from now on (off: zeroed, no gradient)."""
        ...

    def try_view_term(self) -> None:
        """Put the view term on trial: in every other training render, in no render outside training."""
        ...

    def optimizer_states_of(self, states: dict) -> dict:
        """A checkpoint's optimizer states (optimizer name -> its state dict) for this model's parameters: a
        checkpoint saved with another layout of them (an older version's) as this model holds them."""
        ...
