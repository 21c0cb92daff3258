"""The embedded default scene: a small procedural thermal capture with known truth.

A courtyard at night, seen by a cheap microbolometer: cool textured ground, a facade with warm
windows, three warm bodies (people-sized spheres) and a cold sky. Rendered by analytic ray
casting from cameras on an arc, with the sensor faults the paper describes applied to the
frames a user would get:
- low dynamic range: the scene spans ~800 of 65,536 counts;
- slow drift (offset and gain ramps) plus frame-to-frame gain/offset jitter;
- vignetting (radial fall-off of the signal);
- temporal noise and fixed-pattern column noise.
Clean frames (no faults) of the same views are written as ground truth for evaluation; sparse
surface points with their temperatures stand in for an SfM point cloud; the true depth of every
view (`depth/*.npy`, camera z) is kept for floater measures.

Everything is deterministic for a given `DemoSceneConfig`; no download.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Dict, List, Tuple

import cv2
import numpy as np
from plyfile import PlyData, PlyElement

from thermal_wild_ns.data.thermal_io import make_work_folder
from thermal_wild_ns.errors import InputError

GENERATOR_VERSION = (
    3  # bump when an unchanged config would give different frames (3: outlier gain on the normalised scale)
)


@dataclass(frozen=True)
class DemoSceneConfig:
    num_frames: int = 40
    width: int = 128
    height: int = 96
    focal: float = 110.0
    eval_every: int = 8
    """Every n-th frame (by capture order, starting at 0) is held out for evaluation."""
    drift_counts: float = 60.0
    """Offset drift over the whole sequence (sensor warm-up), in counts."""
    drift_gain: float = 0.04
    """Relative gain drift over the whole sequence."""
    jitter_counts: float = 6.0
    jitter_gain: float = 0.01
    vignetting: float = 0.15
    """Relative signal loss at the image corners."""
    noise_counts: float = 2.0
    column_noise_counts: float = 2.0
    num_points: int = 3000
    seed: int = 0
    # stress faults (off in the demo scene; see STRESS_FAULTS)
    outlier_frame: int = -1
    """Index of a frame recorded `outlier_gain` times brighter (-1: none): its values above the
    recording range's low end are scaled, so its mean in the dataset-normalised scale (what the
    model sees; an 8-bit AGC frame's levels) is that much higher while its content stays in range."""
    outlier_gain: float = 1.3
    ffc_period: int = 0
    """Flat-field-correction sawtooth: the offset climbs `ffc_step_counts` per frame and drops back
    every `ffc_period` frames (0: off). DUNR's facade climbs ~15 counts per frame for ~18 frames."""
    ffc_step_counts: float = 15.0
    row_noise_counts: float = 0.0
    """Fixed-pattern noise per sensor row (column noise: `column_noise_counts`)."""
    contrast: float = 1.0
    """Scale of temperature differences about 12 degC (low texture / low contrast below 1)."""
    look_up: float = 0.0
    """Raise the cameras' aim (metres at the target): more of every frame is uniform sky."""
    view_falloff: float = 0.0
    """View-dependent radiance (0: none): a surface's emissivity falls with the angle from its normal,
    1 - view_falloff * (1 - cos)^2, and the sky it reflects makes up the rest, as on a real survey."""
    path_views: int = 0
    """Clean views (with depth) on the smooth camera path through the capture, for flicker and floater measures."""


# Sensor model: counts = COUNTS_AT_0C + COUNTS_PER_C * temperature (degC).
COUNTS_AT_0C = 3000.0
COUNTS_PER_C = 20.0
CELSIUS_RANGE = (-10.0, 40.0)  # the recording range declared in transforms.json
COUNTS_RANGE = tuple(COUNTS_AT_0C + COUNTS_PER_C * c for c in CELSIUS_RANGE)

# Scene (world frame: z up, metres).
WALL_Y = 3.0  # facade plane y = WALL_Y, facing -y, x in [-4, 4], z in [0, 4]
SPHERES = ((-1.2, 0.6, 0.45, 34.0), (0.3, -0.4, 0.4, 31.0), (1.6, 1.0, 0.5, 28.0))  # x, y, r, degC (centre z = r)


def _ground_temp(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    tiles = 0.8 * np.sign(np.sin(2.2 * x) * np.sin(2.2 * y))  # paving
    patches = 1.5 * np.sin(0.7 * x + 0.3) * np.cos(0.5 * y)  # damp/dry patches
    return 9.0 + tiles + patches


def _wall_temp(x: np.ndarray, z: np.ndarray) -> np.ndarray:
    t = 14.0 + 0.4 * z
    for wx in (-2.6, -0.9, 0.9, 2.6):
        for wz in (1.2, 2.9):
            inside = (np.abs(x - wx) < 0.45) & (np.abs(z - wz) < 0.55)
            t = np.where(inside, 21.0 + 0.5 * np.cos(3 * (x - wx)), t)
    return t


def _sky_temp(d: np.ndarray) -> np.ndarray:
    return -6.0 + 8.0 * (1.0 - np.clip(d[..., 2], 0.0, 1.0)) ** 2  # colder towards the zenith


def cast_rays(
    origins: np.ndarray, dirs: np.ndarray, view_falloff: float = 0.0
) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Temperature (degC), hit distance (inf for sky) and hit points for rays [..., 3]; with
    `view_falloff`, the apparent temperature of surfaces seen at an angle (`DemoSceneConfig`)."""
    t_best = np.full(dirs.shape[:-1], np.inf)
    normals = np.zeros(dirs.shape)  # [..., 3], the surface normal at each hit (zero for sky)
    temp = _sky_temp(dirs)
    # ground z = 0
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -origins[..., 2] / dirs[..., 2]
    p = origins + t[..., None] * dirs
    hit = (t > 0) & (t < t_best)
    temp = np.where(hit, _ground_temp(p[..., 0], p[..., 1]), temp)
    t_best = np.where(hit, t, t_best)
    normals = np.where(hit[..., None], np.array([0.0, 0.0, 1.0]), normals)
    # facade y = WALL_Y
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (WALL_Y - origins[..., 1]) / dirs[..., 1]
    p = origins + t[..., None] * dirs
    hit = (t > 0) & (t < t_best) & (np.abs(p[..., 0]) < 4.0) & (p[..., 2] > 0) & (p[..., 2] < 4.0)
    temp = np.where(hit, _wall_temp(p[..., 0], p[..., 2]), temp)
    t_best = np.where(hit, t, t_best)
    normals = np.where(hit[..., None], np.array([0.0, -1.0, 0.0]), normals)
    # warm bodies
    for sx, sy, r, deg in SPHERES:
        oc = origins - np.array([sx, sy, r])
        b = np.sum(oc * dirs, -1)
        disc = b**2 - (np.sum(oc * oc, -1) - r * r)
        with np.errstate(invalid="ignore"):
            t = -b - np.sqrt(disc)
        hit = (disc > 0) & (t > 0) & (t < t_best)
        p = origins + t[..., None] * dirs
        shade = deg - 3.0 * (p[..., 2] / (2 * r))  # cooler head-to-feet gradient
        temp = np.where(hit, shade, temp)
        t_best = np.where(hit, t, t_best)
        normals = np.where(hit[..., None], (p - np.array([sx, sy, r])) / r, normals)
    if view_falloff > 0:
        cos = np.abs(np.sum(dirs * normals, -1))  # [...], 0 for sky
        emissivity = np.where(np.isfinite(t_best), 1.0 - view_falloff * (1.0 - cos) ** 2, 1.0)
        reflected = dirs - 2.0 * np.sum(dirs * normals, -1, keepdims=True) * normals
        temp = emissivity * temp + (1.0 - emissivity) * _sky_temp(reflected)
    points = origins + np.where(np.isfinite(t_best), t_best, 0.0)[..., None] * dirs
    return temp, t_best, points


def camera_to_world(index: float, cfg: DemoSceneConfig) -> np.ndarray:
    """OpenGL-convention (nerfstudio) camera-to-world 4x4 on an arc in front of the facade;
    fractional indices lie on the same smooth path between frames."""
    s = index / max(cfg.num_frames - 1, 1)
    angle = np.deg2rad(-55.0 + 110.0 * s)
    eye = np.array([6.0 * np.sin(angle), -6.0 * np.cos(angle) + 0.5, 1.6 + 0.3 * np.sin(2 * np.pi * s)])
    target = np.array([0.0, 0.8, 0.9 + cfg.look_up])
    back = eye - target
    back /= np.linalg.norm(back)
    right = np.cross(np.array([0.0, 0.0, 1.0]), back)
    right /= np.linalg.norm(right)
    up = np.cross(back, right)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, up, back, eye
    return c2w


def render_view(c2w: np.ndarray, cfg: DemoSceneConfig, supersample: int = 2) -> Tuple[np.ndarray, np.ndarray]:
    """Clean temperature image (degC) [H, W] and depth along the optical axis [H, W] (inf = sky)."""
    s = supersample
    v, u = np.meshgrid((np.arange(cfg.height * s) + 0.5) / s, (np.arange(cfg.width * s) + 0.5) / s, indexing="ij")
    d_cam = np.stack([(u - cfg.width / 2) / cfg.focal, -(v - cfg.height / 2) / cfg.focal, -np.ones_like(u)], -1)
    dirs = d_cam @ c2w[:3, :3].T
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    temp, dist, _ = cast_rays(np.broadcast_to(c2w[:3, 3], dirs.shape), dirs, cfg.view_falloff)
    temp = temp.reshape(cfg.height, s, cfg.width, s).mean(axis=(1, 3))
    z = dist / np.linalg.norm(d_cam, axis=-1)
    depth = z.reshape(cfg.height, s, cfg.width, s).min(axis=(1, 3))
    return temp, depth


def drift(cfg, rng: np.random.Generator) -> Tuple[np.ndarray, np.ndarray]:
    """Per-frame gain and offset (counts) of a scene config with `num_frames`, `drift_gain`,
    `drift_counts`, `jitter_gain` and `jitter_counts`: a ramp over the capture plus frame-to-frame jitter."""
    s = np.linspace(0.0, 1.0, cfg.num_frames)
    gain = 1.0 + cfg.drift_gain * s + cfg.jitter_gain * rng.standard_normal(cfg.num_frames)
    offset = cfg.drift_counts * s + cfg.jitter_counts * rng.standard_normal(cfg.num_frames)
    return gain, offset


def sensor_faults(cfg: DemoSceneConfig) -> Dict[str, np.ndarray]:
    """Per-frame gain/offset and the fixed patterns (vignetting, column noise) of the sensor."""
    rng = np.random.default_rng(cfg.seed)
    gain, offset = drift(cfg, rng)
    v, u = np.meshgrid(np.arange(cfg.height) + 0.5, np.arange(cfg.width) + 0.5, indexing="ij")
    r2 = ((u - cfg.width / 2) ** 2 + (v - cfg.height / 2) ** 2) / ((cfg.width / 2) ** 2 + (cfg.height / 2) ** 2)
    frames = np.arange(cfg.num_frames)
    sawtooth = cfg.ffc_step_counts * (frames % cfg.ffc_period) if cfg.ffc_period > 0 else np.zeros(cfg.num_frames)
    return {
        "gain": gain,
        "offset": offset + sawtooth,
        "vignetting": 1.0 - cfg.vignetting * r2,
        "columns": cfg.column_noise_counts * rng.standard_normal(cfg.width)[None, :]
        + cfg.row_noise_counts * rng.standard_normal(cfg.height)[:, None],
        "outlier": np.where(frames == cfg.outlier_frame, cfg.outlier_gain, 1.0),
    }


def sensor_counts(
    clean: np.ndarray, faults: Dict[str, np.ndarray], gain: float, offset: float, outlier: float, noise=0.0
) -> np.ndarray:
    """The counts [H, W] the sensor records for the scene's `clean` counts under one frame's state (`gain`,
    `offset`, `outlier` factor) and `faults`' fixed patterns, `noise` (counts) added before the outlier gain."""
    signal = (clean - COUNTS_AT_0C) * faults["vignetting"]
    observed = COUNTS_AT_0C + offset + gain * signal + faults["columns"]
    observed = observed + noise
    # the outlier gain acts on the normalised scale, not on raw counts: x1.3 on counts of ~3,250
    # would put the whole frame ~90 degC above the range, a saturated frame rather than a bright one
    if outlier != 1.0:  # every other frame stays bit for bit as before
        observed = COUNTS_RANGE[0] + outlier * (observed - COUNTS_RANGE[0])
    return observed


STRESS_FAULTS: Dict[str, Dict] = {
    "clean": {},
    "outlier": {"outlier_frame": 13},
    "drift": {"drift_counts": 200.0, "drift_gain": 0.1, "jitter_counts": 15.0, "jitter_gain": 0.02},
    "ffc": {"ffc_period": 18, "ffc_step_counts": 15.0},
    "vignetting": {"vignetting": 0.35},
    "fixed-pattern": {"column_noise_counts": 6.0, "row_noise_counts": 6.0},
    "low-contrast": {"contrast": 0.15},
    "sky": {"look_up": 2.5},
    "view": {"view_falloff": 0.5},
}
"""The stress scenes: the demo's content with one fault at a time (and "all" of them together).
"clean" has no fault at all, not even sensor noise: the reference the others are compared with."""
_NO_FAULTS = dict(
    drift_counts=0.0,
    drift_gain=0.0,
    jitter_counts=0.0,
    jitter_gain=0.0,
    vignetting=0.0,
    noise_counts=0.0,
    column_noise_counts=0.0,
)


def stress_scene_config(fault: str, path_views: int = 60) -> DemoSceneConfig:
    """The demo scene with exactly this fault ('all': every fault), plus smooth-path views."""
    if fault == "all":
        changes = {k: v for preset in STRESS_FAULTS.values() for k, v in preset.items()}
    elif fault in STRESS_FAULTS:
        changes = STRESS_FAULTS[fault]
    else:
        raise InputError(f"unknown stress fault '{fault}' (one of {', '.join([*STRESS_FAULTS, 'all'])})")
    return DemoSceneConfig(**{**_NO_FAULTS, **changes, "path_views": path_views})


def scene_key(cfg: DemoSceneConfig) -> str:
    payload = json.dumps({"version": GENERATOR_VERSION, **asdict(cfg)}, sort_keys=True)
    return hashlib.sha256(payload.encode()).hexdigest()[:16]


def generate_demo_scene(out_dir: Path, cfg: DemoSceneConfig = DemoSceneConfig()) -> Path:
    """Write the scene to `out_dir` (nerfstudio transforms.json layout); reuse it if up to date.

    Written into a temporary folder and moved into place at the end, so an interrupted run
    never leaves a half-written scene behind.
    """
    out_dir = Path(out_dir)
    key = scene_key(cfg)
    meta_path = out_dir / "transforms.json"
    if meta_path.exists():
        with open(meta_path) as f:
            if json.load(f).get("thermal_demo", {}).get("key") == key:
                return out_dir
    rng = np.random.default_rng(cfg.seed + 1)
    faults = sensor_faults(cfg)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = make_work_folder(out_dir.parent, ".demo-")
    (tmp / "images").mkdir()
    (tmp / "ground_truth").mkdir()
    (tmp / "depth").mkdir()
    frames, point_sets = [], []
    for i in range(cfg.num_frames):
        c2w = camera_to_world(i, cfg)
        clean, depth = clean_counts(c2w, cfg)
        noise = cfg.noise_counts * rng.standard_normal(clean.shape)
        observed = sensor_counts(clean, faults, faults["gain"][i], faults["offset"][i], faults["outlier"][i], noise)
        name = f"frame_{i:05d}.png"
        cv2.imwrite(str(tmp / "images" / name), np.clip(np.round(observed), 0, 65535).astype(np.uint16))
        cv2.imwrite(str(tmp / "ground_truth" / name), np.clip(np.round(clean), 0, 65535).astype(np.uint16))
        np.save(tmp / "depth" / f"frame_{i:05d}.npy", depth.astype(np.float32))
        frames.append(
            {
                "file_path": f"images/{name}",
                "gt_file_path": f"ground_truth/{name}",
                "depth_npy_path": f"depth/frame_{i:05d}.npy",
                "transform_matrix": c2w.tolist(),
            }
        )
        if i % cfg.eval_every != 0:  # SfM-like points only from training views
            point_sets.append(_surface_points(c2w, cfg, rng, cfg.num_points // cfg.num_frames + 1))
    path = []
    if cfg.path_views > 0:
        (tmp / "path").mkdir()
        for k, index in enumerate(np.linspace(0, cfg.num_frames - 1, cfg.path_views)):
            c2w = camera_to_world(index, cfg)
            clean, depth = clean_counts(c2w, cfg)
            cv2.imwrite(str(tmp / "path" / f"path_{k:05d}.png"), np.clip(np.round(clean), 0, 65535).astype(np.uint16))
            np.save(tmp / "path" / f"path_{k:05d}_depth.npy", depth.astype(np.float32))
            path.append(
                {
                    "file_path": f"path/path_{k:05d}.png",
                    "depth_npy_path": f"path/path_{k:05d}_depth.npy",
                    "frame": float(index),
                    "transform_matrix": c2w.tolist(),
                }
            )
    points = np.concatenate(point_sets)[: cfg.num_points]
    _write_points_ply(tmp / "sparse_pc.ply", points)
    extra = {
        "key": key,
        "config": asdict(cfg),
        "faults": {k: np.asarray(v).tolist() for k, v in faults.items() if k in ("gain", "offset", "outlier")},
    }
    write_transforms(tmp, cfg, frames, path, extra)
    if out_dir.exists():
        shutil.rmtree(out_dir)
    tmp.rename(out_dir)
    return out_dir


def write_transforms(folder: Path, cfg, frames: List[Dict], path: List[Dict], generator: Dict) -> None:
    """`folder/transforms.json` of a generated scene (`cfg`: its width, height, focal, eval_every):
    the frames, the train/held-out split (every `eval_every`-th frame held out), the seed points file,
    the recording range, the smooth-path views, and what generated it (`thermal_demo`: key, config)."""
    names = [f["file_path"] for f in frames]
    meta = {
        "camera_model": "OPENCV",
        "fl_x": cfg.focal,
        "fl_y": cfg.focal,
        "cx": cfg.width / 2,
        "cy": cfg.height / 2,
        "w": cfg.width,
        "h": cfg.height,
        "frames": frames,
        "train_filenames": [n for i, n in enumerate(names) if i % cfg.eval_every != 0],
        "val_filenames": [n for i, n in enumerate(names) if i % cfg.eval_every == 0],
        "test_filenames": [n for i, n in enumerate(names) if i % cfg.eval_every == 0],
        "ply_file_path": "sparse_pc.ply",
        "thermal": {
            "celsius_low": CELSIUS_RANGE[0],
            "celsius_high": CELSIUS_RANGE[1],
            "low": COUNTS_RANGE[0],
            "high": COUNTS_RANGE[1],
            "dtype": "uint16",
        },
        "path": path,
        "thermal_demo": generator,
    }
    with open(folder / "transforms.json", "w") as f:
        json.dump(meta, f, indent=1)


def clean_counts(c2w: np.ndarray, cfg: DemoSceneConfig) -> Tuple[np.ndarray, np.ndarray]:
    """Fault-free counts [H, W] (contrast applied) and depth [H, W] of a view."""
    temp, depth = render_view(c2w, cfg)
    temp = 12.0 + cfg.contrast * (temp - 12.0)
    return COUNTS_AT_0C + COUNTS_PER_C * temp, depth


def _surface_points(c2w: np.ndarray, cfg: DemoSceneConfig, rng: np.random.Generator, n: int) -> np.ndarray:
    """n noisy surface points seen by this camera: x, y, z, counts [n, 4] (SfM stand-in)."""
    u = rng.uniform(0, cfg.width, n)
    v = rng.uniform(0, cfg.height, n)
    d_cam = np.stack([(u - cfg.width / 2) / cfg.focal, -(v - cfg.height / 2) / cfg.focal, -np.ones(n)], -1)
    dirs = d_cam @ c2w[:3, :3].T
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    temp, dist, pts = cast_rays(np.broadcast_to(c2w[:3, 3], dirs.shape), dirs, cfg.view_falloff)
    temp = 12.0 + cfg.contrast * (temp - 12.0)
    keep = np.isfinite(dist)
    pts = pts[keep] + 0.02 * rng.standard_normal((int(keep.sum()), 3))
    return np.concatenate([pts, (COUNTS_AT_0C + COUNTS_PER_C * temp[keep])[:, None]], -1)


def _write_points_ply(path: Path, points: np.ndarray) -> None:
    vertex = np.empty(len(points), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("thermal", "f4")])
    for i, name in enumerate(("x", "y", "z", "thermal")):
        vertex[name] = points[:, i]
    PlyData([PlyElement.describe(vertex, "vertex")]).write(str(path))
