"""How far each scene's content moves across the sensor (`thermal_wild_ns.data.content_motion`), the
measure the full method's camera-pattern rule reads (`camera_pattern_min_motion`), printed per scene.

python -m experiments.content_motion --scenes ../shared/data/flight2 ../shared/data/dunr demo stress:clean \
    survey:24 --cache-dir .data/cache
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from experiments.scenes import scene_dataparser
from thermal_wild_ns.data.content_motion import content_motion


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", required=True, help="bench scenes (survey:24: the synthetic survey)")
    parser.add_argument("--cache-dir", type=Path, default=Path(".data/cache"))
    args = parser.parse_args()
    print("| scene | training frames | seed points | content motion (frame sizes) |")
    print("| --- | --- | --- | --- |")
    with tempfile.TemporaryDirectory() as work:
        for scene in args.scenes:
            config = scene_dataparser(scene, Path(work), args.cache_dir.resolve())
            outputs = config.setup().get_dataparser_outputs("train")
            points = outputs.metadata.get("points3D_xyz")
            motion = content_motion(outputs.cameras, points)
            shown = "unknown" if motion is None else f"{motion:.3f}"
            print(
                f"| {scene} | {len(outputs.cameras)} | {0 if points is None else len(points)} | {shown} |", flush=True
            )


if __name__ == "__main__":
    main()
