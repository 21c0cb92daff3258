"""Sparse points for a thermal capture with KNOWN poses: SIFT (OpenCV) + pycolmap triangulation.

Thermal frames are low-contrast and 16-bit, so each frame is put on the dataset's radiometric
range (never per-frame) and locally equalized (CLAHE) before SIFT with a low contrast threshold.
Pairs are each frame's nearest cameras that look the same way; matches pass Lowe's ratio test
and the epipolar constraint of the known poses (Sampson distance). pycolmap then triangulates,
merges tracks and filters by reprojection error with the poses held fixed.

The result (points.npy, reprojection_errors.npy, report.json and the COLMAP model in sparse/,
which COLMAP's GUI opens) is cached in a folder
keyed by the frames, poses, intrinsics and parameters; it is written to a temporary folder and
renamed into place, so an interrupted run never leaves a half-written cache.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import time
from dataclasses import asdict, dataclass
from functools import lru_cache
from pathlib import Path
from typing import Dict, Sequence, Tuple

import cv2
import numpy as np
from nerfstudio.utils.rich_utils import CONSOLE

from thermal_wild_ns.data.capture import ThermalFrame
from thermal_wild_ns.data.thermal_io import (
    RadiometricRange,
    discard_cache_folder,
    file_fingerprint,
    load_npy,
    make_work_folder,
    publish_cache_folder,
)
from thermal_wild_ns.progress import track

CACHE_VERSION = 1


@dataclass(frozen=True)
class TriangulationConfig:
    max_features: int = 8000
    """SIFT features per frame at most."""
    contrast_threshold: float = 0.01
    """OpenCV SIFT contrast threshold (its default 0.04 finds ~200 features on a 640x512 thermal frame)."""
    clahe_clip: float = 2.0
    """CLAHE clip limit applied to the range-normalised 8-bit frame before SIFT."""
    neighbours: int = 10
    """Each frame is matched with this many nearest cameras."""
    max_view_angle_deg: float = 60.0
    """Only pairs whose viewing directions differ by less than this are matched."""
    ratio: float = 0.8
    """Lowe's ratio test."""
    max_epipolar_px: float = 4.0
    """Matches farther than this (Sampson distance, pixels) from the known epipolar geometry are dropped."""


def cache_key(frames: Sequence[ThermalFrame], radiometric_range: RadiometricRange, config: TriangulationConfig) -> str:
    h = hashlib.sha256()
    h.update(
        json.dumps(
            {"version": CACHE_VERSION, "config": asdict(config), "range": asdict(radiometric_range)}, sort_keys=True
        ).encode()
    )
    for f in frames:
        h.update(file_fingerprint(f.image))
        # rounded: the same poses read from COLMAP text and from transforms.json differ in the last bits
        h.update(
            np.round(np.asarray([*f.camera_to_world.reshape(-1), f.fx, f.fy, f.cx, f.cy, *f.distortion]), 6).tobytes()
        )
    return h.hexdigest()[:16]


def equalised_grey(normalised: np.ndarray, clahe: cv2.CLAHE) -> np.ndarray:
    """What SIFT sees of a thermal frame [H, W] on a 0..1 scale (one range for the whole capture,
    never per frame): 8-bit grey, locally equalised (CLAHE) [H, W] uint8."""
    return clahe.apply(np.clip(normalised * 255.0, 0, 255).astype(np.uint8))


def _feature_image(frame: ThermalFrame, radiometric_range: RadiometricRange, clahe: cv2.CLAHE) -> np.ndarray:
    return equalised_grey(radiometric_range.read(frame.image), clahe)


def prior_pairs(frames: Sequence[ThermalFrame], neighbours: int, max_view_angle_deg: float) -> list:
    """(i, j), i < j: each frame with its `neighbours` nearest cameras whose viewing directions
    differ by less than `max_view_angle_deg`, by the frames' (known or prior) poses."""
    centres = np.stack([f.camera_to_world[:3, 3] for f in frames])
    views = np.stack([f.camera_to_world[:3, 2] for f in frames])  # OpenCV z: viewing direction
    cos_max = np.cos(np.radians(max_view_angle_deg))
    pairs = set()
    for i in range(len(frames)):
        candidates = [j for j in range(len(frames)) if j != i and views[i] @ views[j] > cos_max]
        candidates.sort(key=lambda j: np.linalg.norm(centres[i] - centres[j]))
        pairs.update((min(i, j), max(i, j)) for j in candidates[:neighbours])
    return sorted(pairs)


def _fundamental(a: ThermalFrame, b: ThermalFrame) -> np.ndarray:
    """F with x_b^T F x_a = 0 for pixel coordinates of a and b."""
    rel = np.linalg.inv(b.camera_to_world) @ a.camera_to_world  # a's camera -> b's camera
    R, t = rel[:3, :3], rel[:3, 3]
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    return np.linalg.inv(b.intrinsics_matrix()).T @ (tx @ R) @ np.linalg.inv(a.intrinsics_matrix())


def _sampson(F: np.ndarray, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
    xa = np.concatenate([xa, np.ones((len(xa), 1))], 1)
    xb = np.concatenate([xb, np.ones((len(xb), 1))], 1)
    Fxa, Ftxb = xa @ F.T, xb @ F
    num = np.sum(xb * Fxa, axis=1) ** 2
    return np.sqrt(num / (Fxa[:, 0] ** 2 + Fxa[:, 1] ** 2 + Ftxb[:, 0] ** 2 + Ftxb[:, 1] ** 2 + 1e-12))


def colmap_camera(frame: ThermalFrame):
    """The frame's intrinsics and distortion as a pycolmap camera (OPENCV, or FULL_OPENCV with k3/k4)."""
    import pycolmap  # here, not at the top: the light GPU install has none (SfM runs where it is installed)

    k1, k2, k3, k4, p1, p2 = frame.distortion
    if k3 or k4:
        params = [frame.fx, frame.fy, frame.cx, frame.cy, k1, k2, p1, p2, k3, k4, 0.0, 0.0]
        return pycolmap.Camera(model="FULL_OPENCV", width=frame.width, height=frame.height, params=params)
    params = [frame.fx, frame.fy, frame.cx, frame.cy, k1, k2, p1, p2]
    return pycolmap.Camera(model="OPENCV", width=frame.width, height=frame.height, params=params)


def triangulate(
    frames: Sequence[ThermalFrame], radiometric_range: RadiometricRange, work_dir: Path, config: TriangulationConfig
) -> Tuple[np.ndarray, np.ndarray, Dict]:
    """Points [N, 3] (world), their mean reprojection errors [N] (px) and a report, written under work_dir."""
    import pycolmap  # here, not at the top: the light GPU install has none (SfM runs where it is installed)

    sift = cv2.SIFT_create(nfeatures=config.max_features, contrastThreshold=config.contrast_threshold)
    clahe = cv2.createCLAHE(clipLimit=config.clahe_clip, tileGridSize=(8, 8))
    keypoints = []
    # descriptors (128 float32 per keypoint) wait on disk, not in memory, so memory does not grow
    # with them as the frame count grows
    store = work_dir / "descriptors"
    store.mkdir()
    for i, frame in enumerate(track(frames, "SIFT on thermal frames")):
        kp, des = sift.detectAndCompute(_feature_image(frame, radiometric_range, clahe), None)
        # OpenCV puts pixel centres on integers, COLMAP at +0.5
        keypoints.append(np.array([k.pt for k in kp], dtype=np.float32).reshape(-1, 2) + 0.5)
        np.save(store / f"{i:05d}.npy", des if des is not None else np.zeros((0, 128), np.float32))

    @lru_cache(maxsize=2 * config.neighbours + 2)  # pairs are sorted by their first frame: it stays cached
    def descriptors(i: int) -> np.ndarray:
        return np.load(store / f"{i:05d}.npy")

    rec = pycolmap.Reconstruction()
    database = pycolmap.Database.open(str(work_dir / "database.db"))
    for i, frame in enumerate(frames):
        camera = colmap_camera(frame)
        camera.camera_id = i + 1
        rec.add_camera_with_trivial_rig(camera)
        database.write_camera(camera, use_camera_id=True)
        w2c = np.linalg.inv(frame.camera_to_world)
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(w2c[:3, :3]), w2c[:3, 3])
        name = f"{i:05d}_{frame.image.name}"  # unique even when folders repeat file names
        rec.add_image_with_trivial_frame(pycolmap.Image(name=name, camera_id=i + 1, image_id=i + 1), pose)
        database.write_image(pycolmap.Image(name=name, camera_id=i + 1, image_id=i + 1), use_image_id=True)
        database.write_keypoints(i + 1, keypoints[i])

    matcher = cv2.BFMatcher(cv2.NORM_L2)
    pairs = prior_pairs(frames, config.neighbours, config.max_view_angle_deg)
    inlier_counts = []
    for i, j in track(pairs, "Matching frame pairs"):
        if len(keypoints[i]) < 2 or len(keypoints[j]) < 2:
            continue
        knn = matcher.knnMatch(descriptors(i), descriptors(j), k=2)
        good = np.array(
            [
                (m[0].queryIdx, m[0].trainIdx)
                for m in knn
                if len(m) == 2 and m[0].distance < config.ratio * m[1].distance
            ],
            dtype=np.uint32,
        ).reshape(-1, 2)
        distance = _sampson(_fundamental(frames[i], frames[j]), keypoints[i][good[:, 0]], keypoints[j][good[:, 1]])
        inliers = good[distance < config.max_epipolar_px]
        inlier_counts.append(len(inliers))
        database.write_matches(i + 1, j + 1, good)
        geometry = pycolmap.TwoViewGeometry()
        geometry.config = pycolmap.TwoViewGeometryConfiguration.CALIBRATED
        geometry.inlier_matches = inliers
        database.write_two_view_geometry(i + 1, j + 1, geometry)
    database.close()
    descriptors.cache_clear()
    shutil.rmtree(store)

    (work_dir / "sparse").mkdir()
    # image_path: colours are not needed (and COLMAP would read RGB); the model lands in sparse/
    result = pycolmap.triangulate_points(rec, str(work_dir / "database.db"), str(work_dir), str(work_dir / "sparse"))
    (work_dir / "database.db").unlink()
    points = list(result.points3D.values())
    xyz = np.array([p.xyz for p in points], dtype=np.float64).reshape(-1, 3)
    errors = np.array([p.error for p in points], dtype=np.float64)
    report = {
        "frames": len(frames),
        "features_per_frame_median": float(np.median([len(k) for k in keypoints])),
        "pairs": len(pairs),
        "inlier_matches_per_pair_median": float(np.median(inlier_counts)) if inlier_counts else 0.0,
        "points": len(points),
        "reprojection_error_px_median": float(np.median(errors)) if len(errors) else None,
        "reprojection_error_px_p90": float(np.percentile(errors, 90)) if len(errors) else None,
        "mean_track_length": float(result.compute_mean_track_length()) if len(points) else 0.0,
    }
    return xyz, errors, report


def cached_triangulation(
    frames: Sequence[ThermalFrame],
    radiometric_range: RadiometricRange,
    cache_root: Path,
    config: TriangulationConfig = TriangulationConfig(),
) -> Tuple[np.ndarray, Dict]:
    """Triangulated points [N, 3] and the report, computed once per (frames, poses, parameters)."""
    key = cache_key(frames, radiometric_range, config)
    final = Path(cache_root) / f"triangulation-{key}"
    if (final / "report.json").is_file():
        try:
            return load_npy(final / "points.npy"), json.loads((final / "report.json").read_text())
        except (OSError, ValueError) as err:  # a file cut short or damaged (JSONDecodeError is a ValueError)
            CONSOLE.log(f"[yellow]{final}: the triangulation cache is damaged ({err}): triangulating again")
            discard_cache_folder(final)
    work = make_work_folder(Path(cache_root), ".triangulation-")
    try:
        start = time.perf_counter()
        xyz, errors, report = triangulate(frames, radiometric_range, work, config)
        report["seconds"] = round(time.perf_counter() - start, 1)
        np.save(work / "points.npy", xyz)
        np.save(work / "reprojection_errors.npy", errors)
        (work / "report.json").write_text(json.dumps(report, indent=1))
        publish_cache_folder(work, final, "report.json")
    except BaseException:
        shutil.rmtree(work, ignore_errors=True)
        raise
    return xyz, report
