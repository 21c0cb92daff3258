"""Readers for the published thermal dataset layouts, each returning a `ThermalCapture`.

Facts per layout come from the datasets' own loaders (cited per reader). Each reader sets every
frame's split by the dataset's published rule; `LAYOUTS` maps a layout name to its reader and to
a test that says why a folder is NOT of that layout (None when it is), which `detect_layout` uses.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Dict, Optional

import numpy as np
from plyfile import PlyData

from thermal_wild_ns.data.capture import (
    SeedPoints,
    ThermalCapture,
    ThermalFrame,
    check_pose,
    fraction_split,
    interval_split,
    opencv_to_opengl,
)
from thermal_wild_ns.data.colmap_layouts import read_colmap, read_msx, read_thermalmix
from thermal_wild_ns.data.frame_files import image_files, natural_key
from thermal_wild_ns.data.surveys import (
    OPENSFM_FILES,
    exif_gps_mismatch,
    metashape_mismatch,
    read_exif_gps,
    read_metashape,
    read_odm,
)
from thermal_wild_ns.data.thermal_io import IMAGE_SUFFIXES, RadiometricRange, frame_size, load_npy
from thermal_wild_ns.errors import InputError, MissingInput, faults_named


def _declared_range(meta: dict) -> Optional[RadiometricRange]:
    declared = meta.get("thermal")
    if not declared or "low" not in declared or "high" not in declared:
        return None
    return RadiometricRange(**{k: declared.get(k) for k in RadiometricRange.__dataclass_fields__ if k in declared})


def _read_ply_points(path: Path) -> Optional[SeedPoints]:
    try:
        vertex = PlyData.read(str(path))["vertex"]
    except Exception as err:  # plyfile raises several types for bad files
        raise InputError(f"{path}: unreadable point cloud ({err})") from err
    if len(vertex) == 0:
        return None
    xyz = np.stack([np.asarray(vertex[a], dtype=np.float64) for a in ("x", "y", "z")], -1)
    values = np.asarray(vertex["thermal"], dtype=np.float64) if "thermal" in vertex.data.dtype.names else None
    return SeedPoints(xyz=xyz, values=values, source=f"ply ({path.name})")


def read_nerfstudio(root: Path, thermal_only: bool = False) -> ThermalCapture:
    """nerfstudio `transforms.json` (OpenGL camera axes), global or per-frame intrinsics and
    OPENCV distortion (k1, k2, k3, p1, p2). Split: its `train_filenames`/`test_filenames` when
    present, otherwise every 8th frame held out. Optional extras: `thermal` (declared range),
    `ply_file_path` (seed points, `thermal` property in native units), `gt_file_path` per frame.

    `thermal_only`: keep only frames flagged `is_thermal` (ThermalNeRF, Lin et al.).
    """
    path = root / "transforms.json" if root.suffix != ".json" else root
    root = path.parent
    if not path.is_file():
        raise MissingInput(f"{path}: no transforms.json")
    with faults_named(path, "not a readable transforms.json"):
        meta = json.loads(path.read_bytes().decode("utf-8"))
    with faults_named(path, "a malformed transforms.json"):
        return _nerfstudio_capture(meta, path, thermal_only)


def _nerfstudio_capture(meta: dict, path: Path, thermal_only: bool) -> ThermalCapture:
    root = path.parent
    if not isinstance(meta.get("frames"), list):
        raise InputError(f"{path}: no 'frames' list")
    raw_frames = [f for f in meta["frames"] if f.get("is_thermal", False)] if thermal_only else meta["frames"]
    if thermal_only and not raw_frames:
        raise InputError(f"{path}: no frame is flagged is_thermal (ThermalNeRF layout)")
    frames = []
    for f in raw_frames:

        def get(key, default=None, f=f):
            return f.get(key, meta.get(key, default))

        model = get("camera_model", "OPENCV")
        if model not in ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE"):
            raise InputError(
                f"{path}: camera_model {model} of {f.get('file_path')} is not supported (OPENCV or PINHOLE)"
            )
        try:
            c2w = check_pose(np.array(f["transform_matrix"], dtype=np.float64), f"{path}, frame {f.get('file_path')}")
            intrinsics = [float(get(k)) for k in ("fl_x", "fl_y", "cx", "cy")] + [int(get(k)) for k in ("w", "h")]
        except (KeyError, TypeError) as err:
            raise InputError(f"{path}: frame {f.get('file_path')} lacks {err} (pose or intrinsics)") from err
        frames.append(
            ThermalFrame(
                image=root / f["file_path"],
                camera_to_world=opencv_to_opengl(c2w),
                fx=intrinsics[0],
                fy=intrinsics[1],
                cx=intrinsics[2],
                cy=intrinsics[3],
                width=intrinsics[4],
                height=intrinsics[5],
                distortion=np.array([float(get(k, 0.0)) for k in ("k1", "k2", "k3", "k4", "p1", "p2")]),
                ground_truth=root / f["gt_file_path"] if "gt_file_path" in f else None,
            )
        )
    if "train_filenames" in meta:
        held_out = {(root / n).resolve() for n in meta.get("test_filenames", meta.get("val_filenames", []))}
        splits = ["test" if fr.image.resolve() in held_out else "train" for fr in frames]
        rule = "the transforms' train/test_filenames"
    elif thermal_only:
        splits, rule = fraction_split(len(frames), 0.9), "evenly spaced 90/10 (ThermalNeRF)"
    else:
        splits, rule = interval_split(len(frames)), "every 8th frame held out"
    for frame, split in zip(frames, splits):
        frame.split = split
    ply = meta.get("ply_file_path")
    points = None
    if ply and not (root / ply).is_file():
        # the frames and poses are all there: train on the configured seeds rather than refuse the scene
        warnings.warn(f"{path}: ply_file_path {ply} is missing; seeds from --seed-points instead", stacklevel=2)
    elif ply:
        points = _read_ply_points(root / ply)
    return ThermalCapture(
        layout="thermalnerf" if thermal_only else "nerfstudio",
        root=root,
        frames=frames,
        split_rule=rule,
        declared_range=_declared_range(meta),
        points=points,
    )


def read_thermalnerf(root: Path) -> ThermalCapture:
    """ThermalNeRF (Lin et al.): nerfstudio transforms.json holding RGB and thermal frames; the
    thermal ones are flagged `is_thermal` (their loader, nerfstudio-thermal's
    `thermalnerf_dataparser.py`), with their own intrinsics and k1, k2, p1, p2, images in
    `images_thermal/` as 8-bit grey PNG. Only thermal frames are used; evenly spaced 90/10 split."""
    return read_nerfstudio(root, thermal_only=True)


def read_ye(root: Path) -> ThermalCapture:
    """Thermal-NeRF (Ye et al.): `<condition>/<sequence>/{train,test}/{intrinsics,pose,rgb}/`, one
    text file per image holding a 4x4 intrinsic matrix and a 4x4 camera-to-world pose (OpenCV
    axes); 382x288 frames (in `rgb/`, despite the name). `root` is the sequence folder. Split: the
    folders. Capture order: file names across both folders."""
    frames = []
    for split in ("train", "test"):
        folder = root / split
        images = image_files(folder / "rgb", IMAGE_SUFFIXES | {".npy"})
        poses = sorted((folder / "pose").glob("*.txt"), key=lambda p: natural_key(p.name))
        intrinsics = sorted((folder / "intrinsics").glob("*.txt"), key=lambda p: natural_key(p.name))
        if not (len(images) == len(poses) == len(intrinsics)):
            raise InputError(
                f"{folder}: {len(images)} images in rgb/, {len(poses)} poses in pose/, {len(intrinsics)} files in "
                "intrinsics/: the counts must match"
            )
        for image, pose, intr in zip(images, poses, intrinsics):
            if not (image.stem == pose.stem == intr.stem):
                raise InputError(f"{pose}: pose file does not match image {image.name} (files are paired by name)")
            c2w = check_pose(_read_matrix(pose), pose)
            K = _read_matrix(intr)
            if K.shape not in ((4, 4), (3, 3)):
                raise InputError(f"{intr}: intrinsics must be a 3x3 or 4x4 matrix, got {K.shape}")
            # image size: from the principal point until the frame is read (scan_frames checks it)
            frames.append(ThermalFrame(image, c2w, K[0, 0], K[1, 1], K[0, 2], K[1, 2], 0, 0, split=split))
    if frames:  # the layout does not record the image size
        size = frame_size(frames[0].image)
        for f in frames:
            f.width, f.height = size
    frames.sort(key=lambda f: natural_key(f.image.name))
    return ThermalCapture("ye", root, frames, "the train/ and test/ folders")


def _read_matrix(path: Path) -> np.ndarray:
    try:
        return np.loadtxt(path, dtype=np.float64, ndmin=2)
    except ValueError as err:
        raise InputError(f"{path}: not a whitespace-separated matrix ({err})") from err


def read_llff(root: Path, layout: str = "llff") -> ThermalCapture:
    """LLFF: `poses_bounds.npy` [N, 17] = per image a 3x5 matrix [R | t | (h, w, f)] with camera
    axes (down, right, back), plus near/far bounds; images in `images/` sorted by name (one per
    row). The focal length is rescaled to the actual image width. Split: every 8th image held out
    (LLFF's `llffhold`)."""
    path = root / "poses_bounds.npy"
    try:
        table = load_npy(path)
    except (OSError, ValueError) as err:
        raise InputError(f"{path}: unreadable poses_bounds.npy ({err})") from err
    if table.ndim != 2 or table.shape[1] != 17:
        raise InputError(f"{path}: expected an [N, 17] array, got {table.shape}")
    folder = next((root / d for d in ("images", "thermal") if (root / d).is_dir()), root / "images")
    images = image_files(folder, IMAGE_SUFFIXES | {".npy"}) if folder.is_dir() else []
    if len(images) != len(table):
        raise InputError(f"{path}: {len(table)} poses but {len(images)} images in {folder}: pose/image count mismatch")
    frames = []
    for row, image in zip(table, images):
        m = row[:15].reshape(3, 5)
        down, right, back = m[:, 0], m[:, 1], m[:, 2]
        c2w = np.eye(4)
        c2w[:3, :3] = np.stack([right, down, -back], axis=1)  # OpenCV: x right, y down, z forward
        c2w[:3, 3] = m[:, 3]
        c2w = check_pose(c2w, f"{path}, row {len(frames)} ({Path(image).name})")
        h, w, f = m[:, 4]
        frames.append(ThermalFrame(image, c2w, f, f, w / 2.0, h / 2.0, int(round(w)), int(round(h))))
    # LLFF records the size the poses were computed at; rescale to the stored frames
    w, h = frame_size(frames[0].image)
    for f in frames:
        s = w / f.width
        f.fx, f.fy, f.cx, f.cy, f.width, f.height = f.fx * s, f.fy * s, f.cx * s, f.cy * s, w, h
    for frame, split in zip(frames, interval_split(len(frames))):
        frame.split = split
    return ThermalCapture(layout, root, frames, "every 8th image held out (LLFF)")


def read_mvtv(root: Path) -> ThermalCapture:
    """MVTV (Xu et al., ECCV 2024). ASSUMPTION: its released layout could not be confirmed; the
    method builds on raw-image NeRF work that uses LLFF, so MVTV scenes are read as LLFF
    (`poses_bounds.npy` + thermal frames in `images/` or `thermal/`). If a release differs,
    convert it to LLFF or COLMAP."""
    return read_llff(root, layout="mvtv")


# --------------------------------------------------------------------------- registry / detection
@dataclass(frozen=True)
class Layout:
    read: Callable[[Path], ThermalCapture]
    mismatch: Callable[[Path], Optional[str]]
    """Why `root` is not this layout, or None when it looks like it."""
    description: str


def _needs(*parts: str) -> Callable[[Path], Optional[str]]:
    def mismatch(root: Path) -> Optional[str]:
        missing = [p for p in parts if not (root / p).exists()]
        return f"no {', '.join(missing)}" if missing else None

    return mismatch


def _transforms_mismatch(thermal_flag: bool) -> Callable[[Path], Optional[str]]:
    def mismatch(root: Path) -> Optional[str]:
        path = root / "transforms.json"
        if not path.is_file():
            return "no transforms.json"
        # the layout's own file is there: if it is broken, that is the error, and detection must not
        # fall through to a layout it happens to resemble as well (a COLMAP sparse/0 beside it)
        try:
            meta = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as err:
            raise InputError(f"{path}: not valid JSON ({err})") from None
        if not isinstance(meta, dict) or not isinstance(meta.get("frames"), list):
            raise InputError(f"{path}: expected a JSON object with a 'frames' list")
        flagged = any(isinstance(f, dict) and f.get("is_thermal") for f in meta["frames"])
        if flagged != thermal_flag:
            return "frames flagged is_thermal (ThermalNeRF)" if flagged else "no frame flagged is_thermal"
        return None

    return mismatch


def _thermalmix_mismatch(root: Path) -> Optional[str]:
    if not any((root / d / "0").is_dir() for d in ("colmap_sparse", "sparse")):
        return "no colmap_sparse/0 or sparse/0"
    if (root / "thermal" / "train").is_dir():
        return "thermal/train/ (that is MSX)"
    if not (root / "warped_thermal").is_dir():
        return "no warped_thermal/"
    return None


def _poses_bounds_mismatch(*parts: str) -> Callable[[Path], Optional[str]]:
    """LLFF-style: `poses_bounds.npy` (plus `parts`); a present but unreadable file stops detection."""

    def mismatch(root: Path) -> Optional[str]:
        path = root / "poses_bounds.npy"
        if path.is_file():
            try:
                array = np.load(path, allow_pickle=False)
            except (OSError, ValueError) as err:
                raise InputError(f"{path}: unreadable ({err})") from None
            if array.ndim != 2 or array.shape[1] != 17:
                raise InputError(f"{path}: shape {array.shape}, expected [N, 17] (LLFF poses and bounds)")
        return _needs("poses_bounds.npy", *parts)(root)

    return mismatch


def _colmap_mismatch(root: Path) -> Optional[str]:
    return _needs("sparse/0", "images")(root)


def _ti_nsd_mismatch(root: Path) -> Optional[str]:
    """TI-NSD's cue: COLMAP's layout whose images all have numeric names (1.jpg, 2.jpg, ...)."""
    reason = _colmap_mismatch(root)
    if reason is not None:
        return reason
    stems = [p.stem for p in (root / "images").iterdir() if p.suffix.lower() in IMAGE_SUFFIXES]
    if not stems or not all(stem.isdigit() for stem in stems):
        return "image names are not all numbers (TI-NSD's are)"
    return None


# Detection order matters: the specific layouts come before the generic ones they resemble.
LAYOUTS: Dict[str, Layout] = {
    "thermalnerf": Layout(
        read_thermalnerf, _transforms_mismatch(True), "ThermalNeRF (Lin et al.): transforms.json with is_thermal frames"
    ),
    "nerfstudio": Layout(read_nerfstudio, _transforms_mismatch(False), "nerfstudio transforms.json of thermal frames"),
    "ye": Layout(
        read_ye,
        _needs("train/pose", "train/intrinsics", "train/rgb"),
        "Thermal-NeRF (Ye et al.): {train,test}/{intrinsics,pose,rgb}/",
    ),
    "msx": Layout(
        read_msx,
        _needs("thermal/train", "sparse/0"),
        "MSX / RGBT-Scenes (ThermalGaussian): thermal/{train,test}/ + sparse/0",
    ),
    "thermalmix": Layout(
        read_thermalmix, _thermalmix_mismatch, "ThermalMix (Ozer et al.): warped_thermal/ + colmap_sparse/0"
    ),
    "mvtv": Layout(
        read_mvtv,
        _poses_bounds_mismatch("thermal"),
        "MVTV (Xu et al.): layout unconfirmed (no public loader), assumed LLFF: poses_bounds.npy + thermal/",
    ),
    "llff": Layout(read_llff, _poses_bounds_mismatch(), "LLFF: poses_bounds.npy + images/"),
    "ti-nsd": Layout(
        lambda root: read_colmap(root, layout="ti-nsd"),
        _ti_nsd_mismatch,
        "TI-NSD (Thermal3D-GS): images/ with numeric names + sparse/0, names sorted as strings",
    ),
    "colmap": Layout(read_colmap, _colmap_mismatch, "COLMAP sparse/0 + images/"),
    "odm": Layout(
        read_odm,
        lambda root: None if any((root / f).is_file() for f in OPENSFM_FILES) else f"no {' or '.join(OPENSFM_FILES)}",
        "a drone survey reconstructed by OpenDroneMap / OpenSfM: opensfm/reconstruction.json + images/ (R-JPEGs)",
    ),
    "metashape": Layout(
        read_metashape,
        metashape_mismatch,
        "a drone survey aligned in Metashape: its XML (or metashape/*.xml) + the frames (R-JPEGs) in rjpeg/ or images/",
    ),
    "exif-gps": Layout(
        read_exif_gps,
        exif_gps_mismatch,
        "a drone survey with no photogrammetry: geotagged frames (R-JPEGs) placed by SfM from their GPS and "
        "gimbal priors",
    ),
}


def detect_layout(root: Path) -> str:
    """The first layout `root` looks like; an error listing every layout tried (and why not). A
    layout whose own file is present but broken stops detection with that file's error."""
    if not Path(root).is_dir():
        raise MissingInput(f"{root}: data folder not found")
    reasons = {}
    for name, layout in LAYOUTS.items():
        reason = layout.mismatch(Path(root))
        if reason is None:
            return name
        reasons[name] = reason
    tried = "\n".join(f"  - {name} ({LAYOUTS[name].description}): {why}" for name, why in reasons.items())
    raise InputError(f"{root}: not a thermal dataset layout this plugin knows. Tried:\n{tried}")
