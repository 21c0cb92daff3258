"""`python -m experiments.schedule_profile`: where a whole default run's seconds go, step by step and
event by event (ms/step over the default schedule, not one warm step).

`experiments.profile_step` times a few hundred steps after a warm-up; a run of the default schedule
also pays the automatic stop's checks (held-back renders, the best model copied and written), the
divergence guard's model checks and healthy copies, nerfstudio's checkpoints and log writes, and the
end of the run. This trains the method's default config on a scene, as the bench does (one seed, its
own schedule, the automatic stop on), and times each of those events (the rare ones with the GPU
synchronised before and after), so the time left over is the training steps' own. Also the steps' ms in windows of
`--window` steps (their cost as the model grows). Writes `schedule.json` and `schedule.md` to
`--output-dir`.

    python -m experiments.schedule_profile --scene .data/dunr --cache-dir .data/cache --output-dir OUT
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Dict, List, Optional, Tuple

import tyro

from experiments import device_name, synchronize, train_with_hooks, write_report
from experiments.bench import BenchArgs, setup_trainer, trainer_config
from experiments.scenes import scene_name
from thermal_wild_ns.training.schedule import FULL_SCHEDULE


@dataclass
class ScheduleArgs:
    scene: str = "demo"
    """'demo', 'stress:FAULT' or a dataset folder (as in python -m experiments.bench)."""
    method: str = "wild-thermal"
    steps: int = FULL_SCHEDULE
    """Steps asked (the automatic stop may end the run sooner)."""
    seed: int = 0
    window: int = 500
    """Steps per row of the step-cost table."""
    set: Tuple[str, ...] = ()
    """Settings of the method's config, as the bench's `--set`."""
    output_dir: Path = Path("outputs/schedule_profile")
    cache_dir: Optional[Path] = None


class EventClock:
    """Seconds and calls per named event. A rare event is timed with the GPU synchronised at both
    ends, so its time is its own and not the queued steps' before it; an event of every step is
    timed on the host only (a sync per step would stall the step it measures)."""

    def __init__(self) -> None:
        self.seconds: Dict[str, float] = {}
        self.calls: Dict[str, int] = {}

    def timed(self, name: str, function: Callable, every_step: bool = False) -> Callable:
        wait = (lambda: None) if every_step else synchronize

        def wrapper(*args, **kwargs):
            wait()
            start = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                wait()
                self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - start
                self.calls[name] = self.calls.get(name, 0) + 1

        return wrapper

    def total(self) -> float:
        return sum(self.seconds.values())


def instrument(trainer, clock: EventClock) -> Callable[[], None]:
    """Wrap the run's events on this trainer (and nerfstudio's log writes) with `clock`; returns what
    puts the two module functions it wraps back."""
    import nerfstudio.utils.writer as writer

    import thermal_wild_ns.training.trainer as trainer_module

    originals = (trainer_module.snapshot, writer.write_out_storage)

    if trainer.auto_stop is not None:
        stop = trainer.auto_stop
        stop.check = clock.timed("automatic stop: checks (held-back renders, best model kept)", stop.check)
        stop.finish = clock.timed("automatic stop: end of run", stop.finish)
    trainer._check_model = clock.timed("divergence guard: model checks", trainer._check_model)
    trainer_module.snapshot = clock.timed("divergence guard: healthy copies", trainer_module.snapshot)
    trainer.save_checkpoint = clock.timed("checkpoints written", trainer.save_checkpoint)
    trainer.eval_iteration = clock.timed("nerfstudio's evaluation", trainer.eval_iteration, every_step=True)
    writer.write_out_storage = clock.timed("log writes", writer.write_out_storage, every_step=True)

    def undo() -> None:
        trainer_module.snapshot, writer.write_out_storage = originals

    return undo


def main(args: ScheduleArgs) -> Dict:
    bench = BenchArgs(
        scenes=(args.scene,),
        steps=args.steps,
        schedule=FULL_SCHEDULE,
        seed=args.seed,
        set=args.set,
        output_dir=args.output_dir,
        cache_dir=args.cache_dir,
        fps_frames=0,
    )
    config = trainer_config(args.method, args.scene, bench, args.output_dir / "runs", args.seed)
    config.save_config()
    trainer = setup_trainer(config)
    clock = EventClock()
    undo = instrument(trainer, clock)
    windows: List[Dict] = []
    marks = {"wall": 0.0, "events": 0.0, "step": -1}

    def start() -> None:
        synchronize()
        marks["wall"] = time.perf_counter()
        marks["begin"] = marks["wall"]

    def after_step(step: int) -> None:
        if (step + 1) % args.window:
            return
        synchronize()
        now, events = time.perf_counter(), clock.total()
        steps = step - marks["step"]
        spent = now - marks["wall"] - (events - marks["events"])
        windows.append(
            {
                "last_step": step,
                "ms_per_step": round(1000 * spent / steps, 3),
                "gaussians": int(trainer.pipeline.model.num_points),
            }
        )
        marks.update(wall=now, events=events, step=step)

    try:
        train_with_hooks(trainer, args.steps, after_step, start)
    finally:
        undo()
    synchronize()
    wall = time.perf_counter() - marks["begin"]
    steps = trainer.step + 1
    events = clock.total()
    result = {
        "device": device_name(),
        "scene": scene_name(args.scene),
        "method": args.method,
        "settings": list(args.set),
        "seed": args.seed,
        "steps": steps,
        "gaussians": int(trainer.pipeline.model.num_points),
        "wall_seconds": round(wall, 3),
        "ms_per_step_all": round(1000 * wall / steps, 3),
        "ms_per_step_steps_only": round(1000 * (wall - events) / steps, 3),
        "events": {
            name: {
                "seconds": round(seconds, 3),
                "calls": clock.calls[name],
                "ms_per_step": round(1000 * seconds / steps, 3),
            }
            for name, seconds in sorted(clock.seconds.items(), key=lambda kv: -kv[1])
        },
        "windows": windows,
    }
    args.output_dir.mkdir(parents=True, exist_ok=True)
    (args.output_dir / "schedule.json").write_text(json.dumps(result, indent=1))
    write_report(args.output_dir / "schedule.md", markdown(result))
    return result


def markdown(result: Dict) -> str:
    settings = f", {' '.join(result['settings'])}" if result["settings"] else ""
    lines = [
        f"# {result['method']}{settings} on {result['scene']}, its default schedule ({result['device']}, "
        f"seed {result['seed']})",
        "",
        f"- {result['steps']:,} steps, {result['gaussians']:,} Gaussians at the end, {result['wall_seconds']:.1f} s: "
        f"**{result['ms_per_step_all']:.2f} ms/step** over the run, {result['ms_per_step_steps_only']:.2f} of them "
        "the training steps' own",
        "",
        "| event | calls | seconds | ms per training step |",
        "| --- | --- | --- | --- |",
    ]
    for name, event in result["events"].items():
        lines.append(f"| {name} | {event['calls']} | {event['seconds']:.2f} | {event['ms_per_step']:.3f} |")
    lines += ["", "| steps to | ms/step (steps only) | Gaussians |", "| --- | --- | --- |"]
    for window in result["windows"]:
        lines.append(f"| {window['last_step'] + 1:,} | {window['ms_per_step']:.2f} | {window['gaussians']:,} |")
    return "\n".join(lines) + "\n"


def entrypoint() -> None:
    main(tyro.cli(ScheduleArgs))


if __name__ == "__main__":
    entrypoint()
