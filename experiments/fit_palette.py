"""Fit a palette's colour table to real colour-mapped frames (a principal curve through their
pixels, started from the built-in table), and print it as stops to paste into
`thermal_wild_ns/data/palettes.py`.

    python -m experiments.fit_palette --frames ../shared/data/rgbt_frames/*.jpg --start iron

Each round assigns every pixel to its nearest table entry, moves each entry to the mean of its
pixels (entries with too few keep their place), smooths the table along the level axis and
resamples it to equal colour steps (so no stretch of levels collapses). The level order of the
starting table (cold to hot) is kept. It prints the median and 90th-percentile distance of the
pixels to the old and the new table.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import List

import cv2
import numpy as np
import tyro
from scipy.ndimage import gaussian_filter1d
from scipy.spatial import cKDTree

from thermal_wild_ns.data.palettes import palette_rgb


@dataclass
class FitPaletteArgs:
    frames: List[Path]
    """Colour-mapped frames (8-bit RGB images) that use one palette."""
    start: str = "iron"
    """The built-in palette to start from (sets the level order)."""
    rounds: int = 15
    smoothing: float = 6.0
    """Gaussian smoothing of the table along its 256 levels, in levels (keeps the curve from
    wiggling into the JPEG noise around it)."""
    stops: int = 33
    """How many evenly spaced stops to print."""
    samples: int = 300_000


def resample_equal_steps(table: np.ndarray, count: int) -> np.ndarray:
    """`count` points evenly spaced along the polyline `table` [K, 3]."""
    steps = np.linalg.norm(np.diff(table, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(steps)])
    at = np.linspace(0.0, arc[-1], count)
    return np.stack([np.interp(at, arc, table[:, c]) for c in range(3)], axis=1)


def fit(pixels: np.ndarray, table: np.ndarray, rounds: int, smoothing: float) -> np.ndarray:
    for _ in range(rounds):
        _, nearest = cKDTree(table).query(pixels)
        counts = np.bincount(nearest, minlength=len(table))
        sums = np.stack([np.bincount(nearest, pixels[:, c], minlength=len(table)) for c in range(3)], axis=1)
        enough = counts >= 20
        table = table.copy()
        table[enough] = sums[enough] / counts[enough, None]
        table = gaussian_filter1d(table, sigma=smoothing, axis=0, mode="nearest")
        table = resample_equal_steps(table, len(table))
    return table


def main(args: FitPaletteArgs) -> np.ndarray:
    rng = np.random.default_rng(0)
    pixels = np.concatenate([cv2.imread(str(p), cv2.IMREAD_COLOR)[..., ::-1].reshape(-1, 3) for p in args.frames])
    pixels = pixels[rng.choice(len(pixels), min(args.samples, len(pixels)), replace=False)].astype(np.float64)
    start = palette_rgb(args.start).astype(np.float64)
    table = fit(pixels, start, args.rounds, args.smoothing)
    for name, t in (("start", start), ("fitted", table)):
        d, _ = cKDTree(t).query(pixels)
        print(f"{name}: distance median {np.median(d):.1f}, p90 {np.percentile(d, 90):.1f}")
    stops = resample_equal_steps(table, args.stops)
    print("stops (position, RGB):")
    for i, rgb in enumerate(stops):
        print(f"    ({i / (args.stops - 1):.4f}, ({', '.join(str(int(round(v))) for v in np.clip(rgb, 0, 255))})),")
    return table


if __name__ == "__main__":
    main(tyro.cli(FitPaletteArgs))
