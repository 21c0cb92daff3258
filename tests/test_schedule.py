"""The schedule in training frames (`training/schedule.py`): a trainer config of several cameras per step runs
its lengths in 1/B the steps, leaves the user's config (config.yml) as given, changes nothing for one camera a
step, and is the schedule `experiments.bench` measured as `FRAMES=1` before the trainer counted frames."""

import dataclasses

from thermal_wild_ns.method_configs import method_trainer
from thermal_wild_ns.training.schedule import FULL_SCHEDULE, in_steps, scale_schedule, steps_for

SCHEDULE_FIELDS = ("warmup_length", "refine_every", "stop_split_at", "stop_screen_size_at", "resolution_schedule")


def frames_config(count: int, frames: int = 15_000):
    config = method_trainer("wild-thermal")
    config.max_num_iterations = frames
    config.pipeline.cameras_per_step = count
    return config


def test_one_camera_per_step_keeps_the_config_itself():
    config = frames_config(1)
    assert in_steps(config) is config
    zero = frames_config(0)
    assert in_steps(zero) is zero  # the pipeline refuses 0, saying why; no division by it here


def test_two_cameras_per_step_halve_every_length_of_a_copy():
    config = frames_config(2)
    before = dataclasses.asdict(config.pipeline.model), config.auto_stop.check_every
    steps = in_steps(config)
    assert steps is not config and steps.max_num_iterations == 7_500
    for name in SCHEDULE_FIELDS:
        frames, stepped = getattr(config.pipeline.model, name), getattr(steps.pipeline.model, name)
        assert stepped == max(frames // 2, 1 if name == "resolution_schedule" else 10), name
        assert stepped < frames, name
    assert steps.auto_stop.check_every == config.auto_stop.check_every // 2
    # the user's config, what config.yml records and a resumed run converts again, is untouched
    assert (dataclasses.asdict(config.pipeline.model), config.auto_stop.check_every) == before
    assert config.max_num_iterations == 15_000
    # the optimizers keep the config's settings (as the runs that chose the rule)
    assert steps.optimizers == config.optimizers


def test_steps_for_trains_at_least_the_frames_asked():
    assert [steps_for(frames, 2) for frames in (1, 2, 3, 4, 15_000)] == [1, 1, 2, 2, 7_500]
    assert steps_for(10, 4) * 4 >= 10 and steps_for(10, 4) == 3


def test_the_frame_schedule_is_the_one_the_bench_measured_in_steps():
    """docs/results/cameras_per_step_h200's `FRAMES=1` arms gave the bench half the steps and half the
    schedule (`--steps 7500 --schedule 15000`, the stop's checks scaled to 15,000) with the schedule counted
    in steps; the trainer now derives the same from the frames (`--steps 15000 --schedule 30000`)."""
    measured = frames_config(2, frames=7_500)
    scale_schedule(measured.pipeline.model, 15_000 / FULL_SCHEDULE)
    measured.auto_stop.scale_to(15_000, FULL_SCHEDULE)
    now = in_steps(frames_config(2))
    assert now.max_num_iterations == measured.max_num_iterations
    assert dataclasses.asdict(now.pipeline.model) == dataclasses.asdict(measured.pipeline.model)
    assert dataclasses.asdict(now.auto_stop) == dataclasses.asdict(measured.auto_stop)


def test_a_short_schedule_scales_splatfactos_sh_interval_and_leaves_the_thermal_models_unused_one():
    from nerfstudio.configs.method_configs import method_configs

    splatfacto = method_configs["splatfacto"].pipeline.model
    splatfacto = type(splatfacto)(**{f.name: getattr(splatfacto, f.name) for f in dataclasses.fields(splatfacto)})
    scale_schedule(splatfacto, 0.5)
    assert splatfacto.sh_degree_interval == 500
    thermal = frames_config(1).pipeline.model
    default = thermal.sh_degree_interval
    scale_schedule(thermal, 0.5)
    assert thermal.sh_degree_interval == default  # config_checks would refuse it changed
