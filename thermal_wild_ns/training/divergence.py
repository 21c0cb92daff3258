"""The divergence guard, apart from any trainer: `verdict` decides on the device whether a step's
update may happen (its loss or gradients are not finite, or its loss spikes far above the recent
median), `settle` reads the step's values back later and says why a step was skipped, `check_model`
now and then whether the model itself is broken (NaN/inf parameters, every Gaussian gone or
transparent), `record` counts skips and stops after too many in a row (`TrainingDiverged`).

The verdict needs no host sync: the spike threshold comes from the losses already read back (every
step before this one), the comparisons run on the device, and the optimizer takes the verdict as
fused Adam's `found_inf` (`_upstream.fused_adam_step`). The step's values travel to host memory
behind the queued work and are read at the next step's verdict, a step after they were queued: a
skip is counted, said and can stop the run one step later than it happened."""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass
from typing import Callable, Deque, Dict, List, Optional, Tuple

import torch
from nerfstudio.models.splatfacto import SplatfactoModel
from nerfstudio.utils.rich_utils import CONSOLE


class TrainingDiverged(RuntimeError):
    """Training cannot go on: the model is broken (NaN/inf, collapsed) or every step fails."""


@dataclass
class DivergenceGuardConfig:
    enabled: bool = True
    """Skip bad steps and roll a broken model back (off: train without these checks)."""
    loss_spike_factor: float = 20.0
    """Skip a step whose loss exceeds this many times the median loss of the last accepted steps."""
    spike_window: int = 100
    """Accepted steps the median is taken over (no spike test before the window is full)."""
    persistent_frame_factor: float = 2.0
    """A spike is sudden: a frame whose loss on its previous visit was already within this factor
    of the spike is a hard frame (a flat-field jump, an outlier frame), and its step is accepted.
    Skipping it at every visit would silently drop that frame from training."""
    max_consecutive_skips: int = 50
    """Stop when this many steps in a row had to be skipped."""
    check_every: int = 100
    """Steps between checks of the model itself (finite parameters, Gaussians left, opacity)."""
    max_rollbacks: int = 3
    """When the model breaks (NaN/inf parameters, collapse, every step skipped), training goes back
    to the last healthy state (kept at every model check) up to this many times, then stops."""
    min_mean_opacity: float = 1e-3
    """Stop when the mean Gaussian opacity falls below this (everything turned transparent)."""


@dataclass
class PendingVerdict:
    """A step's verdict on its way to the host: `values` [2 + G] (accepted 1/0, the loss, each gradient's
    norm), readable once `ready` (None: already on the host)."""

    step: Optional[int]
    frame: Optional[int]
    values: torch.Tensor
    ready: Optional[torch.cuda.Event]
    gradient_groups: List[str]  # the parameter group of each gradient norm
    has_loss: bool
    threshold: float  # the loss above which the step was a spike
    median: Optional[float]  # the recent median it came from


class DivergenceGuard:
    """The checks, independent of the trainer (`verdict` before the optimizer step, `settle` after,
    `check_model` now and then)."""

    def __init__(self, config: DivergenceGuardConfig):
        self.config = config
        self.recent: Deque[float] = collections.deque(maxlen=config.spike_window)
        self.frame_loss: Dict[int, float] = {}  # each training frame's loss at its last visit
        self.skipped = 0
        self.consecutive = 0
        self.rollbacks = 0
        self.pending: Optional[PendingVerdict] = None  # the last verdict, not yet read back
        self._host: Optional[torch.Tensor] = None  # pinned [2 + G]: where the verdicts reach the host
        self._ready: Optional[torch.cuda.Event] = None

    def spike_threshold(self, frame: Optional[int]) -> Tuple[float, Optional[float]]:
        """(the loss above which this step is a spike, the recent median it comes from): inf before the
        window is full; a frame whose previous loss was already within `persistent_frame_factor` of
        the loss is a hard frame, not a spike, so the threshold is at least that far above it."""
        if len(self.recent) < self.recent.maxlen:
            return math.inf, None
        median = sorted(self.recent)[len(self.recent) // 2]
        threshold = self.config.loss_spike_factor * median
        previous = self.frame_loss.get(frame) if frame is not None else None
        if previous is not None:
            threshold = max(threshold, self.config.persistent_frame_factor * previous)
        return threshold, median

    def verdict(
        self,
        loss: Optional[torch.Tensor],
        parameters: dict,
        groups: List[str],
        frame: Optional[int] = None,
        step: Optional[int] = None,
        agree: Callable[[torch.Tensor], torch.Tensor] = lambda accepted: accepted,
    ) -> Optional[torch.Tensor]:
        """Whether this step's update may happen, [] bool on the loss's device, decided there without
        waiting for it (None: no loss and no gradients to check). The previous step is settled first:
        its loss joins the history this step's threshold reads. `frame`: the step's training image
        (a spike tells from a hard frame by it); `step`: `settle` records the skip under it;
        `agree(accepted)`: one verdict for all GPUs of a run (default: this one's)."""
        self.settle()
        grads = [(g, p.grad) for g in groups for p in parameters[g] if p.grad is not None]
        if loss is None and not grads:
            return None
        device = loss.device if loss is not None else grads[0][1].device
        threshold, median = self.spike_threshold(frame) if loss is not None else (math.inf, None)
        # few operations, none waited for: each one is host time in every training step
        if loss is not None:
            value = loss.detach().float()  # []
        else:
            value = torch.full((), math.nan, device=device)
        # [1 + G] the loss, each gradient's norm (one fused kernel for every gradient's norm)
        norms = torch._foreach_norm([grad for _, grad in grads]) if grads else []
        values = torch.stack([value, *norms]).float()
        checked = values if loss is not None else values[1:]  # what must be finite
        # their sum is finite where each is finite and they do not overflow, which NaN/inf anywhere breaks (x * 0
        # is 0 for a finite x, NaN for inf and NaN: torch.isfinite in two kernels, torch's own is four)
        accepted = checked.sum() * 0 == 0
        if loss is not None and threshold < math.inf:  # below an infinite threshold every finite loss lies
            accepted = accepted & (value <= threshold)
        accepted = agree(accepted)
        values = torch.cat([accepted.reshape(1), values])  # [2 + G] float: cat promotes the verdict
        ready = None
        if values.is_cuda:  # behind the queued work, into pinned memory: no wait here
            values, ready = self._to_host(values)
        self.pending = PendingVerdict(
            step, frame, values, ready, [g for g, _ in grads], loss is not None, threshold, median
        )
        return accepted

    def _to_host(self, values: torch.Tensor) -> Tuple[torch.Tensor, torch.cuda.Event]:
        """`values` on their way to host memory behind the queued work, and the event that says they are
        there. The pinned buffer and the event are the guard's own, reused from step to step: the last
        step's values were read back (`settle`) before this copy is queued."""
        if self._host is None or self._host.shape != values.shape:
            self._host = torch.empty(values.shape, dtype=values.dtype, pin_memory=True)
            self._ready = torch.cuda.Event()
        self._host.copy_(values, non_blocking=True)
        self._ready.record()
        return self._host, self._ready

    def settle(self) -> Optional[str]:
        """Read the last verdict back: why its step was skipped (None: it was not, or nothing is
        pending). Its loss joins the frame's and, accepted, the recent losses; with a step, the
        skip is recorded (`record`, which stops the run after too many in a row)."""
        pending, self.pending = self.pending, None
        if pending is None:
            return None
        if pending.ready is not None:
            pending.ready.synchronize()  # queued a step ago: at most the rest of that step is waited for
        accepted, value, *norms = pending.values.tolist()
        reason = self._reason(pending, bool(accepted), value, norms)
        if pending.step is not None:
            self.record(pending.step, reason)
        return reason

    def _reason(self, pending: PendingVerdict, accepted: bool, value: float, norms: List[float]):
        if pending.has_loss:
            if not math.isfinite(value):
                return f"non-finite loss ({value})"
            if pending.frame is not None:
                self.frame_loss[pending.frame] = value
            if accepted:
                self.recent.append(value)
            elif value > pending.threshold:
                return (
                    f"loss spike ({value:.4g} > {self.config.loss_spike_factor:g} x recent median {pending.median:.4g})"
                )
        if accepted:
            return None
        # a norm is non-finite where a gradient is, or where its squares overflow float32 (a GPU's norm does not
        # rescale: any element past about 1.8e19 gives inf); either way the gradients cannot be stepped with
        bad = sorted({g for g, n in zip(pending.gradient_groups, norms) if not math.isfinite(n)})
        if bad:
            return f"non-finite gradient norm in {', '.join(bad)}"
        checked = ([value] if pending.has_loss else []) + norms
        if not math.isfinite(float(torch.tensor(checked, dtype=torch.float32).sum())):  # as the device summed them
            return "the loss and gradient norms overflow float32 (each finite)"
        return "skipped on another GPU"

    def rebaseline(self) -> None:
        """Forget the recent losses: the schedule itself just moved the loss (an opacity reset, a
        finer training resolution). Without this, every frame's first visit after such a step
        looks like a spike and is skipped, right when the model must recover. The last verdict is
        read back first: its loss belongs to the history being forgotten."""
        self.settle()
        self.recent.clear()
        self.frame_loss.clear()

    def record(self, step: int, reason: Optional[str]) -> None:
        if reason is None:
            self.consecutive = 0
            return
        self.skipped += 1
        self.consecutive += 1
        CONSOLE.log(f"[yellow]step {step}: {reason}; step skipped ({self.skipped} so far)")
        if self.consecutive >= self.config.max_consecutive_skips:
            raise TrainingDiverged(
                f"step {step}: {self.consecutive} steps in a row were skipped (last: {reason}). Training has diverged; "
                "lower the learning rates or check the data (diagnose it with wild-thermal-diagnose)."
            )

    def check_model(self, model, step: int) -> None:
        named = [(name, param) for name, param in model.named_parameters() if param.numel() > 0]
        finite = torch.stack([torch.isfinite(param).all() for _, param in named]).tolist()  # one host sync
        for (name, _), ok in zip(named, finite):
            if not ok:
                raise TrainingDiverged(f"step {step}: parameter '{name}' holds NaN/inf values; training has diverged")
        if isinstance(model, SplatfactoModel):  # Gaussians to count
            if model.num_points == 0:
                raise TrainingDiverged(f"step {step}: every Gaussian was pruned; the model collapsed to an empty scene")
            opacity = float(torch.sigmoid(model.opacities.detach()).mean())
            if opacity < self.config.min_mean_opacity:
                raise TrainingDiverged(
                    f"step {step}: mean Gaussian opacity {opacity:.2e} < {self.config.min_mean_opacity:g}; the "
                    f"scene has turned "
                    "transparent (the background explains every pixel)"
                )
