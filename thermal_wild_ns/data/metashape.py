"""Agisoft Metashape alignments: a drone survey's poses, sensor calibration and georeference.

A Metashape chunk (`doc.xml` inside a `.psx` project's `chunk.zip`, or File > Export Cameras as
XML) holds per camera a 4x4 camera-to-chunk transform (camera axes x right, y down, z forward:
OpenCV's), the sensors' calibration, and the chunk-to-geocentric transform (rotation, translation,
scale: x_ecef = s R x + t) with the project's coordinate system.

nerfstudio's converter (`ns-process-data metashape`, `process_data/metashape_utils.py` in 1.1.5)
is not reused, for two reasons: it divides the geocentric translation by the scale and keeps it,
so a survey's poses lie about 10^6 units from the origin, where the float32 the dataparser
stores them in resolves centimetres at best; and it copies Metashape's tangential coefficients
P1, P2 to OpenCV's p1, p2, whose roles are swapped (Metashape's P1 is OpenCV's p2: Agisoft's
manual, "Camera models"). Here poses go to a local east-north-up frame in metres around the
cameras' mean position, whose origin (geocentric and geodetic) and the project's coordinate system
are kept as the capture's `Georeference`, so outputs can land where the site is.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import replace
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import numpy as np

from thermal_wild_ns.data.capture import ThermalFrame
from thermal_wild_ns.data.georeference import Georeference, datum_to_wgs84
from thermal_wild_ns.errors import InputError


def _floats(element: Optional[ET.Element], path: Path, what: str) -> np.ndarray:
    if element is None or not (element.text or "").strip():
        raise InputError(f"{path}: Metashape XML without {what}")
    try:
        return np.array([float(v) for v in element.text.split()])
    except ValueError as err:
        raise InputError(f"{path}: Metashape {what} is not numbers ({err})") from None


def _calibrated_frame(calibration: ET.Element, width: int, height: int, path: Path, label: str) -> ThermalFrame:
    """A frame (no image, no pose yet) of the camera a Metashape `<calibration>` describes."""

    def value(name: str) -> float:
        node = calibration.find(name)
        try:
            return float(node.text) if node is not None and node.text else 0.0
        except ValueError:
            raise InputError(f"{path}: Metashape calibration '{label}': {name} is not a number") from None

    f = value("f")
    if f <= 0:
        raise InputError(f"{path}: Metashape calibration '{label}' has no focal length")
    distortion = np.array([value("k1"), value("k2"), value("k3"), value("k4"), value("p2"), value("p1")])
    fx, cx, cy = f + value("b1"), width / 2 + value("cx"), height / 2 + value("cy")
    return ThermalFrame(Path(), np.eye(4), fx, f, cx, cy, width, height, distortion)


def _sensor(element: ET.Element, path: Path) -> Optional[ThermalFrame]:
    calibrations = element.findall("calibration")
    if not calibrations:
        return None
    # the adjusted calibration when the alignment refined it, else the initial one
    calibration = next((c for c in calibrations if c.get("class") == "adjusted"), calibrations[0])
    resolution = calibration.find("resolution")
    if resolution is None:
        resolution = element.find("resolution")
    if resolution is None or element.get("type", "frame") != "frame":
        raise InputError(
            f"{path}: Metashape sensor '{element.get('label')}' is a {element.get('type')} camera; "
            f"only frame (pinhole) cameras are read"
        )
    width, height = int(resolution.get("width")), int(resolution.get("height"))
    return _calibrated_frame(calibration, width, height, path, element.get("label", ""))


def read_lens_calibration(path: Path) -> ThermalFrame:
    """A camera's lens calibration as Metashape and Agisoft Lens export it (File > Export >
    Calibration, XML: `<calibration>` with width, height, f, cx, cy, b1, k1-k4, p1, p2): a frame
    (no image, no pose) with its intrinsics and distortion."""
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as err:
        raise InputError(f"{path}: not a readable calibration XML ({err})") from None
    if root.tag != "calibration":
        raise InputError(f"{path}: not a Metashape / Agisoft Lens calibration (its root is <{root.tag}>)")
    if (root.findtext("projection") or "frame") != "frame":
        raise InputError(f"{path}: a {root.findtext('projection')} camera; only frame (pinhole) cameras are read")
    try:
        width, height = int(root.findtext("width")), int(root.findtext("height"))
    except (TypeError, ValueError):
        raise InputError(f"{path}: calibration without its image width and height") from None
    return _calibrated_frame(root, width, height, path, path.name)


def _chunk_transform(element: Optional[ET.Element], path: Path) -> Optional[np.ndarray]:
    """[4, 4] chunk -> geocentric (s R | t), None where the chunk is not georeferenced."""
    if element is None:
        return None
    rotation = element.find("rotation")
    translation = element.find("translation")
    scale = element.find("scale")
    if rotation is None or translation is None:
        return None
    m = np.eye(4)
    m[:3, :3] = _floats(rotation, path, "chunk rotation").reshape(3, 3) * (
        float(scale.text) if scale is not None else 1.0
    )
    m[:3, 3] = _floats(translation, path, "chunk translation")
    return m


def read_metashape_xml(
    path: Path,
) -> Tuple[List[Tuple[str, ThermalFrame]], Optional[Georeference], List[str]]:
    """The aligned cameras of a Metashape XML (a chunk's `doc.xml` or an exported cameras XML), as
    (label, ThermalFrame with no image yet: OpenCV axes, a local east-north-up frame in metres where
    the chunk is georeferenced, else the chunk's own), with the georeference; and the labels of the
    cameras it could not align (no transform)."""
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as err:
        raise InputError(f"{path}: not a readable Metashape XML ({err})") from None
    chunk = root if root.tag == "chunk" else root.find("chunk")
    if chunk is None:
        raise InputError(f"{path}: not a Metashape XML (no <chunk>)")
    sensors: Dict[str, ThermalFrame] = {}
    for element in chunk.iter("sensor"):
        sensor = _sensor(element, path)
        if sensor is not None:
            sensors[element.get("id")] = sensor
    if not sensors:
        raise InputError(f"{path}: no calibrated sensor in this Metashape XML (align the photos first)")
    components = {
        c.get("id"): _chunk_transform(c.find("transform"), path) for c in chunk.iter("component") if c.get("id")
    }
    chunk_transform = _chunk_transform(chunk.find("transform"), path)
    cameras, unaligned = [], []
    raw: List[Tuple[str, np.ndarray, ThermalFrame]] = []
    for element in chunk.iter("camera"):
        label = element.get("label", "")
        transform = element.find("transform")
        if transform is None or element.get("sensor_id") not in sensors:
            unaligned.append(label)
            continue
        to_world = components.get(element.get("component_id")) if element.get("component_id") else None
        to_world = to_world if to_world is not None else chunk_transform
        pose = _floats(transform, path, f"camera '{label}' transform").reshape(4, 4)
        raw.append((label, (to_world @ pose) if to_world is not None else pose, sensors[element.get("sensor_id")]))
    if not raw:
        raise InputError(f"{path}: no aligned camera in this Metashape XML")
    georeference = None
    if chunk_transform is not None or any(t is not None for t in components.values()):
        reference = chunk.find("reference")
        crs = reference.text if reference is not None else None
        to_wgs84 = datum_to_wgs84(crs)
        origin = to_wgs84[:3, :3] @ np.mean([pose[:3, 3] for _, pose, _ in raw], axis=0) + to_wgs84[:3, 3]
        georeference = Georeference(tuple(float(v) for v in origin), crs, str(path))
        to_local = georeference.ecef_to_local() @ to_wgs84
    else:
        to_local = np.eye(4)
    for label, pose, sensor in raw:
        local = to_local @ pose
        scale = np.cbrt(np.linalg.det(local[:3, :3]))  # the chunk's scale: the camera's axes stay unit
        local[:3, :3] /= scale
        cameras.append((label, replace(sensor, camera_to_world=local, distortion=sensor.distortion.copy())))
    return cameras, georeference, unaligned
