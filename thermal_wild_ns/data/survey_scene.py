"""A synthetic drone survey of any size: the demo's sensor (drift, jitter, vignetting, noise) flown
over a flat site in a serpentine nadir pattern, the site growing with the number of frames.

What it is for: measuring how time and memory grow with a survey (frames, pixels, Gaussians) and
training one scene across GPUs, on a capture whose size is a parameter (`experiments/survey_cost.py`).
The site is a plane (z = 0) textured with fields, roads, warm roofs with hot vents and the demo's
paving, so every frame differs from its neighbours and a held-out frame has content to score.

Each frame is rendered and written by a pool of processes (its noise drawn from (seed, frame)): a
survey of thousands of frames uses every core. The layout and the published-when-complete folder are
the demo scene's (`demo_scene.write_transforms`); held-out truth frames are written, depth
maps are not (a plane's depth is the altitude).
"""

from __future__ import annotations

import json
import math
import os
import shutil
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Tuple

import cv2
import numpy as np

from thermal_wild_ns.data.demo_scene import (
    COUNTS_AT_0C,
    COUNTS_PER_C,
    COUNTS_RANGE,
    _ground_temp,
    _write_points_ply,
    drift,
    scene_key,
    write_transforms,
)
from thermal_wild_ns.data.thermal_io import make_work_folder
from thermal_wild_ns.progress import track


@dataclass(frozen=True)
class SurveySceneConfig:
    num_frames: int = 250
    width: int = 640
    height: int = 512
    focal: float = 1130.0
    """Pixels (a 13 mm lens on a 640x512, 17 um microbolometer, as on DJI's Zenmuse XT)."""
    altitude: float = 40.0
    """Metres above the site."""
    forward_overlap: float = 0.8
    side_overlap: float = 0.7
    eval_every: int = 8
    drift_counts: float = 120.0
    """Offset drift over the whole flight, in counts (the demo's sensor model)."""
    drift_gain: float = 0.06
    jitter_counts: float = 6.0
    jitter_gain: float = 0.01
    vignetting: float = 0.15
    noise_counts: float = 2.0
    points_per_frame: int = 40
    """Seed points (the SfM stand-in) drawn per training frame."""
    seed: int = 0

    @property
    def layout(self) -> Tuple[int, int, float, float]:
        """Rows, frames per row, and the along-row and between-row spacing (metres) of the flight."""
        footprint_w = self.width / self.focal * self.altitude  # across the row
        footprint_h = self.height / self.focal * self.altitude  # along the row
        along = footprint_h * (1.0 - self.forward_overlap)
        across = footprint_w * (1.0 - self.side_overlap)
        rows = max(1, round(math.sqrt(self.num_frames * along / across)))
        return rows, math.ceil(self.num_frames / rows), along, across

    @property
    def site_size(self) -> Tuple[float, float]:
        """The flown area's extent (metres, x then y), footprints included."""
        rows, per_row, along, across = self.layout
        footprint_w = self.width / self.focal * self.altitude
        footprint_h = self.height / self.focal * self.altitude
        return (rows - 1) * across + footprint_w, (per_row - 1) * along + footprint_h


def _hash(ix: np.ndarray, iy: np.ndarray, salt: float) -> np.ndarray:
    """A deterministic value in [0, 1) per integer cell."""
    return np.modf(np.abs(np.sin(ix * 127.1 + iy * 311.7 + salt) * 43758.5453))[0]


def site_temperature(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Surface temperature (degC) of the site at (x, y) metres."""
    cell = 25.0
    ix, iy = np.floor(x / cell), np.floor(y / cell)
    temp = 6.0 + 5.0 * _hash(ix, iy, 0.0) + 0.5 * (_ground_temp(x, y) - 9.0)  # fields, paving
    road = np.minimum(np.abs(np.mod(x, 60.0) - 30.0), np.abs(np.mod(y, 75.0) - 37.5)) < 2.5
    temp = np.where(road, 13.0, temp)
    fx, fy = x / cell - ix, y / cell - iy  # position inside the cell, [0, 1)
    half = 0.2 + 0.15 * _hash(ix, iy, 1.0)
    roof = (_hash(ix, iy, 2.0) > 0.55) & (np.abs(fx - 0.5) < half) & (np.abs(fy - 0.5) < half * 0.8)
    temp = np.where(roof, 17.0 + 6.0 * _hash(ix, iy, 3.0) + 0.8 * np.sin(9.0 * fx), temp)
    vent = roof & (np.hypot(fx - 0.5 - 0.3 * half, fy - 0.5) < 0.03)
    return np.where(vent, 38.0, temp)


def camera_to_world(index: int, cfg: SurveySceneConfig) -> np.ndarray:
    """OpenGL-convention camera-to-world 4x4 of frame `index`: nadir, serpentine rows along y, a few
    degrees of roll and pitch as a drone's gimbal leaves them."""
    rows, per_row, along, across = cfg.layout
    row, k = divmod(index, per_row)
    if row % 2:
        k = per_row - 1 - k
    rng = np.random.default_rng([cfg.seed, 7, index])
    tilt = np.deg2rad(rng.uniform(-3.0, 3.0, 2))
    eye = np.array([row * across, k * along, cfg.altitude + rng.uniform(-0.5, 0.5)])
    # looking down: camera back (+z) is world up, camera up (+y) along the row (flipped on return rows)
    heading = 1.0 if row % 2 == 0 else -1.0
    rot = np.array([[heading, 0.0, 0.0], [0.0, heading, 0.0], [0.0, 0.0, 1.0]])
    cx, sx, cy, sy = np.cos(tilt[0]), np.sin(tilt[0]), np.cos(tilt[1]), np.sin(tilt[1])
    rot = rot @ np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]]) @ np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    c2w = np.eye(4)
    c2w[:3, :3], c2w[:3, 3] = rot, eye
    return c2w


def _rays(c2w: np.ndarray, cfg: SurveySceneConfig, u: np.ndarray, v: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Ground points [..., 3] and temperatures [...] under pixel positions (u, v)."""
    d_cam = np.stack([(u - cfg.width / 2) / cfg.focal, -(v - cfg.height / 2) / cfg.focal, -np.ones_like(u)], -1)
    dirs = d_cam @ c2w[:3, :3].T
    t = -c2w[2, 3] / dirs[..., 2]
    points = c2w[:3, 3] + t[..., None] * dirs
    return points, site_temperature(points[..., 0], points[..., 1])


def _write_frame(args) -> Tuple[int, list]:
    """Render, fault and write frame `i` (a pool worker); returns its seed points."""
    i, cfg, folder, gain, offset = args
    c2w = camera_to_world(i, cfg)
    v, u = np.meshgrid(np.arange(cfg.height) + 0.5, np.arange(cfg.width) + 0.5, indexing="ij")
    _, temp = _rays(c2w, cfg, u, v)
    clean = COUNTS_AT_0C + COUNTS_PER_C * temp
    r2 = ((u - cfg.width / 2) ** 2 + (v - cfg.height / 2) ** 2) / ((cfg.width / 2) ** 2 + (cfg.height / 2) ** 2)
    rng = np.random.default_rng([cfg.seed, 1, i])
    signal = (clean - COUNTS_AT_0C) * (1.0 - cfg.vignetting * r2)
    observed = COUNTS_AT_0C + offset + gain * signal + cfg.noise_counts * rng.standard_normal(clean.shape)
    name = f"frame_{i:05d}.png"
    cv2.imwrite(str(folder / "images" / name), np.clip(np.round(observed), 0, 65535).astype(np.uint16))
    cv2.imwrite(str(folder / "ground_truth" / name), np.clip(np.round(clean), 0, 65535).astype(np.uint16))
    points: list = []
    if i % cfg.eval_every != 0:  # SfM-like points only from training views
        n = cfg.points_per_frame
        pts, t = _rays(c2w, cfg, rng.uniform(0, cfg.width, n), rng.uniform(0, cfg.height, n))
        pts = pts + 0.05 * rng.standard_normal(pts.shape)
        points = np.concatenate([pts, (COUNTS_AT_0C + COUNTS_PER_C * t)[:, None]], -1).tolist()
    return i, points


def generate_survey_scene(out_dir: Path, cfg: SurveySceneConfig = SurveySceneConfig(), workers: int = 0) -> Path:
    """Write the survey to `out_dir` (the demo's transforms.json layout); reuse it if up to date.
    Built in a temporary folder and moved into place at the end. `workers`: processes (0: every core)."""
    out_dir = Path(out_dir)
    key = scene_key(cfg)
    meta_path = out_dir / "transforms.json"
    if meta_path.exists():
        with open(meta_path) as f:
            if json.load(f).get("thermal_demo", {}).get("key") == key:
                return out_dir
    gain, offset = drift(cfg, np.random.default_rng(cfg.seed))
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = make_work_folder(out_dir.parent, ".survey-")
    (tmp / "images").mkdir()
    (tmp / "ground_truth").mkdir()
    jobs = [(i, cfg, tmp, gain[i], offset[i]) for i in range(cfg.num_frames)]
    points: list = [None] * cfg.num_frames
    with ProcessPoolExecutor(max_workers=workers or os.cpu_count()) as pool:
        results = pool.map(_write_frame, jobs, chunksize=8)
        for i, pts in track(results, "survey frames", total=cfg.num_frames):
            points[i] = pts
    frames = [
        {
            "file_path": f"images/frame_{i:05d}.png",
            "gt_file_path": f"ground_truth/frame_{i:05d}.png",
            "transform_matrix": camera_to_world(i, cfg).tolist(),
        }
        for i in range(cfg.num_frames)
    ]
    _write_points_ply(tmp / "sparse_pc.ply", np.array([p for pts in points for p in pts], dtype=np.float64))
    extra = {"key": key, "config": asdict(cfg), "faults": {"gain": gain.tolist(), "offset": offset.tolist()}}
    write_transforms(tmp, cfg, frames, [], extra)
    if out_dir.exists():
        shutil.rmtree(out_dir)
    tmp.rename(out_dir)
    return out_dir


__all__ = ["SurveySceneConfig", "generate_survey_scene", "site_temperature", "COUNTS_RANGE"]
