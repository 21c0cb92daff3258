"""Where a capture sits on the Earth: a local east-north-up frame in metres, its origin, and the
project's coordinate system; the geodesy the photogrammetry layouts need (WGS84)."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Optional, Tuple

import numpy as np

WGS84_A, WGS84_F = 6378137.0, 1 / 298.257223563


@dataclass(frozen=True)
class Georeference:
    """Where a capture's local frame sits on the Earth: x east, y north, z up, in metres, with its
    origin at `origin_ecef` (WGS84 geocentric, metres)."""

    origin_ecef: Tuple[float, float, float]
    crs_wkt: Optional[str] = None
    """The project's coordinate system (Metashape's `<reference>`), for outputs in it."""
    source: str = ""

    @property
    def latitude(self) -> float:
        return ecef_to_geodetic(np.asarray(self.origin_ecef))[0]

    @property
    def longitude(self) -> float:
        return ecef_to_geodetic(np.asarray(self.origin_ecef))[1]

    @property
    def height(self) -> float:
        """Of the origin above the WGS84 ellipsoid, metres."""
        return ecef_to_geodetic(np.asarray(self.origin_ecef))[2]

    def ecef_to_local(self) -> np.ndarray:
        """[4, 4]: geocentric -> local east-north-up."""
        lat, lon = math.radians(self.latitude), math.radians(self.longitude)
        east = [-math.sin(lon), math.cos(lon), 0.0]
        north = [-math.sin(lat) * math.cos(lon), -math.sin(lat) * math.sin(lon), math.cos(lat)]
        up = [math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon), math.sin(lat)]
        m = np.eye(4)
        m[:3, :3] = np.array([east, north, up])
        m[:3, 3] = -m[:3, :3] @ np.asarray(self.origin_ecef)
        return m

    def as_dict(self) -> dict:
        return {
            "frame": "local east-north-up, metres",
            "origin_ecef": list(self.origin_ecef),
            "latitude": self.latitude,
            "longitude": self.longitude,
            "height": self.height,
            "crs_wkt": self.crs_wkt,
            "source": self.source,
        }


def ecef_to_geodetic(xyz: np.ndarray) -> Tuple[float, float, float]:
    """WGS84 geocentric -> (latitude°, longitude°, ellipsoidal height m), by Bowring's iteration."""
    x, y, z = (float(v) for v in xyz)
    e2 = WGS84_F * (2 - WGS84_F)
    lon = math.atan2(y, x)
    p = math.hypot(x, y)
    lat = math.atan2(z, p * (1 - e2))
    for _ in range(6):
        n = WGS84_A / math.sqrt(1 - e2 * math.sin(lat) ** 2)
        height = p / math.cos(lat) - n
        lat = math.atan2(z, p * (1 - e2 * n / (n + height)))
    n = WGS84_A / math.sqrt(1 - e2 * math.sin(lat) ** 2)
    return math.degrees(lat), math.degrees(lon), p / math.cos(lat) - n


def geodetic_to_ecef(latitude: float, longitude: float, height: float) -> np.ndarray:
    """WGS84 (latitude°, longitude°, ellipsoidal height m) -> geocentric [3] metres."""
    e2 = WGS84_F * (2 - WGS84_F)
    lat, lon = math.radians(latitude), math.radians(longitude)
    n = WGS84_A / math.sqrt(1 - e2 * math.sin(lat) ** 2)
    return np.array(
        [
            (n + height) * math.cos(lat) * math.cos(lon),
            (n + height) * math.cos(lat) * math.sin(lon),
            (n * (1 - e2) + height) * math.sin(lat),
        ]
    )


def datum_to_wgs84(crs_wkt: Optional[str]) -> np.ndarray:
    """[4, 4] from the geocentric frame of the project's datum (where Metashape's chunk transform
    lands) to WGS84's: the WKT's `TOWGS84[dx, dy, dz, rx, ry, rz, ds]` (metres, arc-seconds, ppm,
    position-vector convention); identity where it has none (a WGS84 project). On a CH1903+
    project the shift is about 790 m: skipped, heights would be off by hundreds of metres."""
    m = np.eye(4)
    found = re.search(r"TOWGS84\[([^\]]*)\]", crs_wkt or "")
    if found is None:
        return m
    values = [float(v) for v in found.group(1).split(",")] + [0.0] * 7
    dx, dy, dz, rx, ry, rz, ds = values[:7]
    rx, ry, rz = (math.radians(v / 3600) for v in (rx, ry, rz))
    m[:3, :3] = (1 + ds * 1e-6) * np.array([[1, -rz, ry], [rz, 1, -rx], [-ry, rx, 1]])
    m[:3, 3] = [dx, dy, dz]
    return m
