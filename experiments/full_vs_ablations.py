"""Is the full method within reach of the best of its ablations and splatfacto, scene by scene?

    python -m experiments.full_vs_ablations --full A/bench.json ... --others B/bench.json ... \
        --output docs/results/full_vs_ablations.md

Reads bench.json files (`python -m experiments.bench`). `--full`: the runs of `wild-thermal` (its
label before any " (...)"), one configuration per scene: where several files hold a scene, the last
file's runs replace the earlier ones (`--pool`: they add to them, more seeds of one configuration).
`--others`: every other method's runs (the full method's runs in them are left out; a method's runs of a fixed
schedule, no automatic stop, are a rival of their own per number of steps). For each scene and
protocol (`aligned`, `time`), the full method's mean over seeds against the best other method's mean: the
margin, and whether it is within `--tolerance` dB.
Also the steps the automatic stop saved: steps asked minus steps trained, and those steps at the
run's own ms/step.
"""

from __future__ import annotations

import json
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Tuple

import numpy as np
import tyro

from experiments import write_report
from experiments.bench import _cell, spread

FULL = "wild-thermal"
PROTOCOLS = ("aligned", "time")


@dataclass
class Args:
    full: Tuple[Path, ...]
    """bench.json files with the full method's runs (later files replace a scene's earlier runs)."""
    others: Tuple[Path, ...]
    """bench.json files with the ablations' and splatfacto's runs."""
    output: Path = Path("outputs/full_vs_ablations.md")
    pool: bool = False
    """Pool the full method's runs of a scene over the `--full` files (more seeds of the same configuration
    from several calls) instead of letting a later file replace them."""
    tolerance: float = 0.3
    """How far (dB) under the best other method the full method may be."""


def base_method(label: str) -> str:
    """'wild-thermal (num-downscales 1)' -> 'wild-thermal'."""
    return label.split(" (")[0]


def _runs(path: Path) -> List[dict]:
    return [r for r in json.loads(Path(path).read_text())["runs"] if "failed" not in r]


def collect(args: Args) -> Tuple[Dict[str, List[dict]], Dict[Tuple[str, str], List[dict]]]:
    """The full method's runs by scene, and the other methods' runs by (scene, method label)."""
    full: Dict[str, List[dict]] = {}
    for path in args.full:
        by_scene: Dict[str, List[dict]] = defaultdict(list)
        for run in _runs(path):
            if base_method(run["method"]) == FULL:
                by_scene[run["scene"]].append(run)
        for scene, runs in by_scene.items():  # a later file's scene replaces the earlier one, or adds to it
            full[scene] = full.get(scene, []) + runs if args.pool else runs
    others: Dict[Tuple[str, str], List[dict]] = defaultdict(list)
    for path in args.others:
        for run in _runs(path):
            if base_method(run["method"]) != FULL:
                others[(run["scene"], rival_label(run))].append(run)
    return full, others


def rival_label(run: dict) -> str:
    """A run's method label, with its steps where it trained a fixed schedule (no automatic stop): one method on
    two schedules (splatfacto at the protocol's steps and at its own 30k) is two rivals, not one pooled."""
    if run.get("auto_stop"):
        return run["method"]
    return f"{run['method']}, {run['steps']} steps"


def _mean_range(values: List[float], digits: int = 2) -> str:
    """Mean (min–max) as the bench's tables write it (the range only where the runs differ)."""
    return _cell({"values": spread(values)}, "values", digits)


def margins(args: Args) -> Tuple[str, List[dict]]:
    full, others = collect(args)
    rows, lines = [], []
    lines += [
        f"Full `{FULL}` against the best of the other methods on each scene (mean over seeds, min–max), "
        f"within {args.tolerance} dB or not:",
        "",
        "| scene | protocol | full | best other | its mean | margin | met |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for scene, runs in full.items():
        rivals = {method: rs for (s, method), rs in others.items() if s == scene}
        for protocol in PROTOCOLS:
            key = f"psnr_{protocol}"
            mine = [r[key] for r in runs]
            best_method, best = max(
                ((m, float(np.mean([r[key] for r in rs]))) for m, rs in rivals.items()), key=lambda mb: mb[1]
            )
            margin = float(np.mean(mine)) - best
            met = margin >= -args.tolerance
            rows.append(
                {
                    "scene": scene,
                    "protocol": protocol,
                    "full": float(np.mean(mine)),
                    "best": best_method,
                    "best_mean": best,
                    "margin": margin,
                    "met": met,
                    "seeds": len(mine),
                }
            )
            lines.append(
                f"| {scene} | `{protocol}` | {_mean_range(mine)} | {best_method} | {best:.2f} | {margin:+.2f} | "
                f"{'yes' if met else f'**no**, {-margin:.2f} dB short'} |"
            )
    lines += ["", "Methods compared on each scene:", ""]
    for scene in full:
        lines.append(f"- {scene}: " + ", ".join(sorted({m for (s, m) in others if s == scene})))
    lines += [
        "",
        "The automatic stop (full method): steps trained of those asked, and the steps saved at each run's ms/step:",
        "",
    ]
    lines += [
        "| scene | seeds | steps trained | of | steps saved | seconds saved |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for scene, runs in full.items():
        stops = [r for r in runs if r.get("auto_stop")]
        if not stops:
            continue
        trained = [r["steps"] for r in stops]
        asked = stops[0]["auto_stop"]["steps_asked"]
        saved = [asked - r["steps"] for r in stops]
        seconds = [(asked - r["steps"]) * r["ms_per_step"] / 1000 for r in stops]
        lines.append(
            f"| {scene} | {len(stops)} | {_mean_range(trained, 0)} | {asked} | "
            f"{np.mean(saved):.0f} | {_mean_range(seconds)} |"
        )
    return "\n".join(lines) + "\n", rows


def main(args: Args) -> List[dict]:
    text, rows = margins(args)
    write_report(args.output, text)
    return rows


if __name__ == "__main__":
    main(tyro.cli(Args))
