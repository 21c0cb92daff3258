"""The table and chart of docs/results/growth/README.md: each configuration's held-out PSNR at every
checkpoint of its runs against the Gaussians it held there, from the *-bench.json files of a folder.

python -m experiments.growth_table docs/results/growth      # prints the table, writes novel_vs_gaussians.png
python -m experiments.growth_table docs/results/growth flight2-3dgs-prune   # only the bench files whose name holds
                                                           # it: novel_vs_gaussians-flight2-3dgs-prune.png

Then the automatic stop's held-back checks of the runs that recorded them, and the model each run kept.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Dict, List

import numpy as np

from experiments import mean_range

COLUMNS = ["scene", "method, bench file", "card", "step", "Gaussians", "`novel`", "`aligned` (fit on the frame)"]


def curves(folder: Path) -> Dict[str, List[dict]]:
    """bench file name -> its runs (each with `curve`: step, Gaussians and scores at each checkpoint)."""
    found = {}
    for path in sorted(folder.glob("*-bench.json")):
        data = json.loads(path.read_text())
        found[path.name.removesuffix("-bench.json")] = dict(device=data.get("device", "?"), runs=data["runs"])
    return found


def table(found: Dict[str, dict]) -> str:
    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + " --- |" * len(COLUMNS)]
    for name, bench in found.items():
        runs = bench["runs"]
        card = "H200" if "H200" in bench["device"] else "H100" if "H100" in bench["device"] else bench["device"]
        for index, point in enumerate(runs[0]["curve"]):
            at = [r["curve"][index] for r in runs if len(r["curve"]) > index]
            gaussians = int(np.mean([p["gaussians"] for p in at]))
            scores = [mean_range([p[f"psnr_{k}"] for p in at]) for k in ("novel", "aligned")]
            label = f"{runs[0]['method'].split(' (')[0]}, `{name}` ({len(at)} seeds)"
            cells = [runs[0]["scene"], label, card, str(point["step"]), f"{gaussians:,}", *scores]
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def checks_table(found: Dict[str, dict]) -> str:
    """The automatic stop's held-back checks of each bench file whose runs recorded them (a gain + offset fit per
    held-back frame: a training signal, not a held-out score), check by check over the seeds, and the model the
    stop kept with its held-out scores."""
    lines = ["| bench file | check step | Gaussians | held-back PSNR (a fit) |", "| --- | --- | --- | --- |"]
    for name, bench in found.items():
        runs = [r for r in bench["runs"] if (r.get("auto_stop") or {}).get("checks")]
        if not runs:
            continue
        for index in range(min(len(r["auto_stop"]["checks"]) for r in runs)):
            at = [r["auto_stop"]["checks"][index] for r in runs]
            gaussians = int(np.mean([c["gaussians"] for c in at]))
            lines.append(f"| `{name}` | {at[0]['step']} | {gaussians:,} | {mean_range([c['psnr'] for c in at])} |")
        kept = [r["auto_stop"]["kept_step"] for r in runs]
        counts = [r["gaussians"] for r in runs]
        lines.append(
            f"| `{name}`, the model kept | {min(kept)}–{max(kept)} | {min(counts):,}–{max(counts):,} | `novel` "
            f"{mean_range([r['psnr_novel'] for r in runs])}, `aligned` (a fit) "
            f"{mean_range([r['psnr_aligned'] for r in runs])} |"
        )
    return "\n".join(lines)


def panel(bench: dict) -> str:
    """The chart's panel of a bench file: its scene and method (without the settings it changed)."""
    run = bench["runs"][0]
    return f"{run['scene']}: {run['method'].split(' (')[0]}"


def chart(found: Dict[str, dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = sorted({panel(b) for b in found.values()})
    fig, axes = plt.subplots(1, len(panels), figsize=(6 * len(panels), 4.8), squeeze=False)
    for ax, title in zip(axes[0], panels):
        for name, bench in found.items():
            if panel(bench) != title:
                continue
            runs = bench["runs"]
            steps = min(len(r["curve"]) for r in runs)  # the checkpoints every seed reached (the stop ends some)
            gaussians = [np.mean([r["curve"][i]["gaussians"] for r in runs]) for i in range(steps)]
            novel = np.array([[r["curve"][i]["psnr_novel"] for r in runs] for i in range(steps)])
            line = ax.plot(gaussians, novel.mean(1), marker="o", label=name)[0]
            ax.fill_between(gaussians, novel.min(1), novel.max(1), color=line.get_color(), alpha=0.15)
        ax.set_xscale("log")
        ax.set_xlabel("Gaussians (mean of the seeds, at each checkpoint of the runs)")
        ax.set_ylabel("`novel` PSNR (dB): mean, band = min-max of the seeds")
        ax.set_title(f"{title}: held-out views as the model grows", fontsize=10)
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(folder: Path, only: str = "") -> None:
    found = {name: bench for name, bench in curves(folder).items() if only in name}
    print(table(found))
    print()
    print(checks_table(found))
    chart(found, folder / (f"novel_vs_gaussians-{only}.png" if only else "novel_vs_gaussians.png"))


if __name__ == "__main__":
    main(Path(sys.argv[1]), *sys.argv[2:3])
