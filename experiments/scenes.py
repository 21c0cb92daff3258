"""The bench's scenes by name, apart from the bench: what reads a scene (its dataparser config) needs none of the
bench's imports (a timed setup phase imports this alone).

A scene is 'demo', 'stress:FAULT' or 'survey:FRAMES' (generated), or a dataset folder, 'LAYOUT:FOLDER' naming its
layout."""

from __future__ import annotations

from pathlib import Path
from typing import Tuple


def scene_dataparser(scene: str, output_dir: Path, cache_dir: Path):
    """The dataparser config of a bench scene: 'demo' and 'stress:FAULT' generated under
    `output_dir`, anything else a dataset folder (triangulation cache in `cache_dir`)."""
    from thermal_wild_ns.data.dataparsers import ThermalDataParserConfig, ThermalDemoDataParserConfig

    if scene == "demo":
        return ThermalDemoDataParserConfig(data=output_dir / "demo-scene")
    if scene.startswith("stress:"):
        return ThermalDemoDataParserConfig(data=output_dir / scene_name(scene), scene=scene.split(":", 1)[1])  # type: ignore[arg-type]
    if scene.startswith("survey:"):
        frames = scene.split(":", 1)[1]
        if not frames.isdigit():
            raise ValueError(f"bench scene {scene!r}: 'survey:FRAMES' takes a number of frames, e.g. survey:48")
        return ThermalDemoDataParserConfig(
            data=output_dir / scene_name(scene), scene="survey", survey_frames=int(frames)
        )
    layout, folder = layout_and_folder(scene)
    return ThermalDataParserConfig(data=Path(folder), layout=layout, cache_dir=cache_dir)  # type: ignore[arg-type]


def layout_and_folder(scene: str) -> Tuple[str, str]:
    """('auto', FOLDER), or (LAYOUT, FOLDER) for a scene given as 'LAYOUT:FOLDER'."""
    from thermal_wild_ns.data.layouts import LAYOUTS

    prefix, _, rest = scene.partition(":")
    return (prefix, rest) if rest and prefix in LAYOUTS else ("auto", scene)


def scene_name(scene: str) -> str:
    if scene.startswith(("stress:", "survey:")):
        return scene.replace(":", "-")
    layout, folder = layout_and_folder(scene)
    return Path(folder).name if layout == "auto" else f"{Path(folder).name}-{layout}"
