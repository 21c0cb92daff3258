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
from thermal_wild_ns.preprocessing.stage import CONTRAST_SPREAD


@dataclass
class RuleArgs:
    scenes: Tuple[str, ...] = ("demo",)
    """'demo', 'stress:FAULT' or dataset folders (as in python -m experiments.bench)."""
    output: Path = Path("outputs/preprocessing_rule.md")
    work_dir: Path = Path("outputs/preprocessing_rule")
    """Where generated scenes go."""
    cache_dir: Optional[Path] = None
    """Triangulation / preprocessing cache (default: `work_dir/cache`), as in python -m experiments.bench."""


def measure(scene: str, work_dir: Path, cache_dir: Path) -> dict:
    from thermal_wild_ns.data.datamanager import ThermalDatamanagerConfig
    from thermal_wild_ns.data.dataparsers import ThermalDataParserConfig, ThermalDemoDataParserConfig
    from thermal_wild_ns.preprocessing.photometric import PhotometricConfig

    if scene == "demo":
        parser = ThermalDemoDataParserConfig(data=work_dir / "demo")
    elif scene.startswith("stress:"):
        fault = scene.split(":", 1)[1]
        parser = ThermalDemoDataParserConfig(data=work_dir / f"stress-{fault}", scene=fault)  # type: ignore[arg-type]
    else:
        parser = ThermalDataParserConfig(data=Path(scene), cache_dir=cache_dir)
    datamanager = ThermalDatamanagerConfig(
        dataparser=parser, preprocessing=PhotometricConfig(), preprocessing_cache=cache_dir
    ).setup(device="cpu")
    sequence = datamanager.preprocessed  # skip_when_stable off: always the processed sequence
    raw, processed = sequence.frame_mean_spreads()
    pays, reason = sequence.decision()
    name = scene if not Path(scene).is_dir() else Path(scene).name
    return {
        "scene": name,
        "raw": raw,
        "processed": processed,
        "contrast": sequence.frame_contrast_spread(),
        "pays": pays,
        "reason": reason,
    }


def table(rows: List[dict]) -> str:
    lines = [
        f"The full method's preprocessing rule (`preprocessing_pays`: preprocessing must steady the frames' "
        f"mean levels and their contrast spread must reach {CONTRAST_SPREAD}):",
        "",
        "| scene | frame-mean spread raw -> preprocessed | contrast spread | preprocessed? |",
        "| --- | --- | --- | --- |",
    ]
    lines += [
        f"| {r['scene']} | {r['raw']:.4f} -> {r['processed']:.4f} | {r['contrast']:.3f} | "
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
