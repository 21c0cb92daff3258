"""`python -m experiments.step_ops`: the torch operations a training step dispatches, by part.

A step bound by the host costs about the same host time per operation it dispatches (the
Python call, torch's dispatcher, a kernel launch), so the count per step is a measure of its host work
that any machine gives alike, GPU or not. Trains `--warmup` steps of the full 30k schedule, then counts
every aten operation of `--steps` steps (torch's dispatch mode, below autograd: forward and backward)
in each part, parts nested in the step:

- `step`: the lean training step (render, loss, backward, the guard's verdict, the Adam update);
- `render` (the model's `get_outputs`), `losses` (`get_loss_dict`), `verdict` (the divergence guard's),
  `adam` (`fused_adam_step`), inside it;
- `statistics`: the densification statistics after the step (the model's `step_post_backward`).

On the CPU the rasterization is gsplat's torch implementation (hundreds of operations where the GPU
runs a few kernels) and no CUDA graph is recorded (the loss, the background and the camera model run
operation by operation): compare the parts that run alike on both, or one package against another
(`PYTHONPATH=.baseline:. python -m experiments.step_ops ...` counts the package in `.baseline`).
Writes `step_ops.json` and `step_ops.md` to `--output-dir`.
"""

from __future__ import annotations

import collections
import functools
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, Optional

import tyro
from torch.utils._python_dispatch import TorchDispatchMode

from experiments import train_with_hooks, write_report
from experiments.profile_step import full_schedule_trainer, measurement_header


@dataclass
class StepOpsArgs:
    scene: str = "demo"
    """'demo', 'stress:FAULT' or a dataset folder (as in python -m experiments.bench)."""
    method: str = "wild-thermal"
    warmup: int = 200
    """Steps trained before counting (past the first pass over the frames, whose views are built then)."""
    steps: int = 10
    """Steps counted."""
    output_dir: Path = Path("outputs/step_ops")
    """Where step_ops.json and step_ops.md go."""
    runs_dir: Path = Path("outputs/step_ops")
    """Where the counted run itself goes (its config and checkpoints, under `runs/`)."""
    cache_dir: Optional[Path] = None


class _Counter(TorchDispatchMode):
    """Counts the aten operations dispatched while it is on, by name."""

    def __init__(self, counts: collections.Counter):
        super().__init__()
        self.counts = counts

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        self.counts[str(func)] += 1
        return func(*args, **(kwargs or {}))


def _parts():
    """(part, owner, attribute) of every counted part."""
    from thermal_wild_ns.model.wild_thermal import WildThermalModel
    from thermal_wild_ns.training import lean_step
    from thermal_wild_ns.training.divergence import DivergenceGuard
    from thermal_wild_ns.training.trainer import GuardedTrainer

    return [
        ("step", GuardedTrainer, "_iteration"),
        ("render", WildThermalModel, "get_outputs"),
        ("losses", WildThermalModel, "get_loss_dict"),
        ("verdict", DivergenceGuard, "verdict"),
        ("adam", lean_step, "fused_adam_step"),
        ("statistics", WildThermalModel, "step_post_backward"),
    ]


def count(args: StepOpsArgs) -> Dict:
    counts: Dict[str, collections.Counter] = {part: collections.Counter() for part, _, _ in _parts()}
    counting = {"on": False}
    originals = []
    for part, owner, name in _parts():
        original = getattr(owner, name)
        originals.append((owner, name, original))

        def counted(*a, __part=part, __original=original, **k):
            if not counting["on"]:
                return __original(*a, **k)
            with _Counter(counts[__part]):
                return __original(*a, **k)

        setattr(owner, name, functools.wraps(original)(counted))  # wraps: nerfstudio reads callbacks' signatures
    try:
        trainer = full_schedule_trainer(args.scene, args.method, (), args.runs_dir, args.cache_dir)

        def after(step: int) -> None:
            counting["on"] = args.warmup <= step + 1 < args.warmup + args.steps

        train_with_hooks(trainer, args.warmup + args.steps, after)  # a step's statistics come before `after`
    finally:
        for owner, name, original in originals:
            setattr(owner, name, original)
    return {
        **measurement_header(args),
        "steps": args.steps,
        "ops_per_step": {part: sum(c.values()) / args.steps for part, c in counts.items()},
        "by_operation": {part: {op: n / args.steps for op, n in c.most_common()} for part, c in counts.items()},
    }


def markdown(result: Dict) -> str:
    lines = [
        f"# Torch operations per training step: {result['method']} on {result['scene']} ({result['device']}, "
        f"torch {result['torch']}), steps {result['warmup']}-{result['warmup'] + result['steps'] - 1}",
        "",
        "| part | operations per step |",
        "| --- | --- |",
        *[f"| {part} | {n:.1f} |" for part, n in result["ops_per_step"].items()],
        "",
    ]
    for part, ops in result["by_operation"].items():
        if part != "step":  # the step's list is the sum of its parts' and the rasterization's
            lines += [f"{part}: " + ", ".join(f"{op.removeprefix('aten.')} {n:g}" for op, n in ops.items()), ""]
    return "\n".join(lines)


def main() -> None:
    args = tyro.cli(StepOpsArgs)
    result = count(args)
    args.output_dir.mkdir(parents=True, exist_ok=True)
    (args.output_dir / "step_ops.json").write_text(json.dumps(result, indent=1))
    write_report(args.output_dir / "step_ops.md", markdown(result))


if __name__ == "__main__":
    main()
