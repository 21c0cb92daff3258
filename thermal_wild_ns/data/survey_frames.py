"""A drone survey's thermal frames as the drone wrote them, and each one's °C.

A DJI M30T, M3T, M4T or H20T writes its visible photos (`_W` wide, `_Z` zoom, `_V` visible, `_S` the
M3T's visible) beside its thermal ones (`_T`, `_R`) in one folder. The thermal frames are picked by the DJI
suffix and by their content (a radiometric record: FLIR's or DJI's), never by their name alone; the visible ones
are left out and counted. Each thermal frame gets its own calibration to °C at its own measurement settings (the
files of one flight differ, e.g. in the rangefinder's distance) or at the user's (`MeasurementSettings`)."""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import List, Optional, Sequence, Tuple

from thermal_wild_ns.data.celsius import (
    DJI_CONVERTER_INSTALL,
    FILE_SETTINGS,
    CelsiusCalibration,
    FlirCalibration,
    MeasurementSettings,
    dji_calibrations,
    dji_converter,
    merged_calibration,
)
from thermal_wild_ns.data.frame_files import file_kind, image_files
from thermal_wild_ns.data.rjpeg import is_radiometric_jpeg, read_rjpeg
from thermal_wild_ns.errors import InputError, MissingInput

FRAME_FOLDERS = ("rjpeg", "images", "thermal", "")
"""Where a drone survey's frames are looked for (the first folder with thermal frames)."""

DJI_VISIBLE = re.compile(r"_(W|Z|V|S)$", re.IGNORECASE)
"""The stems of DJI's visible photos (wide, zoom, visible, the M3T's second camera)."""
DJI_THERMAL = re.compile(r"_(T|R)$", re.IGNORECASE)
"""The stems of DJI's thermal frames."""


@dataclass(frozen=True)
class SurveyFrames:
    folder: Path
    thermal: Tuple[Path, ...]
    """In file-name order, which is capture order for drone files (DJI_0001, ...)."""
    visible: Tuple[Path, ...]
    """Visible photos beside them, left out."""


def is_thermal_frame(path: Path) -> bool:
    """A survey's thermal frame: no DJI visible suffix, and a radiometric JPEG, a 16-bit PNG/TIFF frame, or a
    JPEG named as DJI's thermal frames (read later as one: a file without its records is then named)."""
    if DJI_VISIBLE.search(path.stem):
        return False
    if file_kind(path) != "jpeg":
        return True
    return is_radiometric_jpeg(path) or bool(DJI_THERMAL.search(path.stem))


def survey_frames(root: Path) -> SurveyFrames:
    """The thermal frames of the first of `FRAME_FOLDERS` that holds any (the visible photos beside them counted,
    said once in the log); an `InputError` for a folder of visible photos alone, a `MissingInput` for no frames."""
    for name in FRAME_FOLDERS:
        folder = root / name
        files = image_files(folder) if folder.is_dir() else []
        if not files:
            continue
        thermal = [p for p in files if is_thermal_frame(p)]
        visible = tuple(p for p in files if p not in set(thermal))
        if not thermal:
            raise InputError(
                f"{folder}: its {len(files)} image(s) are visible photos ({files[0].name}, ...: DJI's _W/_Z/_V/_S "
                "files or JPEGs without thermal records), no thermal frame to train on: the thermal ones are the "
                "radiometric JPEGs the thermal camera wrote (DJI: *_T.jpg / *_R.jpg)"
            )
        if visible:
            warnings.warn(
                f"{folder}: {len(visible)} visible photo(s) beside the {len(thermal)} thermal frame(s) are left out "
                f"({', '.join(p.name for p in visible[:3])}{' ...' if len(visible) > 3 else ''})",
                stacklevel=2,
            )
        return SurveyFrames(folder, tuple(thermal), visible)
    folders = ", ".join(f + "/" for f in FRAME_FOLDERS if f)
    raise MissingInput(f"{root}: no frames in any of {folders} or the folder itself")


def survey_celsius(
    paths: Sequence[Path], folder: Path, settings: MeasurementSettings = FILE_SETTINGS
) -> Tuple[Optional[CelsiusCalibration], List[Optional[CelsiusCalibration]]]:
    """The °C calibration of each frame at its own measurement settings or the user's `settings` (None for a
    frame that carries none: a 16-bit TIFF), and the capture's reference for renders at no frame's own state
    (the canonical state, the exports): the first frame's FLIR calibration, or DJI's converter's table over all
    frames. DJI's format without the converter: None for all, said in the log once with how to install it."""
    jpegs = [p for p in paths if file_kind(p) == "jpeg"]
    if not jpegs:
        return None, [None] * len(paths)
    read = {p: read_rjpeg(p, decode=False) for p in jpegs}  # calibrations; DJI's rasters (stored plain)
    own: dict = {p: r.calibration.with_settings(settings) for p, r in read.items() if r.calibration is not None}
    dji = [p for p, r in read.items() if r.calibration is None]
    if dji and dji_converter() is None:
        warnings.warn(
            f"{folder}: DJI-format R-JPEGs train on their raw counts, without °C: to have °C, {DJI_CONVERTER_INSTALL}",
            stacklevel=2,
        )
    elif dji:
        tables = dji_calibrations(dji, [read[p].raw for p in dji], [read[p].camera for p in dji], settings)
        own.update(zip(dji, tables))
    per_frame = [own.get(p) for p in paths]
    found = [c for c in per_frame if c is not None]
    if not found or len(found) < len(jpegs):
        return None, per_frame
    if isinstance(found[0], FlirCalibration):
        differing = sorted(p.name for p, c in zip(paths, per_frame) if c is not None and c != found[0])
        if differing:
            warnings.warn(
                f"{folder}: {len(differing)} frame(s) carry other measurement settings than the first "
                f"({', '.join(differing[:5])}): each frame's °C use its own, renders at the canonical state the "
                "first frame's",
                stacklevel=2,
            )
        return found[0], per_frame
    return merged_calibration(found), per_frame
