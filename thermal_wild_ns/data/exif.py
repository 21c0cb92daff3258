"""What a drone frame says about itself in its EXIF and XMP (`FramePrior`): where it was taken (EXIF GPS; the
altitude is the GPS's, above sea level), where the camera looked (DJI's XMP `GimbalYaw/Pitch/RollDegree`, or
FLIR's `Yaw/Pitch/Roll`), and its focal length in pixels where the file says enough (the 35 mm equivalent focal
length, a FLIR record's field of view, or the focal length with the focal-plane resolution). GPS is metres off
and the gimbal degrees off: too coarse to train on, enough to say which frames overlap and where the site is
(`exif_sfm.py` refines them)."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence, Tuple

import numpy as np
from PIL import Image, UnidentifiedImageError

from thermal_wild_ns.data.georeference import Georeference, geodetic_to_ecef
from thermal_wild_ns.data.rjpeg import flir_field_of_view
from thermal_wild_ns.errors import InputError

FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)
"""The diagonal the 35 mm equivalent focal length is defined on."""

EXIF_GPS, EXIF_SUB_IFD = 0x8825, 0x8769
_FOCAL_LENGTH, _FOCAL_35MM, _PLANE_X_RESOLUTION, _PLANE_UNIT = 0x920A, 0xA405, 0xA20E, 0xA210
_UNIT_MM = {2: 25.4, 3: 10.0, 4: 1.0}
"""EXIF FocalPlaneResolutionUnit -> millimetres per unit (inch, cm, mm)."""


@dataclass(frozen=True)
class FramePrior:
    """What one frame's own metadata says about its camera."""

    latitude: float
    longitude: float
    altitude: float
    """EXIF GPSAltitude, metres above sea level (taken as above the WGS84 ellipsoid: the geoid's
    height, tens of metres, is not applied, so absolute heights carry it)."""
    yaw: Optional[float]
    """Gimbal heading, degrees clockwise from north; None where the XMP has no gimbal angles."""
    pitch: Optional[float]
    """Degrees above the horizon (-90: straight down)."""
    roll: Optional[float]

    def camera_to_enu(self, georeference: Georeference) -> np.ndarray:
        """[4, 4] camera (OpenCV axes) -> the georeference's east-north-up frame; a camera looking
        straight down, image top to the north, where the gimbal angles are missing."""
        pose = np.eye(4)
        if self.yaw is None:
            pose[:3, :3] = gimbal_rotation(0.0, -90.0, 0.0)
        else:
            pose[:3, :3] = gimbal_rotation(self.yaw, self.pitch, self.roll)
        ecef = geodetic_to_ecef(self.latitude, self.longitude, self.altitude)
        to_local = georeference.ecef_to_local()
        pose[:3, 3] = to_local[:3, :3] @ ecef + to_local[:3, 3]
        return pose


def gimbal_rotation(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """[3, 3] camera (OpenCV: x right, y down, z forward) -> east-north-up, for a gimbal's heading
    (degrees clockwise from north), pitch (up from the horizon) and roll (right side down), applied
    in that order as drones report them."""
    yaw, pitch, roll = (math.radians(v) for v in (yaw, pitch, roll))
    level = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # columns: right, down, forward
    heading = np.array([[math.cos(yaw), math.sin(yaw), 0.0], [-math.sin(yaw), math.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
    tilt = np.array(
        [[1.0, 0.0, 0.0], [0.0, math.cos(pitch), -math.sin(pitch)], [0.0, math.sin(pitch), math.cos(pitch)]]
    )
    bank = np.array([[math.cos(roll), 0.0, math.sin(roll)], [0.0, 1.0, 0.0], [-math.sin(roll), 0.0, math.cos(roll)]])
    return heading @ tilt @ bank @ level


def _rational(value) -> float:
    return float(value[0]) / float(value[1]) if isinstance(value, tuple) else float(value)


def _degrees(dms, reference: str) -> float:
    degrees, minutes, seconds = (_rational(v) for v in dms)
    return (degrees + minutes / 60.0 + seconds / 3600.0) * (-1.0 if reference in ("S", "W") else 1.0)


def _xmp_angle(xmp: str, *names: str) -> Optional[float]:
    for name in names:  # attribute (DJI) or element (FLIR) form
        found = re.search(rf'{name}\s*=\s*"([-+0-9.eE]+)"', xmp) or re.search(rf"{name}>([-+0-9.eE]+)<", xmp)
        if found:
            return float(found.group(1))
    return None


def focal_length_px(path: Path, width: int, height: int) -> Tuple[Optional[float], str]:
    """The focal length in pixels of the file's `width` x `height` thermal raster, and what gave it:
    the EXIF 35 mm equivalent (on the frame's diagonal, as CIPA defines it), a FLIR record's field
    of view, or the EXIF focal length with the focal-plane resolution; (None, "") where none is
    recorded."""

    try:
        with Image.open(path) as image:
            sub = image.getexif().get_ifd(EXIF_SUB_IFD)
    except (OSError, UnidentifiedImageError) as err:
        raise InputError(f"{path}: unreadable ({err})") from None
    focal_35 = sub.get(_FOCAL_35MM)
    if focal_35:
        return float(focal_35) * math.hypot(width, height) / FULL_FRAME_DIAGONAL_MM, "EXIF 35 mm equivalent"
    field_of_view = flir_field_of_view(path)
    if field_of_view:
        return width / 2.0 / math.tan(math.radians(field_of_view) / 2.0), "FLIR field of view"
    focal_mm, plane_x, unit = sub.get(_FOCAL_LENGTH), sub.get(_PLANE_X_RESOLUTION), sub.get(_PLANE_UNIT, 2)
    if focal_mm and plane_x and unit in _UNIT_MM:
        # the resolution is of the image the EXIF describes, which may be the preview: scale to the raster
        described = sub.get(0xA002) or width
        return _rational(focal_mm) * _rational(plane_x) / _UNIT_MM[unit] * width / float(described), "EXIF focal plane"
    return None, ""


def read_frame_prior(path: Path) -> Optional[FramePrior]:
    """The frame's GPS position and gimbal angles; None where its EXIF holds no GPS position (reads
    the file's header only)."""

    try:
        with Image.open(path) as image:
            exif, xmp = image.getexif(), image.info.get("xmp", b"")
    except (OSError, UnidentifiedImageError) as err:
        raise InputError(f"{path}: unreadable ({err})") from None
    gps = exif.get_ifd(EXIF_GPS)
    if not gps or 2 not in gps or 4 not in gps:
        return None
    altitude = _rational(gps.get(6, 0.0)) * (-1.0 if gps.get(5) in (b"\x01", 1) else 1.0)
    text = xmp.decode("utf-8", "replace") if isinstance(xmp, bytes) else str(xmp)
    yaw = _xmp_angle(text, "drone-dji:GimbalYawDegree", "Camera:Yaw")
    pitch = _xmp_angle(text, "drone-dji:GimbalPitchDegree", "Camera:Pitch")
    roll = _xmp_angle(text, "drone-dji:GimbalRollDegree", "Camera:Roll")
    if yaw is None or pitch is None:
        yaw = pitch = roll = None
    return FramePrior(
        _degrees(gps[2], gps.get(1, "N")),
        _degrees(gps[4], gps.get(3, "E")),
        altitude,
        yaw,
        pitch,
        roll or 0.0 if yaw is not None else None,
    )


def survey_georeference(priors: Sequence[FramePrior], source: str) -> Georeference:
    """A local east-north-up frame around the frames' mean GPS position."""
    ecef = np.mean([geodetic_to_ecef(p.latitude, p.longitude, p.altitude) for p in priors], axis=0)
    return Georeference(tuple(float(v) for v in ecef), None, source)
