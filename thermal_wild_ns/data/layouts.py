"""Readers for the published thermal dataset layouts, each returning a `ThermalCapture`.

Facts per layout come from the datasets' own loaders (cited per reader). Each reader sets every
frame's split by the dataset's published rule; `LAYOUTS` maps a layout name to its reader and to
a test that says why a folder is NOT of that layout (None when it is), which `detect_layout` uses.
"""

from __future__ import annotations

import json
import re
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Dict, List, Optional, Tuple

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
from thermal_wild_ns.data.exif_sfm import (
    cached_structure_from_motion,
    focal_length_px,
    read_frame_prior,
    survey_georeference,
)
from thermal_wild_ns.data.metashape import read_lens_calibration, read_metashape_xml
from thermal_wild_ns.data.opensfm import read_reconstruction
from thermal_wild_ns.data.rjpeg import DJI_CONVERTER_INSTALL, dji_calibration, dji_converter, read_calibration
from thermal_wild_ns.data.thermal_io import IMAGE_SUFFIXES, RadiometricRange, load_npy, read_raw_frame
from thermal_wild_ns.errors import InputError, MissingInput

THERMALMIX_CELSIUS = {
    "face": (22.5, 35.2),
    "hand": (22.1, 33.6),
    "panel": (22.7, 55.8),
    "lion": (16.8, 48.3),
    "pan": (19.4, 129.8),
    "laptop": (21.6, 40.2),
}
"""ThermalMix (Ozer et al.): 8-bit frames are linear in degC between these per-scene bounds."""


def natural_key(name: str) -> list:
    """Sort key that orders 'frame2' before 'frame10'."""
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


def _image_files(folder: Path, suffixes=IMAGE_SUFFIXES) -> List[Path]:
    return sorted((p for p in folder.iterdir() if p.suffix.lower() in suffixes), key=lambda p: natural_key(p.name))


# --------------------------------------------------------------------------- nerfstudio transforms.json
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
    try:
        meta = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise InputError(f"{path}: not valid JSON ({err})") from err
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


# --------------------------------------------------------------------------- COLMAP based
def _read_colmap_model(folder: Path):
    import pycolmap  # here, not at the top: the light GPU install has none (SfM runs where it is installed)

    if not folder.is_dir() or not any((folder / f"images{ext}").is_file() for ext in (".bin", ".txt")):
        raise MissingInput(f"{folder}: no COLMAP model (images.bin/.txt, cameras.bin/.txt)")
    try:
        rec = pycolmap.Reconstruction(str(folder))
    except Exception as err:  # pycolmap raises RuntimeError/ValueError for corrupt models
        raise InputError(f"{folder}: unreadable COLMAP model ({err})") from err
    if rec.num_images() == 0:
        raise InputError(f"{folder}: the COLMAP model has no images (empty sparse model)")
    return rec


def _colmap_intrinsics(camera, source: str) -> Tuple[float, float, float, float, np.ndarray]:
    """fx, fy, cx, cy and nerfstudio distortion [k1, k2, k3, k4, p1, p2] of a COLMAP camera."""
    p = list(camera.params)
    model = camera.model.name
    dist = np.zeros(6)
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        fx = fy = p[0]
        cx, cy = p[1], p[2]
        dist[: len(p) - 3] = p[3:]
    elif model in ("PINHOLE", "OPENCV"):
        fx, fy, cx, cy = p[:4]
        if model == "OPENCV":
            dist[[0, 1, 4, 5]] = p[4:8]
    else:
        raise InputError(f"{source}: COLMAP camera model {model} is not supported (PINHOLE, SIMPLE_*, RADIAL, OPENCV)")
    return fx, fy, cx, cy, dist


def _colmap_frames(
    rec, folder: Path, find_image: Callable[[str], Tuple[Path, Optional[str]]], order: str = "name"
) -> List[ThermalFrame]:
    """Frames of a COLMAP model; `find_image(name)` gives the thermal file and split of an image."""
    keys = {
        "name": lambda im: natural_key(im.name),  # frame_2 before frame_10
        "string": lambda im: Path(im.name).stem,  # 3DGS's sort of image names: "10" before "2"
        "id": lambda im: im.image_id,
    }
    images = sorted(rec.images.values(), key=keys[order])
    frames = []
    for image in images:
        camera = rec.cameras[image.camera_id]
        fx, fy, cx, cy, dist = _colmap_intrinsics(camera, str(folder))
        w2c = np.concatenate([image.cam_from_world().matrix(), [[0.0, 0.0, 0.0, 1.0]]])
        path, split = find_image(image.name)
        frames.append(
            ThermalFrame(
                image=path,
                camera_to_world=np.linalg.inv(w2c),
                fx=fx,
                fy=fy,
                cx=cx,
                cy=cy,
                width=camera.width,
                height=camera.height,
                distortion=dist,
                split=split,
            )
        )
    return frames


def _colmap_points(rec) -> Optional[SeedPoints]:
    if rec.num_points3D() == 0:
        return None
    xyz = np.stack([p.xyz for p in rec.points3D.values()])
    return SeedPoints(xyz=xyz, source="colmap")


def read_colmap(root: Path, images: str = "images", layout: str = "colmap") -> ThermalCapture:
    """Generic COLMAP: `sparse/0` (binary or text) + a folder of thermal frames named as in the
    model, in natural name order (frame_2 before frame_10), every 8th held out.

    TI-NSD (Thermal3D-GS, `mzzcdf/Thermal3DGS`, `scene/dataset_readers.py`) is the same layout
    (`images/` + `sparse/0`, PINHOLE, numeric names) read as 3DGS reads it: image names sorted as
    strings ("10" before "2"), every 8th from the first held out (`--eval`, llffhold 8). The two
    orders give different held-out frames once names are unpadded numbers past 9."""
    rec = _read_colmap_model(root / "sparse" / "0")
    order = "string" if layout == "ti-nsd" else "name"
    frames = _colmap_frames(rec, root / "sparse" / "0", lambda name: (root / images / name, None), order=order)
    for frame, split in zip(frames, interval_split(len(frames))):
        frame.split = split
    rule = f"sorted by name{' as strings' if order == 'string' else ''}, every 8th frame held out"
    return ThermalCapture(layout, root, frames, rule, points=_colmap_points(rec))


def read_msx(root: Path) -> ThermalCapture:
    """MSX (ThermalGaussian / RGBT-Scenes): `rgb/{train,test}/`, `thermal/{train,test}/`,
    `sparse/0` computed on the RGB frames; a thermal frame has its RGB frame's file name
    (ThermalGaussian's `readTemperSceneInfo`). Thermal frames are 3-channel colour-mapped JPGs
    (iron palette), 640x480. The split is the folders' (test: every 8th image)."""
    rec = _read_colmap_model(root / "sparse" / "0")

    def find(name: str):
        base = Path(name).name
        for split in ("train", "test"):
            if (root / "thermal" / split / base).is_file():
                return root / "thermal" / split / base, split
        raise MissingInput(
            f"{root / 'thermal'}/{{train,test}}/{base}: thermal frame of COLMAP image '{name}' is missing"
        )

    frames = _colmap_frames(rec, root / "sparse" / "0", find)
    return ThermalCapture(
        "msx", root, frames, "the thermal/{train,test} folders", palette="iron", points=_colmap_points(rec)
    )


def read_thermalmix(
    root: Path, holdout_index: int = 20, celsius: Optional[Tuple[float, float]] = None
) -> ThermalCapture:
    """ThermalMix (Ozer et al.), as the authors' loader reads it (`mert-o/thermalnerfs`,
    `nerf/colmap_provider.py` at c8e8f8b): the COLMAP model in `colmap_sparse/0` (or `sparse/0`);
    for each model image, in image-id order, the thermal frame the poses belong to is
    `warped_thermal/<stem>.npy` (float degC). Where only `warped_thermal/<stem>.jpg` exists (8-bit
    grey, linear in degC between the scene's bounds, which `img_temp_mapper.py` turns into the
    `.npy`), that is read. The unwarped `thermal/` frames are never used (they do not match the
    poses). Model images without a frame are dropped BEFORE the held-out view is picked by its
    index (`--val_idx`, 20 in the authors' README), as their loader does. Bounds per scene
    (`THERMALMIX_CELSIUS`) come from the folder name unless `celsius` is given; without either the
    range is measured."""
    model = next(
        (root / d / "0" for d in ("colmap_sparse", "sparse") if (root / d / "0").is_dir()), root / "colmap_sparse" / "0"
    )
    rec = _read_colmap_model(model)
    folder = root / "warped_thermal"
    if not folder.is_dir():
        raise MissingInput(f"{folder}: no warped_thermal/ (the frames the poses belong to; thermal/ is not used)")

    def find(name: str):
        stem = Path(name).stem
        for path in (folder / f"{stem}.npy", folder / f"{stem}.jpg", folder / f"{stem}.png"):
            if path.is_file():
                return path, None
        return None, None

    listed = _colmap_frames(rec, model, find, order="id")
    frames = [f for f in listed if f.image is not None]
    if not frames:
        raise MissingInput(f"{folder}: none of the {len(listed)} images of {model} has a frame here (.npy/.jpg)")
    if len(frames) < len(listed):
        warnings.warn(
            f"{folder}: {len(listed) - len(frames)} of the {len(listed)} images of {model} have no frame; "
            "dropped before the held-out view is picked, as the authors' loader does",
            stacklevel=2,
        )
    if not 0 <= holdout_index < len(frames):
        raise InputError(f"{model}: held-out view index {holdout_index} is outside the {len(frames)} frames")
    for i, frame in enumerate(frames):
        frame.split = "test" if i == holdout_index else "train"
    suffixes = {f.image.suffix for f in frames}
    if len(suffixes) > 1:
        raise InputError(f"{folder}: frames of mixed formats ({', '.join(sorted(suffixes))}); use one")
    bounds = celsius or THERMALMIX_CELSIUS.get(root.name.lower())
    declared = None
    if bounds is not None:
        if frames[0].image.suffix == ".npy":
            declared = RadiometricRange(
                bounds[0], bounds[1], str(load_npy(frames[0].image, mmap_mode="r").dtype), *bounds
            )
        else:
            declared = RadiometricRange(0.0, 255.0, "uint8", *bounds)
    return ThermalCapture(
        "thermalmix",
        root,
        frames,
        f"view {holdout_index} (by image id, among the images with a frame) held out",
        declared_range=declared,
        points=_colmap_points(rec),
    )


# --------------------------------------------------------------------------- per-file poses / LLFF
def read_ye(root: Path) -> ThermalCapture:
    """Thermal-NeRF (Ye et al.): `<condition>/<sequence>/{train,test}/{intrinsics,pose,rgb}/`, one
    text file per image holding a 4x4 intrinsic matrix and a 4x4 camera-to-world pose (OpenCV
    axes); 382x288 frames (in `rgb/`, despite the name). `root` is the sequence folder. Split: the
    folders. Capture order: file names across both folders."""
    frames = []
    for split in ("train", "test"):
        folder = root / split
        images = _image_files(folder / "rgb", IMAGE_SUFFIXES | {".npy"})
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
        size = _frame_size(frames[0].image)
        for f in frames:
            f.width, f.height = size
    frames.sort(key=lambda f: natural_key(f.image.name))
    return ThermalCapture("ye", root, frames, "the train/ and test/ folders")


def _read_matrix(path: Path) -> np.ndarray:
    try:
        return np.loadtxt(path, dtype=np.float64, ndmin=2)
    except ValueError as err:
        raise InputError(f"{path}: not a whitespace-separated matrix ({err})") from err


def _frame_size(path: Path) -> Tuple[int, int]:
    """(width, height) of a frame file."""

    h, w = read_raw_frame(path).shape
    return w, h


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
    images = _image_files(folder, IMAGE_SUFFIXES | {".npy"}) if folder.is_dir() else []
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
    w, h = _frame_size(frames[0].image)
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


METASHAPE_FOLDERS = ("", "metashape")
"""Where a Metashape XML is looked for, relative to the data folder."""
FRAME_FOLDERS = ("rjpeg", "images", "thermal", "")
"""Where a drone survey's frames are looked for (the first folder with image files)."""


def _metashape_xml(root: Path) -> Optional[Path]:
    """The Metashape XML in `root` or `root/metashape` (a chunk's doc.xml or exported cameras)."""
    for folder in METASHAPE_FOLDERS:
        for path in sorted((root / folder).glob("*.xml")):
            with open(path, "rb") as handle:
                head = handle.read(4096)
            if b"<chunk" in head or b"<document" in head:
                return path
    return None


def _survey_frames_folder(root: Path) -> Path:
    folder = next((root / f for f in FRAME_FOLDERS if (root / f).is_dir() and _image_files(root / f)), None)
    if folder is None:
        folders = ", ".join(f + "/" for f in FRAME_FOLDERS if f)
        raise MissingInput(f"{root}: no frames in any of {folders} or the folder itself")
    return folder


def _survey_capture(layout: str, root: Path, source: Path, posed: list, unaligned=(), **facts) -> ThermalCapture:
    """A drone survey's capture from its photogrammetry: `posed`, (name, ThermalFrame with no image
    yet) per aligned camera, matched by file name to the frames in the survey's frame folder; frames
    in file-name order, which is capture order for drone files (DJI_0001, ...); every 8th held out.
    Radiometric JPEGs must carry their thermal data (never their colour preview) and give the °C
    calibration. `facts`: the capture's georeference and points."""

    folder = _survey_frames_folder(root)
    images = {p.stem: p for p in _image_files(folder)}
    frames, calibrations = [], {}
    for name, frame in sorted(posed, key=lambda named: natural_key(named[0])):
        image = images.get(Path(name).stem)
        if image is None:
            continue
        if image.suffix.lower() in (".jpg", ".jpeg"):
            calibrations[image] = read_calibration(image)
        frame.image = image
        frames.append(frame)
    if not frames:
        raise InputError(
            f"{source}: none of its {len(posed)} aligned cameras has a frame in {folder} "
            f"(cameras are matched to files by name, e.g. {posed[0][0] if posed else '-'})"
        )
    without = sorted(set(images) - {Path(name).stem for name, _ in posed})
    if without:
        not_aligned = [name for name in without if name in {Path(u).stem for u in unaligned}]
        warnings.warn(
            f"{folder}: {len(without)} frame(s) without a pose in {source.name} are left out"
            f"{' (the photogrammetry could not align ' + ', '.join(not_aligned[:5]) + ')' if not_aligned else ''}: "
            f"{', '.join(without[:5])}{' ...' if len(without) > 5 else ''}",
            stacklevel=3,
        )
    for frame, split in zip(frames, interval_split(len(frames))):
        frame.split = split
    return ThermalCapture(
        layout,
        root,
        frames,
        "every 8th frame held out",
        celsius_calibration=_one_calibration(calibrations, folder),
        **facts,
    )


def read_metashape(root: Path) -> ThermalCapture:
    """A drone survey aligned in Agisoft Metashape: its XML (`METASHAPE_FOLDERS` says where it is
    looked for) and the frames as the camera wrote them (radiometric JPEGs, or 16-bit frames) in
    the first of `FRAME_FOLDERS` that holds images. Poses in a local east-north-up frame in metres
    where the chunk is georeferenced (`metashape.py`)."""

    xml = _metashape_xml(root)
    if xml is None:
        raise MissingInput(f"{root}: no Metashape XML in {' or '.join(str(root / f) for f in METASHAPE_FOLDERS)}")
    posed, georeference, unaligned = read_metashape_xml(xml)
    return _survey_capture("metashape", root, xml, posed, unaligned, georeference=georeference)


OPENSFM_FILES = ("opensfm/reconstruction.json", "reconstruction.json")
"""Where an OpenDroneMap project (opensfm/) or an OpenSfM dataset keeps its reconstruction."""


def read_odm(root: Path) -> ThermalCapture:
    """A drone survey reconstructed by OpenDroneMap or OpenSfM (`opensfm.py`): the reconstruction's
    shots, cameras and points in its east-north-up frame around `reference_lla`, and the frames as
    the camera wrote them in the first of `FRAME_FOLDERS` that holds images (ODM: `images/`)."""

    path = next((root / f for f in OPENSFM_FILES if (root / f).is_file()), None)
    if path is None:
        raise MissingInput(f"{root}: no {' or '.join(OPENSFM_FILES)}")
    posed, xyz, georeference = read_reconstruction(path)
    points = SeedPoints(xyz, "opensfm") if xyz is not None and len(xyz) else None
    return _survey_capture("odm", root, path, posed, georeference=georeference, points=points)


def read_exif_gps(
    root: Path, cache_root: Optional[Path] = None, lens_calibration: Optional[Path] = None
) -> ThermalCapture:
    """A drone survey with no photogrammetry: geotagged frames as the camera wrote them (the first
    of `FRAME_FOLDERS` that holds images), placed by structure from motion with their EXIF GPS and
    XMP gimbal angles as priors (`exif_sfm.py`; cached under `cache_root`, default
    `<root>/.thermal_wild_ns`). `lens_calibration`: a Metashape / Agisoft Lens calibration XML,
    held fixed (without it the focal length comes from the files and distortion is taken as none).
    Frames without GPS are left out by name."""

    folder = _survey_frames_folder(root)
    images = _image_files(folder)
    read = [(p, read_frame_prior(p)) for p in images]
    geotagged, priors = [p for p, prior in read if prior is not None], [prior for _, prior in read if prior is not None]
    if not geotagged:
        raise InputError(f"{folder}: none of its {len(images)} frames has a GPS position in its EXIF")
    if len(geotagged) < len(images):
        missing = [p.name for p, prior in read if prior is None]
        warnings.warn(
            f"{folder}: {len(missing)} frame(s) without GPS are left out: {', '.join(missing[:5])}", stacklevel=2
        )
    width, height = _frame_size(geotagged[0])  # SfM checks that every frame has this size
    focal = focal_length_px(geotagged[0], width, height)  # one camera: its first frame says it
    georeference = survey_georeference(
        priors, f"EXIF GPS of {folder} (altitudes above sea level, taken as ellipsoidal heights)"
    )
    calibration = read_lens_calibration(Path(lens_calibration)) if lens_calibration is not None else None
    result = cached_structure_from_motion(
        geotagged,
        priors,
        georeference,
        focal,
        calibration,
        Path(cache_root) if cache_root else root / ".thermal_wild_ns",
    )
    camera = result.camera
    posed = [
        (
            name,
            ThermalFrame(
                Path(), pose, camera.fx, camera.fy, camera.cx, camera.cy, width, height, camera.distortion.copy()
            ),
        )
        for name, pose in result.poses.items()
    ]
    unaligned = [p.name for p in geotagged if p.name not in result.poses]
    points = SeedPoints(result.points, "sfm (exif-gps)") if len(result.points) else None
    return _survey_capture("exif-gps", root, folder, posed, unaligned, georeference=georeference, points=points)


def _exif_gps_mismatch(root: Path) -> Optional[str]:
    try:
        first = _image_files(_survey_frames_folder(root))[0]
        if read_frame_prior(first) is None:
            return f"{first.name} has no GPS position in its EXIF"
    except InputError as err:  # no frames, or an unreadable first one: not this layout
        return str(err)
    return None


def _one_calibration(calibrations: Dict[Path, object], folder: Path):
    """The frames' shared °C calibration (the camera's settings do not change within a flight):
    the FLIR records' (where the settings differ, emissivity or distance changed mid-flight, the
    first frame's, said in the log: the model has one radiometric scale), or DJI's converter's
    table over all the frames (DJI's format: None, said in the log, where it is not installed)."""

    found = list(calibrations.values())
    if not found:
        return None
    if all(c is None for c in found):  # DJI's format: the calibration is DJI's converter
        if dji_converter() is None:
            warnings.warn(
                f"{folder}: DJI-format R-JPEGs train on their raw counts, without °C: to have °C, "
                f"{DJI_CONVERTER_INSTALL}",
                stacklevel=3,
            )
            return None
        return dji_calibration(list(calibrations))
    if any(c is None for c in found):
        return None
    differing = sorted(path.name for path, c in calibrations.items() if c != found[0])
    if differing:
        warnings.warn(
            f"{folder}: {len(differing)} frame(s) carry other measurement settings than the first "
            f"({', '.join(differing[:5])}); °C use the first frame's",
            stacklevel=2,
        )
    return found[0]


def _metashape_mismatch(root: Path) -> Optional[str]:
    if _metashape_xml(root) is None:
        return "no Metashape XML (with a <chunk>) in the folder or metashape/"
    return None


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
        _metashape_mismatch,
        "a drone survey aligned in Metashape: its XML (or metashape/*.xml) + the frames (R-JPEGs) in rjpeg/ or images/",
    ),
    "exif-gps": Layout(
        read_exif_gps,
        _exif_gps_mismatch,
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
