"""The first training steps of the demo config: per step the training image, the total loss and
the float64 sums of the render and of its accumulated opacity; then the background MLP's last-layer
weight sum. Run it twice with the same code to see whether CPU training is bitwise repeatable (a
refactor can only be held to identical numbers where it is).

    PYTHONHASHSEED=0 OMP_NUM_THREADS=1 python -m experiments.step_trace SCENE_DIR OUT_DIR --steps 3
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import torch

from thermal_wild_ns.demo import demo_trainer_config
from thermal_wild_ns.training.trainer import seeded_trainer


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scene", type=Path, help="the demo scene folder (written by wild-thermal-demo)")
    parser.add_argument("out", type=Path)
    parser.add_argument("--steps", type=int, default=3)
    args = parser.parse_args()
    shutil.rmtree(args.out, ignore_errors=True)
    config = demo_trainer_config(args.out, steps=args.steps, max_gaussians=3000)
    config.pipeline.datamanager.dataparser.data = args.scene
    trainer = seeded_trainer(config)
    model, steps = trainer.pipeline.model, []
    losses = model.get_loss_dict

    def recorded(outputs, batch, metrics_dict=None):
        values = losses(outputs, batch, metrics_dict)
        sums = [float(outputs[k].double().sum()) for k in ("thermal", "accumulation")]
        steps.append((int(batch["image_idx"]), float(sum(values.values())), *sums))
        return values

    model.get_loss_dict = recorded
    trainer.train()
    print("torch threads", torch.get_num_threads())
    print("step, image, loss, render sum, accumulation sum")
    for step, row in enumerate(steps):
        print(step, *row)
    print("background MLP last-layer weight sum", float(model.background_mlp.net.layers()[-1][0].double().sum()))


if __name__ == "__main__":
    main()
