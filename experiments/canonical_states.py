"""`python -m experiments.canonical_states BENCH_DIR`: every run of a bench scored at several canonical
states (`--states`, default `mean` and `typical`), the cheap protocols only (`score_checkpoint`'s).

Issue 33 asks for a canonical state worth rendering: `typical` (docs/design.md, "The canonical
state") against the default `mean`, on the same checkpoints. Each (run, state) is scored in its own
process, as `experiments.score_checkpoint` does; writes `canonical_states.jsonl` (one line per run and
state) and `canonical_states.md` (per scene and state, the mean (min–max) over the bench's seeds) into
BENCH_DIR and prints the table.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Dict, List

from experiments import json_from_module, mean_range

PROTOCOLS = ("novel", "time", "aligned")


def score(config: str, state: str) -> Dict:
    return json_from_module("experiments.score_checkpoint", config, "--canonical", state)


def table(rows: List[Dict], states: List[str]) -> str:
    lines = [
        "| scene | canonical state | seeds | "
        + " | ".join(f"`{p}` PSNR" + (" (fit on the frame)" if p == "aligned" else "") for p in PROTOCOLS)
        + " |",
        "| --- | --- | --- | " + " | ".join("---" for _ in PROTOCOLS) + " |",
    ]
    for scene in dict.fromkeys(r["scene"] for r in rows):
        for state in states:
            runs = [r for r in rows if r["scene"] == scene and r["canonical"] == state]
            cells = [mean_range([r[f"psnr_{protocol}"] for r in runs]) for protocol in PROTOCOLS]
            lines.append(f"| {scene} | {state} | {len(runs)} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("bench_dir", type=Path, help="an experiments.bench output folder (its bench.json)")
    parser.add_argument("--states", nargs="+", default=["mean", "typical"], help="canonical states to score")
    args = parser.parse_args()
    runs = json.loads((args.bench_dir / "bench.json").read_text())["runs"]
    rows = []
    for run in runs:
        for state in args.states:
            rows.append({"scene": run["scene"], "seed": run["seed"], "canonical": state, **score(run["config"], state)})
            print(f"{run['scene']} seed {run['seed']} {state}: novel {rows[-1]['psnr_novel']:.2f} dB", file=sys.stderr)
    (args.bench_dir / "canonical_states.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    markdown = table(rows, args.states)
    (args.bench_dir / "canonical_states.md").write_text(markdown)
    print(markdown)


if __name__ == "__main__":
    main()
