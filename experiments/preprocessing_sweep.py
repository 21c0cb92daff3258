"""Choose the stabilization defaults (alpha, beta) by measurement.

On the demo scene (known clean frames) it measures how far the stabilized frames are from the
clean ones (RMSE in counts) and the drift left (std of dI_t, against the clean frames' own);
on DUNR the drift left. Prints a table and writes JSON + Markdown:

    python -m experiments.preprocessing_sweep --dunr ../shared/data/dunr --out docs/results/preprocessing_sweep
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import List, Optional, Tuple

import numpy as np
import tyro

from thermal_wild_ns.analysis.diagnostics import relative_mean_change
from thermal_wild_ns.data.dataparsers import ThermalDataParserConfig, ThermalDemoDataParserConfig
from thermal_wild_ns.data.thermal_io import read_raw_frame
from thermal_wild_ns.preprocessing.photometric import LevelGrid, PhotometricConfig, apply_lut, frame_luts


@dataclass
class SweepArgs:
    out: Path = Path("outputs/preprocessing_sweep")
    """Output prefix (.json and .md are added)."""
    dunr: Optional[Path] = None
    """DUNR folder (../shared/data/dunr); skipped if not given."""
    alphas: Tuple[float, ...] = (0.02, 0.05, 0.1, 0.2, 0.5, 1.0)
    betas: Tuple[float, ...] = (0.5, 0.8, 1.0)


def _sequence(parser) -> Tuple[List[np.ndarray], list, object]:
    capture, rng = parser.capture(), parser.radiometric_range()
    return [read_raw_frame(f.image, rng.palette) for f in capture.frames], capture.frames, rng


def _stabilized(frames, rng, alpha, beta):
    grid = LevelGrid.for_dtype(rng.dtype, rng.low, rng.high)
    luts = frame_luts(frames, grid, rng.low, rng.high, PhotometricConfig("stab", alpha, beta))
    return [apply_lut(lut, f, grid) for lut, f in zip(luts, frames)]


def main(args: SweepArgs) -> None:
    demo = ThermalDemoDataParserConfig().setup()
    frames, capture_frames, rng = _sequence(demo)
    clean = [read_raw_frame(f.ground_truth).astype(np.float64) for f in capture_frames]
    dunr = _sequence(ThermalDataParserConfig(data=args.dunr, seed_points="random").setup()) if args.dunr else None
    rows = []
    settings = [(None, None)] + [(a, b) for a in args.alphas for b in args.betas]
    for alpha, beta in settings:
        processed = frames if alpha is None else _stabilized(frames, rng, alpha, beta)
        row = {
            "alpha": alpha,
            "beta": beta,
            "demo_rmse_counts": float(np.sqrt(np.mean([np.mean((p - c) ** 2) for p, c in zip(processed, clean)]))),
            "demo_std_dI": float(np.std(relative_mean_change([p.mean() for p in processed]))),
        }
        if dunr is not None:
            d = dunr[0] if alpha is None else _stabilized(dunr[0], dunr[2], alpha, beta)
            row["dunr_std_dI"] = float(np.std(relative_mean_change([p.mean() for p in d])))
        rows.append(row)
        print({k: (round(v, 6) if isinstance(v, float) else v) for k, v in row.items()})
    result = {"demo_clean_std_dI": float(np.std(relative_mean_change([c.mean() for c in clean]))), "rows": rows}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(result, indent=1))
    lines = [
        "| alpha | beta | demo RMSE vs clean (counts) | demo std dI_t | DUNR std dI_t |",
        "| --- | --- | --- | --- | --- |",
    ]
    for r in rows:
        name = ("raw", "") if r["alpha"] is None else (f"{r['alpha']:g}", f"{r['beta']:g}")
        lines.append(
            f"| {name[0]} | {name[1]} | {r['demo_rmse_counts']:.2f} | {r['demo_std_dI']:.5f} | "
            f"{r.get('dunr_std_dI', float('nan')):.5f} |"
        )
    lines.append(
        f"\nClean demo frames' own std dI_t: {result['demo_clean_std_dI']:.5f} (real content change as the camera "
        f"moves)."
    )
    args.out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main(tyro.cli(SweepArgs))
