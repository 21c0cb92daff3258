"""`python -m experiments.multi_gpu_table [FOLDER]`: the tables of docs/results/multi_gpu/README.md from the
files the GPU runs wrote there (`bash experiments/gpu_plans.sh PLAN`: survey-cost, two-vs-one, large-two,
stop-two, quality-one, quality-two)."""

from __future__ import annotations

import json
import statistics
import sys
from pathlib import Path

from experiments import mean_range
from experiments.survey_cost import growth_line, markdown

QUALITY_RUNS = (
    ("quality_h100_a19f191", 250, "two H100s of one host, commit a19f191"),
    ("quality_h200_e14f018", 250, "two H200s of one host, commit e14f018"),
    ("quality_h200_1000_07bb0f4", 1000, "two H200s of one host, commit 07bb0f4, `novel` only"),
)
"""The quality runs' folders, their surveys' frames and titles (plans quality-one and quality-two;
files score-gpus{N}{tag}-seed{1,2,3}.json; a protocol a folder's files lack shows as not scored)."""
RUN_KINDS = (
    ("score-gpus1", 1, "1"),
    ("score-gpus2", 2, "2, Adam as for one image"),
    ("score-gpus2-scaled", 2, "2, Adam set for two images (the launcher's default since)"),
)


def quality_table(folder: Path, frames: int, title: str) -> list:
    """One table of the quality runs in `folder` (a `frames`-frame survey): a row for each kind of run it holds."""
    lines = [
        f"{frames:,}-frame survey, 2,000 steps through `torchrun -m thermal_wild_ns.multi_gpu` (plans quality-one, "
        f"quality-two), {title}, scored by experiments.score_checkpoint: mean (min–max) of seeds 1–3",
        "",
        "| GPUs | images seen | Gaussians | `novel` PSNR | `time` PSNR | `aligned` PSNR (fit on the frame) "
        "| `aligned` °C MAE (fit on the frame) |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for stem, gpus, label in RUN_KINDS:
        files = [folder / f"{stem}-seed{seed}.json" for seed in (1, 2, 3)]
        if not all(path.exists() for path in files):
            continue
        scores = [json.loads(path.read_text()) for path in files]
        lines.append(
            f"| {label} | {2000 * gpus:,} | {statistics.mean(s['gaussians'] for s in scores):,.0f} | "
            + " | ".join(scored(scores, f"psnr_{p}") for p in ("novel", "time", "aligned"))
            + f" | {scored(scores, 'celsius_mae_aligned')} |"
        )
    return lines


def scored(scores: list, key: str) -> str:
    """mean (min–max) of `key` over the seeds' scores, or "not scored" where they lack it."""
    return mean_range([s[key] for s in scores]) if all(key in s for s in scores) else "not scored"


def main(folder: Path) -> str:
    one, two = (json.loads((folder / f"multi_gpu_cost_{n}.json").read_text()) for n in (1, 2))
    by_count = {row["gaussians"]: row for row in one["counts"]}
    lines = [
        f"1,000-frame survey, {one['device']}; {one['steps']} timed steps per count "
        "(experiments.multi_gpu_cost, plan two-vs-one)",
        "",
        "| Gaussians | 1 GPU ms/step | 1 GPU images/s | 1 GPU peak GiB | 2 GPUs ms/step | 2 GPUs images/s "
        "| 2 GPUs peak GiB per GPU | throughput 2 vs 1 |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for row in two["counts"]:
        single = by_count.get(row["gaussians"])
        cells = (
            [f"{single['ms_per_step']}", f"{single['images_per_s']}", f"{single['gpu_peak_gib_per_rank'][0]}"]
            if single
            else ["does not fit", "", ""]
        )
        ratio = f"{row['images_per_s'] / single['images_per_s']:.2f}x" if single else "—"
        lines.append(
            f"| {row['gaussians']:,} | {' | '.join(cells)} | {row['ms_per_step']} | {row['images_per_s']} "
            f"| {max(row['gpu_peak_gib_per_rank'])} | {ratio} |"
        )
    lines += ["", f"One GPU's first limit: {one['first_limit'].split('. Including')[0]}.", ""]
    for name, frames, title in QUALITY_RUNS:
        lines += quality_table(folder / name, frames, title) + [""]
    lines += ["", "One GPU: surveys of 250 to 4,000 frames (experiments.survey_cost, plans cost-one and cost-4000)", ""]
    for name in ("cost_h100_250_1000.json", "cost_h100_4000.json"):
        lines.append(markdown(json.loads((folder / name).read_text())))
    for name, title in (
        (
            "cost_h100_host_snapshots.jsonl",
            "H100 after the snapshots moved to the host (plan cost-all, GROWTH_STEPS=60; commit 1080822)",
        ),
        (
            "cost_h200_gpu_snapshots.jsonl",
            "H200, snapshots still on the GPU (plan cost-one, GROWTH_STEPS=60; commit f871391)",
        ),
    ):
        lines += [
            "",
            f"{title}: the lines it printed",
            "",
            "| frames | Gaussians | ms/step | GPU peak GiB |",
            "| --- | --- | --- | --- |",
        ]
        growth = []
        for line in (folder / name).read_text().splitlines():
            row = json.loads(line)
            if "growth" in row:
                growth.append(row)
            else:
                lines.append(
                    f"| {row['frames']:,} | {row['gaussians']:,} | {row['ms_per_step']} | {row['gpu_peak_gib']} |"
                )
        for row in growth:
            lines.append("\n" + growth_line(row["frames"], row["growth"]))
    lines += [
        "",
        "H100, 1,000 frames, with the pruning that skips where its copies do not fit (plan cost-1000, "
        "GROWTH_STEPS=60; commit 3e4321b)",
        "",
        markdown(json.loads((folder / "cost_h100_1000_growth.json").read_text())),
        "",
        "H100, 1,000 frames, 128M Gaussians only, with the rollback that frees the failed state first (plan "
        "cost-1000, GAUSSIANS=128000000 GROWTH_STEPS=60; the package of commit 0d5ff91, which has b304b28)",
        "",
        markdown(json.loads((folder / "cost_h100_1000_rollback.json").read_text())),
        "",
        "H200 after the snapshots moved to the host, 1,000 and 4,000 frames, 128M Gaussians and up (plans "
        'cost-1000 with GAUSSIANS="128000000 192000000 256000000", cost-4000 with GAUSSIANS="128000000 '
        '192000000"; commit c78d4cd)',
        "",
    ]
    for name in ("cost_h200_1000_host_snapshots.json", "cost_h200_4000_host_snapshots.json"):
        lines.append(markdown(json.loads((folder / name).read_text())))
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(main(Path(sys.argv[1] if len(sys.argv) > 1 else "docs/results/multi_gpu")))
