"""`python -m experiments.camera_slices`: the host time of one frame's camera sliced from a camera path's batch,
nerfstudio's `cameras[i : i + 1]` against `_upstream.camera_unit_slice` (what `wild-thermal-render` hands the
model), on this machine's CPU: host work alone, the same on any GPU machine's host but for its speed.

    python -m experiments.camera_slices --output-dir docs/results/camera_slices_cpu [--cameras 300 --rounds 5]

Writes `camera_slices.json` (microseconds per slice, every round) and prints mean (min–max) per way.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch
from nerfstudio.cameras.cameras import Cameras

from experiments import mean_range
from thermal_wild_ns._upstream import camera_unit_slice


def camera_path(count: int) -> Cameras:
    """A path of `count` 640x512 cameras with capture times, as ns-render builds one from a camera path file."""
    return Cameras(
        camera_to_worlds=torch.eye(4)[:3].expand(count, 3, 4).clone(),
        fx=torch.full((count, 1), 500.0),
        fy=torch.full((count, 1), 500.0),
        cx=torch.full((count, 1), 320.0),
        cy=torch.full((count, 1), 256.0),
        width=torch.full((count, 1), 640),
        height=torch.full((count, 1), 512),
        times=torch.linspace(0, 1, count)[:, None],
    )


def microseconds_per_slice(cameras: Cameras, slice_one) -> float:
    """Mean host time of `slice_one(cameras, i)` over every camera of the batch."""
    start = time.perf_counter()
    for i in range(len(cameras)):
        slice_one(cameras, i)
    return 1e6 * (time.perf_counter() - start) / len(cameras)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--output-dir", type=Path, required=True)
    parser.add_argument("--cameras", type=int, default=300)
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args()
    cameras = camera_path(args.cameras)
    ways = {"nerfstudio": lambda c, i: c[i : i + 1], "camera_unit_slice": camera_unit_slice}
    rounds = {name: [] for name in ways}
    for _ in range(args.rounds):  # the ways alternated, so a drift of the machine's pace meets both
        for name, way in ways.items():
            rounds[name].append(round(microseconds_per_slice(cameras, way), 2))
    args.output_dir.mkdir(parents=True, exist_ok=True)
    result = dict(cameras=args.cameras, rounds=args.rounds, torch_threads=torch.get_num_threads(), us=rounds)
    (args.output_dir / "camera_slices.json").write_text(json.dumps(result, indent=1))
    for name, values in rounds.items():
        print(f"{name}: {mean_range(values)} us per slice")


if __name__ == "__main__":
    main()
