"""The Gaussian budget each run's held-back frames chose (`--auto-stop.grow-budget`) and the curve behind it:
the best held-back PSNR under each budget the run had, from the `auto_stop` records of bench.json files.

    python -m experiments.budget_curve A/bench.json B/bench.json ... [--start 12500] [--chart curve.png]

Prints one row per run (with the model's size at each budget's best check where the run recorded it);
`--chart` draws one panel per scene, the held-back PSNR against the budget, a line
per run. The held-back frames are training frames kept from the gradient (the automatic stop's), not the
held-out views the protocols score; their PSNR is the stop's, after a gain + offset fit to each frame.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import List, Optional

from thermal_wild_ns.training.stop_rules import HeldBackBudget

COLUMNS = [
    "scene",
    "file",
    "seed",
    "best held-back PSNR per budget",
    "Gaussians at each best",
    "budget chosen",
    "Gaussians at the end",
]


def run_curves(path: Path, start: int) -> List[dict]:
    """One entry per finished run of a bench.json whose automatic stop recorded its checks: the scene,
    seed, (budget, best held-back PSNR) per budget, the budget of its kept model and its final Gaussians.
    `start`: the budget the runs started from (the bench's `--max-gaussians`, else the default)."""
    data = json.loads(Path(path).read_text())
    asked = data.get("args", {}).get("max_gaussians") or start
    found = []
    for run in data["runs"]:
        record = run.get("auto_stop")
        if "failed" in run or not record:
            continue
        raises = [(r["step"], r["budget"]) for r in record.get("budget_raises", [])]
        start = record.get("budget_start", asked)  # absent from older runs' records (the seed points may raise it)
        budget = HeldBackBudget(start=start, limit=max([start] + [b for _, b in raises]), raises=raises)
        curve = budget.best_per_budget([(c["step"], c["psnr"]) for c in record["checks"]])
        # the model's size at each budget's best check, where the run recorded it
        best_checks = {}
        for check in record["checks"]:
            at = budget.budget_at(check["step"])
            if check["psnr"] == dict(curve).get(at) and at not in best_checks:
                best_checks[at] = check
        kept = record.get("kept_step")
        kept = record["last_step"] if kept is None else kept
        chosen = budget.budget_at(kept)
        found.append(
            dict(
                scene=run["scene"],
                file=Path(path).name,
                seed=run.get("seed"),
                curve=curve,
                counts=[best_checks[b].get("gaussians") for b, _ in curve],
                chosen=chosen,
                gaussians=run.get("gaussians"),
            )
        )
    return found


def table(runs: List[dict]) -> str:
    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + " --- |" * len(COLUMNS)]
    for run in runs:
        curve = ", ".join(f"{b:,}: {psnr:.2f}" for b, psnr in run["curve"])
        gaussians = "—" if run["gaussians"] is None else f"{run['gaussians']:,}"
        counts = ", ".join("—" if c is None else f"{c:,}" for c in run["counts"])
        cells = [run["scene"], run["file"], str(run["seed"]), curve, counts, f"{run['chosen']:,}", gaussians]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def doubling_summary(runs: List[dict], within: float = 0.2) -> str:
    """How much each raise moved the best held-back score (the next budget's best less this one's), over
    every raise of every run."""
    steps = [b[1] - a[1] for run in runs for a, b in zip(run["curve"], run["curve"][1:])]
    if not steps:
        return "no run had a check under a raised budget"
    small = sum(abs(d) <= within for d in steps)
    return (
        f"each raise moved the best held-back PSNR by {min(steps):+.2f} to {max(steps):+.2f} dB; "
        f"within ±{within:g} dB on {small} of {len(steps)}"
    )


def chart(runs: List[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenes = sorted({r["scene"] for r in runs})
    columns = min(4, len(scenes))
    rows = -(-len(scenes) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(4.2 * columns, 3.4 * rows), squeeze=False)
    for ax in axes.flat[len(scenes) :]:
        ax.axis("off")
    for ax, scene in zip(axes.flat, scenes):
        budgets_seen = set()
        for run in (r for r in runs if r["scene"] == scene):
            budgets, scores = zip(*run["curve"])
            budgets_seen.update(budgets)
            line = ax.plot(budgets, scores, marker="o", label=f"seed {run['seed']}")[0]
            chosen = dict(run["curve"])[run["chosen"]]
            ax.plot([run["chosen"]], [chosen], marker="*", markersize=14, color=line.get_color())
        ax.set_xscale("log", base=2)
        ticks = sorted(budgets_seen)
        ax.set_xticks(ticks, [f"{b / 1000:g}k" for b in ticks])
        ax.set_xlim(ticks[0] / 1.3, ticks[-1] * 1.3)
        ax.set_title(scene)
        ax.set_xlabel("Gaussian budget (★ the kept model's)")
        ax.set_ylabel("best held-back PSNR, gain+offset fitted (dB)")
        ax.legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: Optional[List[str]] = None) -> List[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="+", type=Path)
    parser.add_argument("--start", type=int, default=12_500, help="budget start where the bench named none")
    parser.add_argument("--chart", type=Path, default=None)
    args = parser.parse_args(argv)
    runs = [r for f in args.files for r in run_curves(f, args.start)]
    print(table(runs))
    print()
    print(doubling_summary(runs))
    if args.chart is not None:
        chart(runs, args.chart)
    return runs


if __name__ == "__main__":
    main()
