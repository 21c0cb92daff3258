"""`python -m experiments.camera_pattern`: the pattern a capture's camera adds to every frame, without
a model: each frame standardised (its own mean and standard deviation), then averaged over the
capture, whose moving content averages out while what is fixed to the sensor stays. Reported as the
mean standardised value in rings of the normalised radius (0 at the centre, 1 at the middle of the
long edge), over the whole capture and over its two halves apart (a pattern of the camera is the same
in both; one of the scene is not). Consecutive frames overlap, so the content does not fully average
out: also reported are the share of the average frame's variance a radial polynomial (1, r^2, r^4)
explains, and the correlation of the two halves' average frames (pixel by pixel). `--training-space`:
each frame first mapped through its LUT of the full method's preprocessing (every frame a training
frame), where the model fits the camera's fall-off. Writes `camera_pattern.json` and `camera_pattern.md`.

    python -m experiments.camera_pattern --scenes ../shared/data/flight2 ../shared/data/dunr \
        --cache-dir .data/cache --output-dir docs/results/camera_falloff
"""

from __future__ import annotations

import json
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import numpy as np
import tyro

from experiments import full_method_luts, read_capture, write_report
from thermal_wild_ns.data.thermal_io import read_raw_frame
from thermal_wild_ns.preprocessing.photometric import apply_lut

RINGS = 8


@dataclass
class PatternArgs:
    scenes: Tuple[Path, ...] = ()
    """Dataset folders (any layout the plugin reads); their frames in capture order."""
    training_space: bool = False
    """Each frame through its preprocessing LUT first (the full method's preprocessing, forced on)."""
    cache_dir: Optional[Path] = None
    """The triangulation cache of the datasets (a layout without poses triangulates; default: under
    `output_dir`); the preprocessing's goes to a temporary folder."""
    output_dir: Path = Path("outputs/camera_pattern")


def average_standardised(frames: np.ndarray) -> np.ndarray:
    """The mean [H, W] of `frames` [F, H, W], each standardised by its own mean and standard deviation."""
    mean = frames.mean(axis=(1, 2), keepdims=True)
    std = frames.std(axis=(1, 2), keepdims=True)
    return ((frames - mean) / np.maximum(std, 1e-12)).mean(axis=0)


def normalised_radius(height: int, width: int) -> np.ndarray:
    """[H, W] distance of each pixel centre from the image centre, 1 at the middle of the long edge."""
    v, u = np.meshgrid(np.arange(height) + 0.5, np.arange(width) + 0.5, indexing="ij")
    return np.hypot(u - width / 2, v - height / 2) / (max(width, height) / 2)


def ring_means(frames: np.ndarray, rings: int = RINGS) -> Tuple[List[float], np.ndarray]:
    """`average_standardised(frames)` per ring of the normalised radius (rings of equal width out to
    the corners) [rings], with the rings' outer radii [rings]."""
    average = average_standardised(frames)  # [H, W]
    radius = normalised_radius(*average.shape)
    edges = np.linspace(0.0, radius.max() + 1e-9, rings + 1)
    values = [float(average[(radius >= a) & (radius < b)].mean()) for a, b in zip(edges[:-1], edges[1:])]
    return values, edges[1:]


def radial_share(frames: np.ndarray) -> float:
    """The share of `average_standardised(frames)`'s variance a least-squares polynomial in r^2
    (1, r^2, r^4) explains: how much of the fixed pattern a radial fall-off can model."""
    average = average_standardised(frames)
    r2 = normalised_radius(*average.shape) ** 2
    basis = np.stack([np.ones_like(r2), r2, r2**2], axis=-1).reshape(-1, 3)  # [P, 3]
    coefficients, *_ = np.linalg.lstsq(basis, average.reshape(-1), rcond=None)
    return float(1.0 - (average.reshape(-1) - basis @ coefficients).var() / average.var())


def capture_frames(scene: Path, cache_dir: Path, training_space: bool) -> np.ndarray:
    """[F, H, W] float64: the capture's frames in capture order, raw or through their preprocessing LUTs."""
    _, capture, rng = read_capture(scene, cache_dir)
    frames = np.stack([read_raw_frame(f.image, rng.palette).astype(np.float64) for f in capture.frames])
    if not training_space:
        return frames
    with tempfile.TemporaryDirectory() as work:  # the preprocessing's cache: not kept
        sequence = full_method_luts(capture, rng, work, [True] * len(frames))
        return np.stack(
            [np.asarray(apply_lut(sequence.luts[t], raw, sequence.grid), np.float64) for t, raw in enumerate(frames)]
        )


def pattern(scene: Path, cache_dir: Path, training_space: bool) -> Dict:
    frames = capture_frames(scene, cache_dir, training_space)  # [F, H, W]
    half = len(frames) // 2
    whole, edges = ring_means(frames)
    first, _ = ring_means(frames[:half])
    second, _ = ring_means(frames[half:])
    return {
        "scene": str(scene),
        "space": "training (preprocessed)" if training_space else "raw",
        "frames": len(frames),
        "ring_outer_radius": [round(float(e), 3) for e in edges],
        "whole": whole,
        "first_half": first,
        "second_half": second,
        "radial_share": round(radial_share(frames), 3),
        "halves_correlation": round(
            float(
                np.corrcoef(average_standardised(frames[:half]).ravel(), average_standardised(frames[half:]).ravel())[
                    0, 1
                ]
            ),
            3,
        ),
        # centre ring minus the outermost (corner) ring, in frame standard deviations
        "centre_minus_corner": {
            k: round(v[0] - v[-1], 3) for k, v in (("whole", whole), ("first_half", first), ("second_half", second))
        },
    }


def markdown(results: List[Dict]) -> str:
    lines = ["# Each capture's fixed pattern: mean standardised frame per ring of the radius", ""]
    for r in results:
        lines += [
            f"## {r['scene']} ({r['frames']} frames, {r['space']})",
            "",
            "| ring (outer radius) | " + " | ".join(f"{e:.2f}" for e in r["ring_outer_radius"]) + " |",
            "| --- " * (len(r["ring_outer_radius"]) + 1) + "|",
        ]
        for key in ("whole", "first_half", "second_half"):
            lines.append(f"| {key.replace('_', ' ')} | " + " | ".join(f"{v:+.3f}" for v in r[key]) + " |")
        c = r["centre_minus_corner"]
        lines += [
            "",
            f"Centre minus corner: {c['whole']:+.2f} frame standard deviations (halves {c['first_half']:+.2f}, "
            f"{c['second_half']:+.2f}). A radial polynomial explains {r['radial_share']:.0%} of the average frame's "
            f"variance; the two halves' average frames correlate at {r['halves_correlation']:.2f} pixel by pixel.",
            "",
        ]
    return "\n".join(lines)


def main(args: PatternArgs) -> List[Dict]:
    cache_dir = args.cache_dir or args.output_dir / "cache"
    results = [pattern(Path(s), cache_dir, args.training_space) for s in args.scenes]
    args.output_dir.mkdir(parents=True, exist_ok=True)
    (args.output_dir / "camera_pattern.json").write_text(json.dumps(results, indent=1))
    write_report(args.output_dir / "camera_pattern.md", markdown(results))
    return results


if __name__ == "__main__":
    main(tyro.cli(PatternArgs))
