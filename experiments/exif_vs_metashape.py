"""How far the EXIF route's poses (GPS + gimbal priors refined by SfM) lie from a photogrammetry
alignment of the same frames (Metashape's, made with ground-control markers).

Both captures are taken to WGS84 geocentric coordinates through their georeferences; the EXIF
route's camera centres are then registered to Metashape's by a similarity (Umeyama), and the
remaining camera-centre distances and rotation differences are reported (median, max), with the
offset before registration (what the GPS gets wrong) and the gimbal priors' own rotation error.

    python -m experiments.exif_vs_metashape ../shared/data/flight2 --out docs/results/flight2_exif/registration.json
    python -m experiments.exif_vs_metashape ../shared/data/flight2 \
        --lens-calibration ../shared/data/flight2/metashape/FlirModel_XT.xml --out ...
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Dict, Optional

import numpy as np

from thermal_wild_ns.data.capture import ThermalCapture
from thermal_wild_ns.data.exif import read_frame_prior
from thermal_wild_ns.data.surveys import read_exif_gps, read_metashape


def _to_ecef(capture: ThermalCapture) -> Dict[str, np.ndarray]:
    to_ecef = np.linalg.inv(capture.georeference.ecef_to_local())
    return {frame.image.name: to_ecef @ frame.camera_to_world for frame in capture.frames}


def similarity(source: np.ndarray, target: np.ndarray):
    """(s, R, t) minimising |s R source + t - target|² over [N, 3] point pairs (Umeyama 1991)."""
    mean_s, mean_t = source.mean(0), target.mean(0)
    a, b = source - mean_s, target - mean_t
    u, singular, vt = np.linalg.svd(b.T @ a / len(a))
    d = np.eye(3)
    d[2, 2] = np.sign(np.linalg.det(u @ vt))
    rotation = u @ d @ vt
    scale = np.trace(np.diag(singular) @ d) / (a**2).sum(1).mean()
    return scale, rotation, mean_t - scale * rotation @ mean_s


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(np.clip((np.trace(a.T @ b) - 1.0) / 2.0, -1.0, 1.0)))


def _summary(values) -> Dict[str, float]:
    return {"median": float(np.median(values)), "max": float(np.max(values))}


def compare(root: Path, lens_calibration: Optional[Path], cache_root: Optional[Path]) -> Dict:
    exif = read_exif_gps(root, cache_root=cache_root, lens_calibration=lens_calibration)
    reference = read_metashape(root)
    ours, theirs = _to_ecef(exif), _to_ecef(reference)
    names = sorted(set(ours) & set(theirs))
    a = np.stack([ours[n][:3, 3] for n in names])
    b = np.stack([theirs[n][:3, 3] for n in names])
    scale, rotation, translation = similarity(a, b)
    registered = (scale * (rotation @ a.T)).T + translation
    to_local = reference.georeference.ecef_to_local()[:3, :3]
    ecef_to_exif_local = exif.georeference.ecef_to_local()
    gimbal = []
    for n in names:  # the gimbal prior's rotation, in ECEF, against Metashape's
        prior = read_frame_prior(root / "rjpeg" / n).camera_to_enu(exif.georeference)
        gimbal.append(angle_deg(np.linalg.inv(ecef_to_exif_local)[:3, :3] @ prior[:3, :3], theirs[n][:3, :3]))
    offset_local = (a - b) @ to_local.T
    return {
        "data": str(root),
        "lens_calibration": str(lens_calibration) if lens_calibration else None,
        "frames_compared": len(names),
        "frames_metashape": len(reference.frames),
        "frames_exif_route": len(exif.frames),
        "before_registration": {
            "centre_distance_m": _summary(np.linalg.norm(a - b, axis=1)),
            "mean_offset_enu_m": [float(v) for v in offset_local.mean(0)],
            "rotation_deg": _summary([angle_deg(ours[n][:3, :3], theirs[n][:3, :3]) for n in names]),
            "gimbal_prior_rotation_deg": _summary(gimbal),
        },
        "registered": {
            "scale": float(scale),
            "centre_distance_m": _summary(np.linalg.norm(registered - b, axis=1)),
            "rotation_deg": _summary(
                [angle_deg(rotation @ ours[n][:3, :3], theirs[n][:3, :3]) for n in names],
            ),
        },
        "camera_spread_m": float(np.linalg.norm(b - b.mean(0), axis=1).max()),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", type=Path, help="a drone survey folder with frames and a Metashape XML")
    parser.add_argument("--lens-calibration", type=Path, default=None)
    parser.add_argument("--cache-dir", type=Path, default=None)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    result = compare(args.data, args.lens_calibration, args.cache_dir)
    text = json.dumps(result, indent=1)
    print(text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
