"""A COLMAP sparse model (`cameras`, `images`, `points3D`; text or binary) read in plain Python, as COLMAP's
documentation and `scripts/python/read_write_model.py` lay the files out. Every count is checked against the bytes
left before it is trusted, so a damaged file (cut short, a byte flipped) is refused naming it, never read past its
end or into a huge allocation; and a COLMAP model reads where pycolmap is not installed."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import numpy as np

from thermal_wild_ns.errors import InputError, MissingInput, faults_named

CAMERA_MODELS = {  # COLMAP's model id: (name, parameter count)
    0: ("SIMPLE_PINHOLE", 3),
    1: ("PINHOLE", 4),
    2: ("SIMPLE_RADIAL", 4),
    3: ("RADIAL", 5),
    4: ("OPENCV", 8),
    5: ("OPENCV_FISHEYE", 8),
    6: ("FULL_OPENCV", 12),
    7: ("FOV", 5),
    8: ("SIMPLE_RADIAL_FISHEYE", 4),
    9: ("RADIAL_FISHEYE", 5),
    10: ("THIN_PRISM_FISHEYE", 12),
    11: ("RAD_TAN_THIN_PRISM_FISHEYE", 16),
}
PARAMETERS = {name: count for name, count in CAMERA_MODELS.values()}


@dataclass(frozen=True)
class ColmapCamera:
    model: str
    width: int
    height: int
    params: Tuple[float, ...]


@dataclass(frozen=True)
class ColmapImage:
    image_id: int
    camera_id: int
    name: str
    world_to_camera: np.ndarray
    """[4, 4] (OpenCV axes)."""


@dataclass(frozen=True)
class ColmapModel:
    cameras: Dict[int, ColmapCamera]
    images: List[ColmapImage]
    points: np.ndarray
    """[N, 3]."""


def read_colmap_model(folder: Path) -> ColmapModel:
    """The model in `folder` (binary where `images.bin` is there, else text); a `MissingInput` where there is none,
    an `InputError` naming the file where one is damaged or names a camera it does not define."""
    binary = (folder / "images.bin").is_file()
    if not folder.is_dir() or not (binary or (folder / "images.txt").is_file()):
        raise MissingInput(f"{folder}: no COLMAP model (images.bin/.txt, cameras.bin/.txt)")
    form = "bin" if binary else "txt"
    files = {name: folder / f"{name}.{form}" for name in ("cameras", "images", "points3D")}
    for path in files.values():
        if not path.is_file():
            raise MissingInput(f"{path}: missing from the COLMAP model in {folder}")
    readers = (_cameras_bin, _images_bin, _points_bin) if binary else (_cameras_txt, _images_txt, _points_txt)
    parts = []
    for (name, path), read in zip(files.items(), readers):
        with faults_named(path, f"a damaged COLMAP {name} file"):
            parts.append(read(path))
    cameras, images, points = parts
    if not images:
        raise InputError(f"{files['images']}: the COLMAP model has no images (empty sparse model)")
    for image in images:
        if image.camera_id not in cameras:
            raise InputError(
                f"{files['images']}: image {image.name} names camera {image.camera_id}, which {files['cameras']} "
                "does not define"
            )
    return ColmapModel(cameras, images, points)


def _pose(qvec, tvec) -> np.ndarray:
    w, x, y, z = (float(v) for v in qvec)
    norm = float(np.sqrt(w * w + x * x + y * y + z * z))
    if not np.isfinite(norm) or norm < 1e-8:
        raise ValueError(f"rotation quaternion {w, x, y, z} is not a rotation")
    w, x, y, z = w / norm, x / norm, y / norm, z / norm
    pose = np.eye(4)
    pose[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    pose[:3, 3] = [float(v) for v in tvec]
    return pose


# --------------------------------------------------------------------------- text
def _lines(path: Path) -> List[str]:
    text = path.read_bytes().decode("utf-8")
    return [line.strip() for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]


def _cameras_txt(path: Path) -> Dict[int, ColmapCamera]:
    cameras = {}
    for line in _lines(path):
        fields = line.split()
        model = fields[1]
        if model not in PARAMETERS or len(fields) != 4 + PARAMETERS[model]:
            raise ValueError(f"camera line '{line[:60]}': model {model} with {len(fields) - 4} parameters")
        cameras[int(fields[0])] = ColmapCamera(model, int(fields[2]), int(fields[3]), tuple(map(float, fields[4:])))
    return cameras


def _images_txt(path: Path) -> List[ColmapImage]:
    text = path.read_bytes().decode("utf-8")
    rows = [line for line in text.splitlines() if not line.lstrip().startswith("#")]
    images = []
    for header in rows[::2]:  # each image: its line, then its 2D points' line (possibly empty)
        fields = header.split()
        if not fields:
            continue
        if len(fields) < 10:
            raise ValueError(f"image line '{header[:60]}' has {len(fields)} fields, not 10")
        name = " ".join(fields[9:])
        images.append(ColmapImage(int(fields[0]), int(fields[8]), name, _pose(fields[1:5], fields[5:8])))
    return images


def _points_txt(path: Path) -> np.ndarray:
    xyz = [[float(v) for v in line.split()[1:4]] for line in _lines(path)]
    points = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    return points


# --------------------------------------------------------------------------- binary
class _Bytes:
    """A binary file read front to back; every read checked against the bytes left."""

    def __init__(self, path: Path):
        self.data, self.at = path.read_bytes(), 0

    def read(self, form: str) -> tuple:
        size = struct.calcsize(form)
        if self.at + size > len(self.data):
            raise ValueError(f"cut short at byte {self.at} ({size} more bytes expected)")
        values = struct.unpack_from(form, self.data, self.at)
        self.at += size
        return values

    def count(self, item_bytes: int) -> int:
        """A uint64 count of items of at least `item_bytes` bytes each, which the bytes left must hold."""
        (n,) = self.read("<Q")
        if n * item_bytes > len(self.data) - self.at:
            raise ValueError(
                f"a count of {n:,} at byte {self.at - 8} that the file's {len(self.data):,} bytes cannot hold"
            )
        return n

    def name(self) -> str:
        end = self.data.find(b"\0", self.at)
        if end < 0:
            raise ValueError(f"a name at byte {self.at} without its end")
        name, self.at = self.data[self.at : end].decode("utf-8"), end + 1
        return name

    def skip(self, size: int) -> None:
        if self.at + size > len(self.data):
            raise ValueError(f"cut short at byte {self.at} ({size} more bytes expected)")
        self.at += size

    def done(self) -> None:
        if self.at != len(self.data):
            raise ValueError(f"{len(self.data) - self.at:,} bytes past the last record")


def _cameras_bin(path: Path) -> Dict[int, ColmapCamera]:
    reader, cameras = _Bytes(path), {}
    for _ in range(reader.count(24)):
        camera_id, model_id, width, height = reader.read("<iiQQ")
        if model_id not in CAMERA_MODELS:
            raise ValueError(f"camera {camera_id}: unknown model id {model_id}")
        model, n = CAMERA_MODELS[model_id]
        cameras[camera_id] = ColmapCamera(model, width, height, reader.read(f"<{n}d"))
    reader.done()
    return cameras


def _images_bin(path: Path) -> List[ColmapImage]:
    reader, images = _Bytes(path), []
    for _ in range(reader.count(64 + 1 + 8)):
        image_id, *pose, camera_id = reader.read("<i7di")
        name = reader.name()
        (points,) = reader.read("<Q")
        reader.skip(24 * points)  # x, y, point id per 2D point
        images.append(ColmapImage(image_id, camera_id, name, _pose(pose[:4], pose[4:])))
    reader.done()
    return images


def _points_bin(path: Path) -> np.ndarray:
    reader, xyz = _Bytes(path), []
    for _ in range(reader.count(43 + 8)):
        _, x, y, z = reader.read("<Q3d")
        reader.skip(3 + 8)  # colour, error
        (track,) = reader.read("<Q")
        reader.skip(8 * track)  # image id, 2D point index per observation
        xyz.append((x, y, z))
    reader.done()
    return np.asarray(xyz, dtype=np.float64).reshape(-1, 3)


def camera_intrinsics(camera: ColmapCamera, source) -> Tuple[float, float, float, float, np.ndarray]:
    """fx, fy, cx, cy and nerfstudio distortion [k1, k2, k3, k4, p1, p2] of a COLMAP camera."""
    p, model = list(camera.params), camera.model
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


def points_or_none(model: ColmapModel) -> Optional[np.ndarray]:
    return model.points if len(model.points) else None
