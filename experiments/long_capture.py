"""Setup cost of long captures: time and peak memory of reading, triangulating and preprocessing
100, 300 and 1,000 frames of 640x512 uint16 (a generated capture).

    python -m experiments.long_capture --frames 100 300 1000 --output-dir docs/results/long_capture

Each size is set up in a fresh process (peak RSS is per process): the dataparser (every frame read
once, the radiometric range, seed triangulation from the known poses), then the pipeline
(preprocessing into the cache, the datamanager's frame cache, the model). The frame cache holds
the training frames as float32, so it grows with the frame count by design; the table shows the
peak minus it, which must not.
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import List

import tyro


@dataclass
class LongCaptureArgs:
    frames: List[int] = field(default_factory=lambda: [100, 300, 1000])
    """Capture lengths to set up (each a prefix-free capture of its own)."""
    output_dir: Path = Path("outputs/long_capture")
    """Where the generated captures, caches and results go."""
    width: int = 640
    height: int = 512


def _setup_one(scene: Path, cache: Path) -> dict:
    """Runs in the child process: the setup phases, timed."""
    import torch

    from thermal_wild_ns.data.dataparsers import ThermalDataParserConfig
    from thermal_wild_ns.method_configs import method_trainer

    torch.set_num_threads(1)
    parser_config = ThermalDataParserConfig(data=scene, seed_points="triangulate", cache_dir=cache / "seeds")
    start = time.perf_counter()
    parser = parser_config.setup()
    parser.get_dataparser_outputs("train")  # every frame read once, the range, the triangulated seeds
    parser_seconds = time.perf_counter() - start
    rss_after_parser = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024

    config = method_trainer("wild-thermal")
    config.pipeline.datamanager.dataparser = parser_config
    config.pipeline.datamanager.preprocessing_cache = cache / "preprocessing"
    start = time.perf_counter()
    pipeline = config.pipeline.setup(device="cpu", test_mode="val")
    pipeline_seconds = time.perf_counter() - start
    train = pipeline.datamanager.train_dataset
    frame_cache_mb = sum(4 * int(c.width) * int(c.height) for c in train.cameras) / 2**20
    return {
        "frames": len(parser.capture().frames),
        "train_frames": len(train),
        "parser_seconds": round(parser_seconds, 1),
        "pipeline_seconds": round(pipeline_seconds, 1),
        "peak_rss_mb_after_parser": round(rss_after_parser),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024),
        "frame_cache_mb": round(frame_cache_mb),
        "seed_points": int(pipeline.model.num_points),
    }


def main(args: LongCaptureArgs) -> List[dict]:
    from thermal_wild_ns.data.demo_scene import DemoSceneConfig, generate_demo_scene

    args.output_dir.mkdir(parents=True, exist_ok=True)
    rows = []
    for n in args.frames:
        scene = args.output_dir / f"capture_{n}"
        start = time.perf_counter()
        generate_demo_scene(
            scene, DemoSceneConfig(num_frames=n, width=args.width, height=args.height, focal=4.3 * args.width / 5)
        )
        print(f"{n} frames generated in {time.perf_counter() - start:.0f} s", flush=True)
        child = subprocess.run(
            [
                sys.executable,
                "-m",
                "experiments.long_capture",
                "--child",
                str(scene),
                str(args.output_dir / f"cache_{n}"),
            ],
            capture_output=True,
            text=True,
        )
        if child.returncode != 0:
            raise RuntimeError(f"setup of {n} frames failed:\n{child.stderr[-3000:]}")
        row = json.loads(child.stdout.strip().splitlines()[-1])
        row["peak_minus_frame_cache_mb"] = row["peak_rss_mb"] - row["frame_cache_mb"]
        rows.append(row)
        print(json.dumps(row), flush=True)
        (args.output_dir / "long_capture.json").write_text(json.dumps(rows, indent=1))
    header = (
        "| frames | train frames | dataparser s (read, range, triangulation) | pipeline s (preprocessing, "
        "frame cache, model) | peak RSS MB | frame cache MB | peak − cache MB | seed points |"
    )
    lines = [header, "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        lines.append(
            f"| {r['frames']} | {r['train_frames']} | {r['parser_seconds']} | {r['pipeline_seconds']} | "
            f"{r['peak_rss_mb']} | {r['frame_cache_mb']} | {r['peak_minus_frame_cache_mb']} | {r['seed_points']} |"
        )
    (args.output_dir / "long_capture.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return rows


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "--child":
        print(json.dumps(_setup_one(Path(sys.argv[2]), Path(sys.argv[3]))))
    else:
        main(tyro.cli(LongCaptureArgs))
