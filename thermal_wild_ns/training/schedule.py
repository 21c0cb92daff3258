"""The training schedule's lengths: laid out for 30,000 training frames, scaled to shorter runs, and counted
in frames where a step trains several (`--pipeline.cameras-per-step`).

A schedule is the steps at which the model changes how it trains: the resolution warm-up, densification
and its end, the view term's start, and the automatic stop's checks. With B cameras per step each step
trains B frames; counted in steps the schedule would show every Gaussian B times as many frames between
two densification rounds and run B times as long for the same steps. Counted in frames (the trainer's
config in steps is `in_steps(config)`), a run of B cameras per step sees the frames a run of one camera
sees at each point of its schedule, in fewer, larger steps (docs/results/cameras_per_step_h200 measured
both). The optimizers keep the config's settings (Adam's for one frame a step, a learning-rate schedule,
where one is set, in steps): the runs that chose this rule were made so.
"""

from __future__ import annotations

import copy
import math

FULL_SCHEDULE = 30_000
"""The length (training frames) the model configs' schedule fields (warm-up, refinement, opacity reset, split
stop) are given for, as splatfacto's; shorter runs scale them proportionally, the same for every method."""


def scale_schedule(model_config, factor: float) -> None:
    """Scale the model's schedule fields (given for `FULL_SCHEDULE` frames) by `factor` in place, e.g. 0.1
    for a 3,000-step run of the whole schedule; 1 or more changes nothing."""
    if factor >= 1:
        return
    model_config.warmup_length = max(int(model_config.warmup_length * factor), 10)
    model_config.refine_every = max(int(model_config.refine_every * factor), 10)
    model_config.stop_split_at = int(model_config.stop_split_at * factor)
    model_config.stop_screen_size_at = int(model_config.stop_screen_size_at * factor)
    model_config.resolution_schedule = max(int(model_config.resolution_schedule * factor), 1)
    # the plugin's model configs (a view term's start; no spherical harmonics, so their SH interval must stay
    # at its default: config_checks refuses it set), named by the field only they have; the training floor
    # does not import the model's
    if hasattr(model_config, "view_term_from_step"):
        model_config.view_term_from_step = int(model_config.view_term_from_step * factor)
    else:  # splatfacto's
        model_config.sh_degree_interval = max(int(model_config.sh_degree_interval * factor), 1)


def cameras_per_step(config) -> int:
    """Training frames each step of a trainer config trains (1 for pipelines without the option)."""
    return int(getattr(config.pipeline, "cameras_per_step", 1))


def steps_for(frames: int, count: int) -> int:
    """Steps of `count` frames each that train at least `frames` frames."""
    return max(math.ceil(frames / count), 1)


def in_steps(config):
    """The trainer config `config` (its schedule in training frames, as the user gives it) with its schedule
    in steps: unchanged (the same object) for one camera per step, else a copy whose run length, model
    schedule and automatic-stop checks are divided by the cameras per step. `config` itself is left as it
    is: it is what config.yml records and what a resumed run converts again."""
    count = cameras_per_step(config)
    if count <= 1:  # below 1: the pipeline refuses it, saying why
        return config
    steps = copy.deepcopy(config)
    steps.max_num_iterations = steps_for(config.max_num_iterations, count)
    scale_schedule(steps.pipeline.model, 1 / count)
    auto_stop = getattr(steps, "auto_stop", None)
    if auto_stop is not None:
        auto_stop.scale_to(FULL_SCHEDULE // count, FULL_SCHEDULE)
    return steps
