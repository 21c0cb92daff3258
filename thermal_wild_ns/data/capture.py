"""A thermal capture in one convention, whatever layout it came from.

Every layout reader (`layouts.py`) produces a `ThermalCapture`: frames in capture order, each
with its image, pinhole(+distortion) intrinsics and camera-to-world pose in OpenCV axes
(x right, y down, z forward; the COLMAP convention), its split when the dataset fixes one, and
the dataset's radiometric facts. `validate` checks what a reader cannot: poses are finite and
rigid, intrinsics are sane. The dataparser turns a capture into nerfstudio's outputs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import List, Literal, Optional, Union

import numpy as np

from thermal_wild_ns.data.celsius import CelsiusCalibration
from thermal_wild_ns.data.georeference import Georeference
from thermal_wild_ns.data.thermal_io import RadiometricRange
from thermal_wild_ns.errors import InputError, MissingInput

Split = Literal["train", "test"]


@dataclass
class ThermalFrame:
    image: Path
    """The thermal frame as captured (with its sensor faults)."""
    camera_to_world: np.ndarray
    """[4, 4] pose, OpenCV camera axes (x right, y down, z forward)."""
    fx: float
    fy: float
    cx: float
    """Principal point in COLMAP pixel coordinates (the top-left pixel's centre is (0.5, 0.5))."""
    cy: float
    width: int
    height: int
    distortion: np.ndarray = field(default_factory=lambda: np.zeros(6))
    """[6] k1, k2, k3, k4, p1, p2 (nerfstudio's order); zeros for a pinhole camera."""
    split: Optional[Split] = None
    """The dataset's own split for this frame, when it defines one."""
    ground_truth: Optional[Path] = None
    """Clean frame for evaluation (generated scenes only)."""
    celsius: Optional[CelsiusCalibration] = None
    """This frame's own calibration of its raw counts to °C at its measurement settings (R-JPEGs)."""

    def intrinsics_matrix(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


@dataclass
class SeedPoints:
    """Sparse 3D points in the capture's world frame."""

    xyz: np.ndarray
    """[N, 3]"""
    source: str
    """Where they came from (for the log): 'colmap', 'ply', 'triangulated', 'random'."""
    values: Optional[np.ndarray] = None
    """[N] per-point value in the dataset's native units, when the source has one."""


@dataclass
class ThermalCapture:
    layout: str
    """Name of the layout that was read."""
    root: Path
    frames: List[ThermalFrame]
    """In capture order (the order frame embeddings and photometric stabilization see)."""
    split_rule: str
    """How the held-out frames are chosen, in words (for the log)."""
    declared_range: Optional[RadiometricRange] = None
    """The dataset's documented radiometric range, when there is one (otherwise measured)."""
    palette: Optional[str] = None
    """The palette of colour-mapped frames, when the layout fixes one (otherwise detected)."""
    points: Optional[SeedPoints] = None
    """The layout's own sparse points (SfM), when it ships a non-empty set."""
    georeference: Optional[Georeference] = None
    """Where the capture's world frame sits on the Earth, when the layout says (photogrammetry)."""
    celsius_calibration: Optional[CelsiusCalibration] = None
    """The camera's calibration of its raw counts to °C, when the frames carry one (R-JPEGs)."""


def check_pose(c2w: np.ndarray, source: Union[Path, str]) -> np.ndarray:
    """A finite rigid [4, 4] camera-to-world pose, or an error naming `source` (the file, and the frame
    where one file holds every pose)."""
    c2w = np.asarray(c2w, dtype=np.float64)
    if c2w.shape == (3, 4):
        c2w = np.concatenate([c2w, [[0.0, 0.0, 0.0, 1.0]]])
    if c2w.shape != (4, 4):
        raise InputError(f"{source}: camera pose has shape {c2w.shape}, expected 4x4 or 3x4")
    if not np.all(np.isfinite(c2w)):
        raise InputError(f"{source}: camera pose has non-finite values")
    rotation = c2w[:3, :3]
    orthogonality = np.abs(rotation.T @ rotation - np.eye(3)).max()
    if orthogonality > 1e-3 or abs(np.linalg.det(rotation) - 1.0) > 1e-3 or np.abs(c2w[3] - [0, 0, 0, 1]).max() > 1e-6:
        raise InputError(
            f"{source}: camera pose is not rigid (rotation part deviates from orthonormal by {orthogonality:.2g}, "
            f"det {np.linalg.det(rotation):.4f}); poses must be rotation + translation"
        )
    return c2w


def validate(capture: ThermalCapture) -> ThermalCapture:
    """Errors (naming the file) for missing images, bad poses, bad intrinsics, half-set splits."""
    if not capture.frames:
        raise InputError(f"{capture.root}: no thermal frames found ({capture.layout} layout)")
    for frame in capture.frames:
        if not frame.image.is_file():
            raise MissingInput(f"{frame.image}: thermal frame listed by the {capture.layout} layout is missing")
        check_pose(frame.camera_to_world, frame.image)
        values = [frame.fx, frame.fy, frame.cx, frame.cy, frame.width, frame.height]
        if not np.all(np.isfinite(values)) or min(frame.fx, frame.fy, frame.width, frame.height) <= 0:
            raise InputError(
                f"{frame.image}: invalid intrinsics fx={frame.fx} fy={frame.fy} size={frame.width}x{frame.height}"
            )
    has_split = [f.split is not None for f in capture.frames]
    if any(has_split) and not all(has_split):
        missing = next(f.image for f in capture.frames if f.split is None)
        raise InputError(f"{missing}: the {capture.layout} layout gives a split for some frames but not this one")
    if all(has_split) and not any(f.split == "train" for f in capture.frames):
        raise InputError(f"{capture.root}: no training frames in the {capture.layout} layout's split")
    return capture


def opencv_to_opengl(c2w: np.ndarray) -> np.ndarray:
    """Flip camera y and z: OpenCV (x right, y down, z forward) <-> OpenGL/nerfstudio (y up, z back)."""
    return c2w @ np.diag([1.0, -1.0, -1.0, 1.0])


def interval_split(num_frames: int, every: int = 8) -> List[Split]:
    """Every `every`-th frame in capture order, starting with the first, is held out (the 3DGS
    `llffhold` and nerfstudio 'interval' rule)."""
    return ["test" if i % every == 0 else "train" for i in range(num_frames)]


def fraction_split(num_frames: int, train_fraction: float = 0.9) -> List[Split]:
    """Evenly spaced training frames, first and last included; the rest held out (nerfstudio's
    'fraction' rule)."""
    num_train = int(np.ceil(num_frames * train_fraction))
    train = set(np.linspace(0, num_frames - 1, num_train, dtype=int).tolist())
    return ["train" if i in train else "test" for i in range(num_frames)]
