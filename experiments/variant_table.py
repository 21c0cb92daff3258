"""One configuration against a baseline, scene by scene: each protocol's mean (min–max) over seeds, the change in
the mean, and whether the two ranges are apart (bold), from bench.json files of the same protocol.

    python -m experiments.variant_table BASELINE/bench.json VARIANT/bench.json ... [--protocols novel time aligned]
        [--pool-baseline OTHER/bench.json ...]

`--pool-baseline` adds more runs of the baseline's configuration from other calls to its seeds: the same
configuration moves between calls (the stop and the budget end runs at different steps), so a variant run in one
call is judged against the baseline's spread over all of them.

Prints one Markdown table per variant file; `aligned` and `half` are fits on the held-out frame and `oracle` a
bound, so the header says so. `gap` is each run's `oracle` minus its `time` (lower is better).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Dict, List, Sequence

import numpy as np

from experiments import mean_range

LABELS = {
    "aligned": "`aligned` (a fit)",
    "half": "`half` (a fit)",
    "oracle": "`oracle` (a bound)",
    "gap": "`time`–`oracle` gap",
}


def scores_by_scene(paths: Sequence[Path], protocol: str) -> Dict[str, List[float]]:
    """scene -> the protocol's PSNR (`gap`: oracle minus time) of every finished run in the bench.json files."""
    found: Dict[str, List[float]] = {}
    for path in paths:
        for run in json.loads(Path(path).read_text())["runs"]:
            if "failed" not in run:
                score = run["psnr_oracle"] - run["psnr_time"] if protocol == "gap" else run[f"psnr_{protocol}"]
                found.setdefault(run["scene"], []).append(float(score))
    return found


def apart(a: List[float], b: List[float]) -> bool:
    """True where the two sets of seeds do not overlap."""
    return max(a) < min(b) or max(b) < min(a)


def table(baseline: Sequence[Path], variant: Path, protocols: List[str]) -> str:
    """The Markdown table of one variant file against the baseline's files (their runs pooled)."""
    header = ["scene"]
    for protocol in protocols:
        header += [LABELS.get(protocol, f"`{protocol}`"), "Δ"]
    lines = ["| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
    base = {p: scores_by_scene(baseline, p) for p in protocols}
    other = {p: scores_by_scene([variant], p) for p in protocols}
    for scene in base[protocols[0]]:
        if scene not in other[protocols[0]]:
            continue
        row = [scene]
        for protocol in protocols:
            a, b = base[protocol][scene], other[protocol][scene]
            delta = f"{np.mean(b) - np.mean(a):+.2f}"
            row += [mean_range(b), f"**{delta}**" if apart(a, b) else delta]
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def baseline_rows(baseline: Sequence[Path], protocols: List[str]) -> str:
    """The pooled baseline's own rows (scene, its runs, each protocol's mean (min–max)), in the tables' columns."""
    base = {p: scores_by_scene(baseline, p) for p in protocols}
    lines = []
    for scene, scores in base[protocols[0]].items():
        row = [f"{scene} (baseline, {len(scores)} runs)"]
        for protocol in protocols:
            row += [mean_range(base[protocol][scene]), ""]
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("baseline", type=Path, help="the baseline's bench.json")
    parser.add_argument("variants", type=Path, nargs="+", help="each variant's bench.json")
    parser.add_argument("--protocols", nargs="+", default=["novel", "time", "aligned", "oracle"])
    parser.add_argument(
        "--pool-baseline", type=Path, nargs="+", default=[], help="more runs of the baseline's configuration"
    )
    args = parser.parse_args()
    baseline = [args.baseline, *args.pool_baseline]
    for variant in args.variants:
        print(f"{variant} against {', '.join(map(str, baseline))} (bold: ranges apart)\n")
        print(table(baseline, variant, args.protocols) + "\n")
    if args.pool_baseline:
        print("The baseline's runs, pooled:\n\n" + baseline_rows(baseline, args.protocols) + "\n")


if __name__ == "__main__":
    main()
