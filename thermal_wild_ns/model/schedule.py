"""Where splatfacto's training schedule itself moves the loss and the scores: its warm-up at lower
resolution (the downscale factor halves every `resolution_schedule` steps, from 2^num_downscales)
and gsplat's opacity resets. The trainer's guard and automatic stop ask the model (`settled_step`,
`schedule_moves_loss`), which answers from these."""

from __future__ import annotations


def settled_step(config, strategy) -> int:
    """The first step past the schedule's start-up: training at full resolution and past the first
    opacity reset. Before it, each of these moves every score by itself."""
    return max(config.num_downscales * config.resolution_schedule, strategy.reset_every)


def schedule_moves_loss(config, strategy, step: int) -> bool:
    """Whether the schedule moves the loss at `step`: the first step after an opacity reset, or the
    first at a finer training resolution."""
    reset_every, stop = strategy.reset_every, strategy.refine_stop_iter
    after_reset = 1 < step <= stop and (step - 1) % reset_every == 0  # gsplat resets at step % reset_every == 0
    r = config.resolution_schedule
    finer = step % r == 0 and 0 < step // r <= config.num_downscales  # splatfacto halves the downscale here
    return after_reset or finer
