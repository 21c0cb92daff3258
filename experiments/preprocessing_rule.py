"""What the full method's preprocessing rule measures on each scene, and what it decides.

For each scene, the training frames through the preprocessing stage (the full method's variant and
cache, exactly as `ns-train wild-thermal` sets up): the spread of the frames' mean levels raw and
preprocessed, the spread of their contrast (`frame_contrast_spread`), and the decision
(`PreprocessedSequence.decision`). Writes a Markdown table:

    python -m experiments.preprocessing_rule --scenes demo stress:clean stress:drift stress:ffc \
        stress:outlier stress:vignetting .data/dunr --cache-dir .data/cache \
        --output docs/results/preprocessing_rule/rule.md
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import List, Optional, Tuple

import tyro

from experiments import write_report
from experiments.scenes import scene_dataparser, scene_name
from thermal_wild_ns.preprocessing.stage import CONTRAST_SPREAD


@dataclass
class RuleArgs:
    scenes: Tuple[str, ...] = ("demo",)
    """'demo', 'stress:FAULT' or dataset folders (as in python -m experiments.bench)."""
    output: Path = Path("outputs/preprocessing_rule.md")
    work_dir: Path = Path("outputs/preprocessing_rule")
    """Where generated scenes go."""
    cache_dir: Optional[Path] = None
    """Triangulation / preprocessing cache (default: `work_dir/cache`), as in python -m experiments.bench.
    Preprocessed frames of a 640x512 capture take tens of MB there."""


def measure(scene: str, work_dir: Path, cache_dir: Path) -> dict:
    from thermal_wild_ns.pipeline.datamanager import ThermalDatamanagerConfig
    from thermal_wild_ns.preprocessing.photometric import PhotometricConfig

    datamanager = ThermalDatamanagerConfig(
        dataparser=scene_dataparser(scene, work_dir, cache_dir),
        preprocessing=PhotometricConfig(),
        preprocessing_cache=cache_dir,
    ).setup(device="cpu")
    decision = datamanager.preprocessed.decision()  # skip_when_stable off: always the processed sequence
    return {"scene": scene_name(scene), **decision._asdict()}


def table(rows: List[dict]) -> str:
    lines = [
        f"The full method's preprocessing rule (`preprocessing_pays`: preprocessing must steady the frames' "
        f"mean levels and their contrast spread must reach {CONTRAST_SPREAD}):",
        "",
        "| scene | frame-mean spread raw -> preprocessed | contrast spread | preprocessed? |",
        "| --- | --- | --- | --- |",
    ]
    lines += [
        f"| {r['scene']} | {r['raw_spread']:.4f} -> {r['processed_spread']:.4f} | {r['contrast_spread']:.3f} | "
        f"{'yes' if r['pays'] else 'no'} |"
        for r in rows
    ]
    return "\n".join(lines) + "\n"


def main(args: RuleArgs) -> List[dict]:
    rows = [measure(scene, args.work_dir, args.cache_dir or args.work_dir / "cache") for scene in args.scenes]
    write_report(args.output, table(rows))
    return rows


if __name__ == "__main__":
    main(tyro.cli(RuleArgs))
