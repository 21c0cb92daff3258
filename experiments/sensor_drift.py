"""How much a capture's sensor level changes from frame to frame, measured on the scene points that
several frames see rather than on whole frames (which captures preprocessing should steady).

The preprocessing rule reads whole frames (`frame_mean_spread`, `frame_contrast_spread`): on a survey
whose frames see different ground, their levels vary with what they see even where the sensor holds
still, and a sensor that drifts can hide behind content that changes the other way. Here each seed
point is projected into every training frame (as `thermal_wild_ns.data.content_motion` does; no
occlusion test) and the raw frame read there (the median of a 3x3 patch, dataset-normalised). The
points seen at least twice are fitted as value = scene[point] + offset[frame] (`frame_offsets`).
Printed: the spread of the frames' offsets (median absolute deviation scaled to a standard deviation),
their range, the step between consecutive frames, what is left of their spread once a linear function of
the camera's travel along its image axes is taken out (`along_image_axes`), and the rule's whole-frame
measures. A fixed linear
gradient across the sensor is part of these offsets wherever the camera translates (it cannot be told
from a level that changes along the way), so on a survey they bound the sensor's level changes from
above.

python -m experiments.sensor_drift --scenes ../shared/data/dunr ../shared/data/flight2 demo stress:clean \
    stress:drift stress:ffc --cache-dir .data/cache
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path
from typing import Tuple

import numpy as np
import torch

from experiments.scenes import scene_dataparser
from thermal_wild_ns.data.content_motion import pixel_positions
from thermal_wild_ns.data.thermal_io import read_raw_frame
from thermal_wild_ns.preprocessing.stage import frame_contrast_spread, frame_mean_spread, frame_quantiles

MAX_POINTS = 4096


def projected_samples(cameras, points: torch.Tensor, frames: list) -> np.ndarray:
    """[F, P] each point's raw value in each frame that sees it (NaN where it does not)."""
    u, v, depth = (t.numpy() for t in pixel_positions(cameras, points))  # [F, P], pixels
    samples = np.full(u.shape, np.nan)
    for f, frame in enumerate(frames):
        height, width = frame.shape
        seen = (depth[f] > 0) & (u[f] >= 1) & (u[f] < width - 1) & (v[f] >= 1) & (v[f] < height - 1)
        cols, rows = u[f][seen].astype(int), v[f][seen].astype(int)
        patches = np.stack([frame[rows + dy, cols + dx] for dy in (-1, 0, 1) for dx in (-1, 0, 1)])  # [9, S]
        samples[f, seen] = np.median(patches, axis=0)
    return samples


def frame_offsets(samples: np.ndarray, iterations: int = 200) -> Tuple[np.ndarray, np.ndarray]:
    """The frames' level offsets [F'] (their median 0), fitted to every point seen at least twice as
    value = scene[point] + offset[frame], least squares by alternating between the two; frames that
    share no point are tied through those in between. Also which frames [F'] had at least 20 such
    points (the others are left out). A fixed linear gradient across the sensor adds, for a camera
    that translates, exactly an offset proportional to the frame's position along the way: these
    offsets hold it, and no fit of the points alone can take it out (tests/test_preprocessing.py)."""
    samples = samples[:, np.isfinite(samples).sum(axis=0) >= 2]
    frames = np.flatnonzero(np.isfinite(samples).sum(axis=1) >= 20)
    samples = samples[frames]
    rows, cols = np.nonzero(np.isfinite(samples))  # one observation each
    values = samples[rows, cols]
    counts = np.bincount(cols, minlength=samples.shape[1])
    frame_counts = np.bincount(rows, minlength=len(frames))
    offsets = np.zeros(len(frames))
    for _ in range(iterations):
        scene = np.bincount(cols, values - offsets[rows], minlength=samples.shape[1]) / np.maximum(counts, 1)
        offsets = np.bincount(rows, values - scene[cols], minlength=len(frames)) / frame_counts
    return offsets - np.median(offsets), frames


def along_image_axes(offsets: np.ndarray, camera_to_worlds: np.ndarray) -> float:
    """The spread (`frame_mean_spread`: a robust standard deviation) of `offsets` [F'] left once a linear
    function of each camera's position along the mean image-right and image-down directions is taken
    out (`camera_to_worlds` [F', 3, 4], OpenGL axes): what a fixed gradient across the sensor (or, at a fixed heading, a
    radiance that changes with the view direction) cannot explain. On a survey flown at one heading,
    a sensor drift stays; on an orbit the image axes turn and the fit means little."""
    centres = camera_to_worlds[:, :, 3]  # [F', 3]
    right = camera_to_worlds[:, :, 0].mean(axis=0)
    down = -camera_to_worlds[:, :, 1].mean(axis=0)
    travel = centres - centres.mean(axis=0)
    design = np.stack([travel @ right / np.linalg.norm(right), travel @ down / np.linalg.norm(down)], axis=1)
    design = np.concatenate([design, np.ones((len(offsets), 1))], axis=1)  # [F', 3]
    residual = offsets - design @ np.linalg.lstsq(design, offsets, rcond=None)[0]
    return frame_mean_spread(residual)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", required=True, help="bench scenes (dataset folders, demo, stress:FAULT)")
    parser.add_argument("--cache-dir", type=Path, default=Path(".data/cache"))
    args = parser.parse_args()
    print(
        "| scene | frames tied by shared points | offset spread | offset range | step between consecutive "
        "frames, median (largest) | offset spread not along the image axes | whole frames: mean spread "
        "| whole frames: contrast spread |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    with tempfile.TemporaryDirectory() as work:
        for scene in args.scenes:
            dataparser = scene_dataparser(scene, Path(work), args.cache_dir.resolve()).setup()
            outputs = dataparser.get_dataparser_outputs("train")
            rng = dataparser.radiometric_range()
            frames = [
                np.asarray(rng.normalize(read_raw_frame(path, rng.palette)), dtype=np.float64)
                for path in outputs.image_filenames
            ]
            points = outputs.metadata.get("points3D_xyz")
            points = points[:: len(points) // MAX_POINTS + 1].float()
            offsets, tied = frame_offsets(projected_samples(outputs.cameras, points, frames))
            steps = np.abs(np.diff(offsets))  # between consecutive tied frames
            left = along_image_axes(offsets, outputs.cameras.camera_to_worlds.numpy()[tied])
            whole = (
                frame_mean_spread([frame.mean() for frame in frames]),
                frame_contrast_spread([frame_quantiles(frame) for frame in frames]),
            )
            cells = (
                f"{len(tied)} | {frame_mean_spread(offsets):.4f} | {offsets.max() - offsets.min():.4f} | "
                f"{np.median(steps):.4f} ({steps.max():.4f}) | {left:.4f}"
            )
            print(f"| {scene} | {cells} | {whole[0]:.4f} | {whole[1]:.3f} |", flush=True)


if __name__ == "__main__":
    main()
