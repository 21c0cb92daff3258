"""OpenDroneMap / OpenSfM reconstructions: a drone survey's poses, cameras, points and georeference.

ODM leaves `opensfm/reconstruction.json` in its project folder (beside `images/`); OpenSfM alone
leaves `reconstruction.json` in its dataset folder. The file is a list of reconstructions (the
largest is read), each with (OpenSfM's documentation, "Reconstruction file format"):
- `cameras`: id -> `projection_type` (perspective, brown, ...), `width`, `height`, focal lengths
  (`focal`, or `focal_x`/`focal_y`) and principal point offsets (`c_x`, `c_y`) normalised by the
  image's larger side, distortion `k1`, `k2` (brown: also `k3`, `p1`, `p2`, OpenCV's meaning);
- `shots`: image name -> `camera`, and its pose as world-to-camera `rotation` (an axis-angle
  vector) and `translation`, camera axes as OpenCV's;
- `points`: id -> `coordinates`, `color`;
- the world frame is topocentric east-north-up metres around `reference_lla` (in the file, or in
  `reference_lla.json` beside it: latitude, longitude, altitude).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import List, Optional, Tuple

import cv2
import numpy as np

from thermal_wild_ns.data.capture import ThermalFrame
from thermal_wild_ns.data.georeference import Georeference, geodetic_to_ecef
from thermal_wild_ns.errors import InputError, faults_named

PROJECTIONS = ("perspective", "simple_radial", "radial", "brown")
"""OpenSfM camera models read (pinhole with radial, and Brown's with tangential, distortion)."""


def _camera(camera_id: str, spec: dict, path: Path):
    kind = spec.get("projection_type", "perspective")
    if kind not in PROJECTIONS:
        raise InputError(f"{path}: camera '{camera_id}' is a {kind} camera; read are {', '.join(PROJECTIONS)}")
    try:
        width, height = int(spec["width"]), int(spec["height"])
        size = max(width, height)
        fx = float(spec.get("focal_x", spec.get("focal"))) * size
        fy = float(spec.get("focal_y", spec.get("focal"))) * size
    except (KeyError, TypeError, ValueError) as err:
        raise InputError(f"{path}: camera '{camera_id}' lacks its size or focal length ({err})") from None
    cx, cy = width / 2 + float(spec.get("c_x", 0.0)) * size, height / 2 + float(spec.get("c_y", 0.0)) * size
    k = [float(spec.get(name, 0.0)) for name in ("k1", "k2", "k3")]
    distortion = np.array([*k, 0.0, float(spec.get("p1", 0.0)), float(spec.get("p2", 0.0))])
    return width, height, fx, fy, cx, cy, distortion


def read_reconstruction(path: Path):
    """(shots in name order as (image name, ThermalFrame with no image yet: OpenCV axes, the
    reconstruction's east-north-up metres), sparse points [N, 3] or None, georeference or None) of
    the largest reconstruction in an OpenSfM `reconstruction.json`."""
    try:
        text = Path(path).read_bytes()
    except OSError as err:
        raise InputError(f"{path}: not a readable OpenSfM reconstruction ({err})") from None
    with faults_named(path, "not a readable OpenSfM reconstruction", cv2.error):
        return _reconstruction(json.loads(text.decode("utf-8")), Path(path))


def _reconstruction(reconstructions, path: Path):
    if not isinstance(reconstructions, list) or not reconstructions:
        raise InputError(f"{path}: expected a list of reconstructions (OpenSfM's reconstruction.json)")
    reconstruction = max(reconstructions, key=lambda r: len(r.get("shots", {})))
    cameras = {cid: _camera(cid, spec, path) for cid, spec in reconstruction.get("cameras", {}).items()}
    shots: List[Tuple[str, ThermalFrame]] = []
    for name, shot in sorted(reconstruction.get("shots", {}).items()):
        if shot.get("camera") not in cameras:
            raise InputError(f"{path}: shot '{name}' names camera '{shot.get('camera')}', which it does not define")
        rotation, _ = cv2.Rodrigues(np.asarray(shot["rotation"], dtype=np.float64))
        w2c = np.eye(4)
        w2c[:3, :3], w2c[:3, 3] = rotation, np.asarray(shot["translation"], dtype=np.float64)
        width, height, fx, fy, cx, cy, distortion = cameras[shot["camera"]]
        shots.append((name, ThermalFrame(Path(), np.linalg.inv(w2c), fx, fy, cx, cy, width, height, distortion.copy())))
    if not shots:
        raise InputError(f"{path}: no shot in its reconstructions (did OpenSfM align any image?)")
    points = reconstruction.get("points") or {}
    xyz = np.array([p["coordinates"] for p in points.values()], dtype=np.float64) if points else None
    return shots, xyz, _georeference(reconstruction, Path(path))


def _georeference(reconstruction: dict, path: Path) -> Optional[Georeference]:
    lla = reconstruction.get("reference_lla")
    beside = path.parent / "reference_lla.json"
    if lla is None and beside.is_file():
        lla = json.loads(beside.read_text())
    if not lla:
        return None
    lat, lon, alt = float(lla["latitude"]), float(lla["longitude"]), float(lla["altitude"])
    return Georeference(tuple(float(v) for v in geodetic_to_ecef(lat, lon, alt)), None, str(path))
