"""`python -m experiments.budget_sweep`: how many Gaussians a scene needs.

Trains one method on one scene once per Gaussian budget (`--budgets`, 0 = uncapped) with
`python -m experiments.bench`, or merges bench.json files of such runs made by separate commands
(`--merge`, e.g. one GPU command per budget). Writes to `--output-dir`:
- `sweep.json`: budget, final Gaussian count, held-out `aligned` PSNR/SSIM (the bench's protocol), ms/step per run,
  and the knee;
- `sweep.md`: the same as a table;
- `psnr_vs_gaussians.png`: `aligned` PSNR against the final Gaussian count.
The knee is the smallest budget whose PSNR is within `--tolerance` dB of the best run's: the
default to set. The best run, not the uncapped one, is the reference because more Gaussians can
score lower (docs/ has a measured case).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import tyro

UNCAPPED = 100_000_000
"""What budget 0 means: more Gaussians than any run here reaches."""


@dataclass
class SweepArgs:
    scene: str = "demo"
    """'demo', 'stress:FAULT' or a dataset folder (as in python -m experiments.bench)."""
    method: str = "wild-thermal"
    budgets: Tuple[int, ...] = (50_000, 100_000, 150_000, 300_000, 0)
    """Gaussian budgets (max_gaussians) to train with; 0 = uncapped."""
    steps: int = 30_000
    tolerance: float = 0.2
    """PSNR (dB) the knee may give up against the best run."""
    output_dir: Path = Path("outputs/budget_sweep")
    cache_dir: Optional[Path] = None
    gpus: int = 1
    """Train the budgets on this many GPUs side by side, one budget per GPU at a time (as
    `python -m experiments.bench --gpus`)."""
    merge: Tuple[Path, ...] = ()
    """Instead of training: bench.json files of one method on one scene at several budgets."""


def _rows(results: List[Dict]) -> List[Dict]:
    rows = []
    for result in results:
        budget = result["args"]["max_gaussians"]
        for run in result["runs"]:
            if "failed" in run:
                rows.append({"budget": budget, "failed": run["failed"], "method": run["method"], "scene": run["scene"]})
                continue
            rows.append(
                {
                    "budget": budget,
                    "method": run["method"],
                    "scene": run["scene"],
                    "gaussians": run["gaussians"],
                    "psnr": run["psnr_aligned"],
                    "ssim": run["ssim_aligned"],
                    "ms_per_step": run["ms_per_step"],
                }
            )
    if len({(r["method"], r["scene"]) for r in rows}) > 1:
        raise ValueError(
            "a budget sweep compares one method on one scene; got "
            + ", ".join(sorted({f"{r['method']} on {r['scene']}" for r in rows}))
        )
    return sorted(rows, key=lambda r: r["budget"] if r["budget"] not in (None, 0) else UNCAPPED)


def knee(rows: List[Dict], tolerance: float) -> Optional[Dict]:
    """The smallest budget within `tolerance` dB of the best run (rows sorted by budget)."""
    done = [r for r in rows if "failed" not in r]
    if not done:
        return None
    best = max(r["psnr"] for r in done)
    return next(r for r in done if r["psnr"] >= best - tolerance)


def _write(args: SweepArgs, rows: List[Dict]) -> Dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    best = knee(rows, args.tolerance)
    result = {"tolerance_db": args.tolerance, "rows": rows, "knee": best}
    args.output_dir.mkdir(parents=True, exist_ok=True)
    (args.output_dir / "sweep.json").write_text(json.dumps(result, indent=1))
    label = lambda b: "uncapped" if b in (None, 0, UNCAPPED) else f"{b:,}"  # noqa: E731
    lines = ["| budget | Gaussians | PSNR | SSIM | ms/step |", "| --- | --- | --- | --- | --- |"]
    for r in rows:
        if "failed" in r:
            lines.append(f"| {label(r['budget'])} | failed: {r['failed'][:80]} | | | |")
        else:
            lines.append(
                f"| {label(r['budget'])} | {r['gaussians']:,} | {r['psnr']:.2f} | {r['ssim']:.3f} | "
                f"{r['ms_per_step']:.2f} |"
            )
    if best is not None:
        lines += [
            "",
            f"Knee (smallest budget within {args.tolerance} dB of the best run): {label(best['budget'])}, "
            f"{best['gaussians']:,} Gaussians, {best['psnr']:.2f} dB.",
        ]
    (args.output_dir / "sweep.md").write_text("\n".join(lines) + "\n")
    done = [r for r in rows if "failed" not in r]
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot([r["gaussians"] for r in done], [r["psnr"] for r in done], marker="o")
    for r in done:
        ax.annotate(
            label(r["budget"]), (r["gaussians"], r["psnr"]), fontsize=7, textcoords="offset points", xytext=(4, 4)
        )
    if best is not None:
        ax.axvline(best["gaussians"], ls="--", color="grey", label=f"knee: {label(best['budget'])}")
        ax.legend(fontsize=8)
    ax.set(
        title=f"{done[0]['method']} on {done[0]['scene']}" if done else "no finished run",
        xlabel="final Gaussians",
        ylabel="held-out PSNR (dB, aligned)",
    )
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(args.output_dir / "psnr_vs_gaussians.png", dpi=120)
    plt.close(fig)
    print("\n".join(lines))
    return result


def main(args: SweepArgs) -> Dict:
    if args.merge:
        return _write(args, _rows([json.loads(Path(p).read_text()) for p in args.merge]))
    from experiments.bench import BenchArgs, run_in_gpu_queues
    from experiments.bench import main as bench

    jobs = [
        BenchArgs(
            scenes=(args.scene,),
            methods=(args.method,),
            steps=args.steps,
            max_gaussians=budget or UNCAPPED,
            set=("auto_stop.grow_budget=False",),  # each budget fixed, not a start the held-back frames raise
            cache_dir=args.cache_dir,
            fps_frames=0,
            fit_steps=0,
            eval_at=(args.steps,),
            output_dir=args.output_dir / f"budget_{budget or 'uncapped'}",
        )
        for budget in args.budgets
    ]
    if args.gpus > 1:
        results = [json.loads(p.read_text()) for p in run_in_gpu_queues(jobs, args.gpus)]
    else:
        results = [bench(job) for job in jobs]
    return _write(args, _rows(results))


def entrypoint():
    main(tyro.cli(SweepArgs))


if __name__ == "__main__":
    entrypoint()
