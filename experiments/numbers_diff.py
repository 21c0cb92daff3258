"""Whether two packages give the same numbers: the folders `experiments/refactor_numbers.sh` wrote for each
(the CPU demo's `metrics.json`, the 300-step DUNR run's `ns-eval` scores), compared key by key, and optionally one
checkpoint's cheap protocols scored by both packages (`experiments.score_checkpoint`, JSON files).

    python -m experiments.numbers_diff BEFORE AFTER [--scores SCORES_BEFORE.json SCORES_AFTER.json] \
      [--output docs/results/refactor_check_cpu/README-table.md]

Prints (and writes) a Markdown table: each score before and after, and the largest absolute difference.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Dict, List, Tuple

TIMINGS = ("train_seconds", "eval_seconds", "num_rays_per_sec", "fps")
"""Keys that measure the machine's pace, not the method: left out of the comparison."""


def numbers(folder: Path) -> Dict[str, Dict[str, float]]:
    """The demo's and DUNR's scalar scores of one `refactor_numbers.sh` folder (timings left out)."""
    demo = json.loads((folder / "demo" / "metrics.json").read_text())
    dunr = json.loads((folder / "dunr_eval.json").read_text())["results"]
    scalar = lambda d: {
        k: float(v)
        for k, v in d.items()
        if isinstance(v, (int, float)) and not isinstance(v, bool) and not k.endswith(TIMINGS)
    }
    return {"demo": scalar(demo), "dunr": scalar(dunr)}


def compared(before: Dict[str, Dict[str, float]], after: Dict[str, Dict[str, float]]) -> List[Tuple]:
    """(run, key, before, after, |difference|) for every key both have; a key one side lacks is listed too."""
    rows = []
    for run in before:
        keys = sorted(set(before[run]) | set(after.get(run, {})))
        for key in keys:
            a, b = before[run].get(key), after.get(run, {}).get(key)
            rows.append((run, key, a, b, None if a is None or b is None else abs(a - b)))
    return rows


def table(rows: List[Tuple], headline: Tuple[str, ...] = ("psnr_", "celsius_mae_")) -> str:
    """The headline rows (PSNR and °C MAE per protocol) and the largest difference over every key."""
    shown = [r for r in rows if r[1].startswith(headline) and not r[1].endswith("_std")]
    lines = ["| run | score | before | after | difference |", "| --- | --- | --- | --- | --- |"]
    fmt = lambda v: "-" if v is None else f"{v:.6g}"
    lines += [f"| {run} | `{key}` | {fmt(a)} | {fmt(b)} | {fmt(d)} |" for run, key, a, b, d in shown]
    differences = [d for *_, d in rows if d is not None]
    missing = [f"{run}/{key}" for run, key, a, b, _ in rows if a is None or b is None]
    lines.append("")
    lines.append(f"Largest absolute difference over all {len(differences)} scores: {max(differences):.3g}")
    if missing:
        lines.append(f"Only on one side: {', '.join(missing)}")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("before", type=Path)
    parser.add_argument("after", type=Path)
    parser.add_argument("--scores", type=Path, nargs=2, help="score_checkpoint JSON of one checkpoint by each package")
    parser.add_argument("--output", type=Path)
    args = parser.parse_args()
    text = table(compared(numbers(args.before), numbers(args.after)))
    if args.scores:
        first, second = (json.loads(p.read_text()) for p in args.scores)
        verdict = "identical" if first == second else "DIFFERENT"
        text += f"\nOne checkpoint scored by both packages (`experiments.score_checkpoint`): {verdict}"
        text += f" ({len(first)} scores)\n"
    print(text)
    if args.output:
        args.output.parent.mkdir(parents=True, exist_ok=True)
        args.output.write_text(text)


if __name__ == "__main__":
    main()
