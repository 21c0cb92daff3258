"""The lean training step: what nerfstudio's `Trainer.train_iteration` does (gradients cleared, the
loss dict summed in the same order, backward, every optimizer stepped, the schedulers stepped),
without the per-step Python around it (gradient-accumulation and grad-scaler bookkeeping, one
wrapped `step()` per optimizer), for the configs where it is the same step."""

from __future__ import annotations

import functools
from typing import Callable, Optional

import torch

from thermal_wild_ns._upstream import fused_adam_ready, fused_adam_step


def lean_step_unsupported(config, optimizers) -> Optional[str]:
    """Why `lean_iteration` cannot stand in for nerfstudio's step with this trainer config and its
    `Optimizers`, or None: it needs fused Adam without gradient clipping, no mixed precision, no
    gradient accumulation or logging."""
    if config.mixed_precision:
        return "mixed precision"
    if any(n != 1 for n in config.gradient_accumulation_steps.values()) or config.log_gradients:
        return "gradient accumulation or gradient logging"
    for name, optimizer in optimizers.optimizers.items():
        if not fused_adam_ready(optimizer) or optimizers.config[name]["optimizer"].max_norm is not None:
            return f"optimizer '{name}' is not a fused Adam without gradient clipping"
    return None


def total_loss(loss_dict) -> torch.Tensor:
    """A step's loss dict summed in its order, as nerfstudio's `Trainer.train_iteration` sums it."""
    return functools.reduce(torch.add, loss_dict.values())


def lean_iteration(
    pipeline,
    optimizers,
    step: int,
    accept: Optional[Callable[[list, torch.Tensor], Optional[torch.Tensor]]],
    after_backward: Optional[Callable[[], None]] = None,
    metrics: bool = True,
):
    """One training step; `after_backward()`, if given, runs right after backward (the gradient sum
    across GPUs); `accept(param_groups, loss)`, if given, decides then on the step's total `loss` whether
    the optimizers step (the divergence guard's verdict: [] bool on the device, None for yes), which they
    read on the device. `metrics` off: the pipeline (a `ThermalPipeline`) leaves the step's metrics out.
    Returns (loss, loss dict, metrics dict) as nerfstudio's."""
    adams = list(optimizers.optimizers.values())
    for optimizer in adams:
        for group in optimizer.param_groups:
            for param in group["params"]:
                param.grad = None
    if metrics:
        _, loss_dict, metrics_dict = pipeline.get_train_loss_dict(step=step)
    else:
        _, loss_dict, metrics_dict = pipeline.get_train_loss_dict(step=step, metrics=False)
    loss = total_loss(loss_dict)
    loss.backward()
    if after_backward is not None:
        after_backward()
    fused_adam_step(adams, None if accept is None else accept(list(optimizers.parameters), loss))
    optimizers.scheduler_step_all(step)
    return loss, loss_dict, metrics_dict
