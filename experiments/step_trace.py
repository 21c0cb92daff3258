"""The first training steps of the demo config, as (training image, total loss, render sum) per
step, and a checksum of the Gaussians after them: run twice with the same code to see whether CPU
training is bitwise repeatable (a refactor can only be held to identical numbers where it is).

    PYTHONHASHSEED=0 OMP_NUM_THREADS=1 python -m experiments.step_trace SCENE_DIR OUT_DIR --steps 3
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

import torch


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scene", type=Path, help="the demo scene folder (written by wild-thermal-demo)")
    parser.add_argument("out", type=Path)
    parser.add_argument("--steps", type=int, default=3)
    args = parser.parse_args()
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from demo_trainers import demo_trainer  # the tests' set-up of the demo trainer

    shutil.rmtree(args.out, ignore_errors=True)
    trainer = demo_trainer(args.out, args.scene, args.steps, "guard")
    model, steps = trainer.pipeline.model, []
    losses = model.get_loss_dict

    def recorded(outputs, batch, metrics_dict=None):
        values = losses(outputs, batch, metrics_dict)
        steps.append((int(batch["image_idx"]), float(sum(values.values())), float(outputs["thermal"].sum())))
        return values

    model.get_loss_dict = recorded
    trainer.train()
    print("torch threads", torch.get_num_threads())
    for step, row in enumerate(steps):
        print(step, row)
    print("gaussians", model.num_points, "sum of means", float(model.means.sum()))


if __name__ == "__main__":
    main()
