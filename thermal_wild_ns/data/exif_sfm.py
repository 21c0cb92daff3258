"""Poses for a drone survey with no photogrammetry: the GPS in each frame's EXIF and the gimbal
angles in its XMP as priors, refined by structure from motion (pycolmap) on the thermal frames.

What each frame says about itself (`exif.FramePrior`: GPS, gimbal, focal length) is metres and
degrees off: too coarse to train on, enough to say which frames overlap and where the site is.

Structure from motion then places the frames from the frames themselves: each frame on the
flight's radiometric range (one range, never per frame) and locally equalised (CLAHE), COLMAP's
SIFT with a low peak threshold (thermal frames are low-contrast), each frame matched with its
nearest cameras that look the same way (from the priors), and COLMAP's incremental mapper with
the GPS positions as priors, so the result lands in the priors' east-north-up frame, in metres.
Two choices are thermal- and survey-specific:
- the mapper's first pair needs only a 4° triangulation angle (COLMAP's default 16° is never
  reached by overlapping nadir frames at survey height);
- the intrinsics are held fixed. A survey flown straight down over flat ground cannot tell the
  focal length from the height, nor radial distortion from a bowl-shaped ground ("doming"), and
  letting bundle adjustment refine them makes the poses worse, not better. A lens calibration
  (a Metashape / Agisoft Lens calibration XML) is used as given where the user has one.

The frames SfM cannot place are left out by name; where fewer than `min_registered_share` of them
are placed, an error says what it found (features, verified pairs) and what to do instead. The
result is cached per (frames, priors, calibration, parameters), written to a temporary folder and
renamed into place, as the triangulation cache is.
"""

from __future__ import annotations

import hashlib
import json
import math
import shutil
import time
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

import cv2
import numpy as np
from nerfstudio.utils.rich_utils import CONSOLE

from thermal_wild_ns.data.capture import ThermalFrame
from thermal_wild_ns.data.exif import FramePrior
from thermal_wild_ns.data.georeference import Georeference
from thermal_wild_ns.data.thermal_io import (
    discard_cache_folder,
    file_fingerprint,
    load_npy,
    make_work_folder,
    publish_cache_folder,
    read_raw_frame,
)
from thermal_wild_ns.data.triangulation import colmap_camera, equalised_grey, prior_pairs
from thermal_wild_ns.errors import InputError
from thermal_wild_ns.progress import track

CACHE_VERSION = 3


@dataclass(frozen=True)
class SfmConfig:
    max_features: int = 8000
    """SIFT features per frame at most."""
    peak_threshold: float = 0.0067 / 3
    """COLMAP SIFT peak threshold (a third of its default: thermal frames are low-contrast)."""
    clahe_clip: float = 2.0
    """CLAHE clip limit on the range-normalised 8-bit frame before SIFT."""
    neighbours: int = 12
    """Each frame is matched with this many nearest cameras (by GPS) that look the same way."""
    max_view_angle_deg: float = 60.0
    """Only pairs whose gimbal viewing directions differ by less than this are matched."""
    init_min_tri_angle_deg: float = 4.0
    """The mapper's first pair's least triangulation angle (COLMAP's 16° suits hand-held captures)."""
    gps_sigma_m: Tuple[float, float] = (3.0, 5.0)
    """Standard deviation of the GPS positions (horizontal, vertical), metres."""
    fallback_focal_factor: float = 1.2
    """Focal length = this x the frame's larger side, where neither the file nor a calibration says (COLMAP's guess)."""
    min_registered_share: float = 0.5
    """Fewer frames placed than this share is a failure (an error), not a capture."""


@dataclass(frozen=True)
class SfmResult:
    poses: Dict[str, np.ndarray]
    """File name -> [4, 4] camera (OpenCV axes) -> east-north-up, metres; the frames SfM placed."""
    camera: ThermalFrame
    """The intrinsics every frame shares (no image, no pose)."""
    points: np.ndarray
    """[N, 3] sparse points, east-north-up."""
    report: Dict


def _prior_frames(
    images: Sequence[Path], priors: Sequence[FramePrior], georeference: Georeference, camera: ThermalFrame
) -> List[ThermalFrame]:
    return [
        ThermalFrame(
            image,
            prior.camera_to_enu(georeference),
            camera.fx,
            camera.fy,
            camera.cx,
            camera.cy,
            camera.width,
            camera.height,
        )
        for image, prior in zip(images, priors)
    ]


def initial_camera(
    focal: Tuple[Optional[float], str], width: int, height: int, calibration: Optional[ThermalFrame], config: SfmConfig
) -> Tuple[ThermalFrame, str]:
    """The intrinsics SfM holds fixed, and where they came from: the lens calibration, else the
    focal length the files record (`focal_length_px`: focal in pixels, its source), else a guess."""
    if calibration is not None:
        if (calibration.width, calibration.height) != (width, height):
            raise InputError(
                f"the lens calibration is for {calibration.width}x{calibration.height} frames; "
                f"these are {width}x{height}"
            )
        return calibration, "lens calibration"
    value, source = focal
    if value is None:
        value, source = config.fallback_focal_factor * max(width, height), "a guess (the files give no focal length)"
    return ThermalFrame(Path(), np.eye(4), value, value, width / 2.0, height / 2.0, width, height), source


def _rotation_angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(np.clip((np.trace(a.T @ b) - 1.0) / 2.0, -1.0, 1.0)))


def structure_from_motion(
    images: Sequence[Path],
    priors: Sequence[FramePrior],
    georeference: Georeference,
    focal: Tuple[Optional[float], str],
    calibration: Optional[ThermalFrame],
    work_dir: Path,
    config: SfmConfig,
) -> SfmResult:
    """The frames' poses in the georeference's east-north-up frame, from the frames and their
    priors (`focal`: what the files say of the focal length, `initial_camera`); intermediate files
    under `work_dir`."""
    import pycolmap  # here, not at the top: the light GPU install has none (SfM runs where it is installed)

    pycolmap.set_random_seed(0)  # RANSAC and the mapper draw samples: the same frames give the same poses
    rasters = [read_raw_frame(path).astype(np.float32) for path in track(images, "Reading frames for SfM")]
    height, width = rasters[0].shape
    for path, raster in zip(images, rasters):
        if raster.shape != (height, width):
            raise InputError(f"{path}: {raster.shape[1]}x{raster.shape[0]}, the survey's first frame {width}x{height}")
    camera, camera_source = initial_camera(focal, width, height, calibration, config)
    low, high = np.percentile(np.stack(rasters), [0.1, 99.9])
    clahe = cv2.createCLAHE(clipLimit=config.clahe_clip, tileGridSize=(8, 8))
    folder = work_dir / "frames"
    folder.mkdir()
    names = [f"{i:05d}_{path.stem}.png" for i, path in enumerate(images)]  # unique, whatever the folders
    for name, raster in zip(names, rasters):
        cv2.imwrite(str(folder / name), equalised_grey((raster - low) / max(high - low, 1e-6), clahe))
    del rasters

    database_path = work_dir / "database.db"
    with CONSOLE.status("SfM: SIFT on the thermal frames"):
        reader = pycolmap.ImageReaderOptions()
        extraction = pycolmap.FeatureExtractionOptions()
        extraction.sift.peak_threshold = config.peak_threshold
        extraction.sift.max_num_features = config.max_features
        extraction.num_threads = 1  # one thread: the same features in the same order on every machine
        pycolmap.extract_features(
            database_path,
            folder,
            image_names=names,
            camera_mode=pycolmap.CameraMode.SINGLE,
            reader_options=reader,
            extraction_options=extraction,
            device=pycolmap.Device.cpu,
        )
    prior_frames = _prior_frames(images, priors, georeference, camera)
    database = pycolmap.Database.open(str(database_path))
    try:
        fixed = colmap_camera(camera)
        stored = database.read_all_cameras()
        fixed.camera_id = stored[0].camera_id
        fixed.has_prior_focal_length = True
        database.update_camera(fixed)
        index = {name: i for i, name in enumerate(names)}
        features = []
        for image in database.read_all_images():
            i = index[image.name]
            covariance = np.diag([config.gps_sigma_m[0] ** 2, config.gps_sigma_m[0] ** 2, config.gps_sigma_m[1] ** 2])
            prior = pycolmap.PosePrior(
                position=prior_frames[i].camera_to_world[:3, 3],
                position_covariance=covariance,
                coordinate_system=pycolmap.PosePriorCoordinateSystem.CARTESIAN,
                corr_data_id=image.data_id,
            )
            database.write_pose_prior(prior)
            features.append(database.read_keypoints(image.image_id).shape[0])
    finally:
        database.close()
    pairs = prior_pairs(prior_frames, config.neighbours, config.max_view_angle_deg)
    pairs_path = work_dir / "pairs.txt"
    pairs_path.write_text("".join(f"{names[i]} {names[j]}\n" for i, j in pairs))
    with CONSOLE.status(f"SfM: matching {len(pairs)} frame pairs"):
        verification = pycolmap.TwoViewGeometryOptions()
        verification.ransac.random_seed = 0
        matching = pycolmap.FeatureMatchingOptions()
        matching.num_threads = 1
        pycolmap.match_image_pairs(
            database_path,
            pairing_options=pycolmap.ImportedPairingOptions(match_list_path=pairs_path),
            matching_options=matching,
            verification_options=verification,
            device=pycolmap.Device.cpu,
        )
    database = pycolmap.Database.open(str(database_path))
    try:
        verified = [len(g.inlier_matches) for g in database.read_two_view_geometries()[1]]
    finally:
        database.close()

    options = pycolmap.IncrementalPipelineOptions()
    options.use_prior_position = True
    options.use_robust_loss_on_prior_position = True
    options.multiple_models = False
    options.mapper.init_min_tri_angle = config.init_min_tri_angle_deg
    options.ba_refine_focal_length = False
    options.ba_refine_extra_params = False
    options.ba_refine_principal_point = False
    options.mapper.abs_pose_refine_focal_length = False
    options.mapper.abs_pose_refine_extra_params = False
    options.random_seed = 0
    options.num_threads = 1  # the same poses on every machine
    sparse = work_dir / "sparse"
    sparse.mkdir()
    with CONSOLE.status("SfM: incremental mapping with the GPS priors"):
        models = pycolmap.incremental_mapping(database_path, folder, sparse, options)
    model = max(models.values(), key=lambda m: m.num_reg_images()) if models else None
    placed = model.num_reg_images() if model is not None else 0
    report = {
        "frames": len(images),
        "registered": placed,
        "features_per_frame_median": float(np.median(features)) if features else 0.0,
        "pairs": len(pairs),
        "verified_matches_per_pair_median": float(np.median(verified)) if verified else 0.0,
        "intrinsics": {"fx": camera.fx, "fy": camera.fy, "cx": camera.cx, "cy": camera.cy, "source": camera_source},
    }
    if placed < max(3, math.ceil(config.min_registered_share * len(images))):
        raise InputError(
            f"{images[0].parent}: structure from motion placed {placed} of {len(images)} frames (median "
            f"{report['features_per_frame_median']:.0f} SIFT features per frame, "
            f"{report['verified_matches_per_pair_median']:.0f} "
            f"verified matches per pair): the frames have too little texture or overlap for it. Align them in "
            f"Metashape or OpenDroneMap and use that layout (metashape-data, odm-data)"
        )
    poses, by_name = {}, {name: image for name, image in zip(names, images)}
    for image in model.images.values():
        if not image.has_pose:
            continue
        world_to_camera = np.eye(4)
        world_to_camera[:3, :4] = image.cam_from_world().matrix()
        poses[by_name[image.name].name] = np.linalg.inv(world_to_camera)
    points = np.array([p.xyz for p in model.points3D.values()], dtype=np.float64).reshape(-1, 3)
    prior_of = {image.name: frame.camera_to_world for image, frame in zip(images, prior_frames)}
    gps_offsets = [np.linalg.norm(pose[:3, 3] - prior_of[name][:3, 3]) for name, pose in poses.items()]
    with_gimbal = [name for name, p in zip((i.name for i in images), priors) if p.yaw is not None and name in poses]
    report.update(
        {
            "points": len(points),
            "reprojection_error_px_mean": float(model.compute_mean_reprojection_error()),
            "gps_offset_m_median": float(np.median(gps_offsets)),
            "gimbal_difference_deg_median": float(
                np.median([_rotation_angle_deg(prior_of[n][:3, :3], poses[n][:3, :3]) for n in with_gimbal])
            )
            if with_gimbal
            else None,
        }
    )
    return SfmResult(poses, camera, points, report)


@contextmanager
def _colmap_errors_only():
    """COLMAP logs every step of SfM on stderr: the user gets our summary, and COLMAP's errors."""
    import pycolmap  # here, not at the top: the light GPU install has none (SfM runs where it is installed)

    level = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = int(pycolmap.logging.ERROR)
    try:
        yield
    finally:
        pycolmap.logging.minloglevel = level


def _cache_key(images: Sequence[Path], priors, focal, calibration: Optional[ThermalFrame], config: SfmConfig) -> str:
    h = hashlib.sha256(
        json.dumps({"version": CACHE_VERSION, "config": asdict(config), "focal": list(focal)}, sort_keys=True).encode()
    )
    for image, prior in zip(images, priors):
        h.update(file_fingerprint(image) + json.dumps(asdict(prior), sort_keys=True).encode())
    if calibration is not None:
        h.update(
            np.round(
                [calibration.fx, calibration.fy, calibration.cx, calibration.cy, *calibration.distortion], 9
            ).tobytes()
        )
    return h.hexdigest()[:16]


def cached_structure_from_motion(
    images: Sequence[Path],
    priors: Sequence[FramePrior],
    georeference: Georeference,
    focal: Tuple[Optional[float], str],
    calibration: Optional[ThermalFrame],
    cache_root: Path,
    config: SfmConfig = SfmConfig(),
) -> SfmResult:
    """`structure_from_motion`, computed once per (frames, priors, calibration, parameters): the
    poses, camera, points and report are kept under `cache_root`, with the COLMAP model (sparse/)."""
    final = Path(cache_root) / f"sfm-{_cache_key(images, priors, focal, calibration, config)}"
    if (final / "report.json").is_file():
        try:
            stored = json.loads((final / "poses.json").read_text())
            camera = stored["camera"]
            return SfmResult(
                {name: np.asarray(pose) for name, pose in stored["poses"].items()},
                ThermalFrame(
                    Path(),
                    np.eye(4),
                    camera["fx"],
                    camera["fy"],
                    camera["cx"],
                    camera["cy"],
                    camera["width"],
                    camera["height"],
                    np.asarray(camera["distortion"]),
                ),
                load_npy(final / "points.npy"),
                json.loads((final / "report.json").read_text()),
            )
        except (OSError, ValueError, KeyError) as err:  # a file cut short or damaged
            CONSOLE.log(f"[yellow]{final}: the SfM cache is damaged ({err}): running SfM again")
            discard_cache_folder(final)
    work = make_work_folder(Path(cache_root), ".sfm-")
    try:
        start = time.perf_counter()
        with _colmap_errors_only():
            result = structure_from_motion(images, priors, georeference, focal, calibration, work, config)
        result.report["seconds"] = round(time.perf_counter() - start, 1)
        shutil.rmtree(work / "frames")
        (work / "database.db").unlink()
        c = result.camera
        camera = {
            "fx": c.fx,
            "fy": c.fy,
            "cx": c.cx,
            "cy": c.cy,
            "width": c.width,
            "height": c.height,
            "distortion": list(c.distortion),
        }
        poses = {name: pose.tolist() for name, pose in result.poses.items()}
        (work / "poses.json").write_text(json.dumps({"camera": camera, "poses": poses}))
        np.save(work / "points.npy", result.points)
        (work / "report.json").write_text(json.dumps(result.report, indent=1))
        publish_cache_folder(work, final, "report.json")
    except BaseException:
        shutil.rmtree(work, ignore_errors=True)
        raise
    return result
