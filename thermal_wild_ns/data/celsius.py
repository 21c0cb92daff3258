"""What turns a thermal camera's raw counts into °C, file by file:

- **FLIR format** (FLIR cameras; DJI Zenmuse XT, XT2, XT R): the standard FLIR conversion, the Planck curve with
  the file's measurement settings (emissivity, object distance, reflected and atmospheric temperature, humidity)
  and the atmosphere's transmission over the distance (`FlirCalibration`).
- **DJI format** (H20T, H30T, M30T, M3T, M3TD, M4T, M2EA, XT S): DJI's own conversion, which is no published
  formula. It runs as a separate program, `dji-thermal-cli` (a pure-Python port of DJI's Thermal SDK, AGPL-3.0:
  called as a command on the files, never imported, so its licence stays its own; `docs/rjpeg.md`), installed by
  the setup command in an environment of its own. Its °C of a file is a function of the raw count for that file's
  settings, so each file gets a table raw count -> °C (`DjiCalibration`).

A user may override the settings for a whole capture (`MeasurementSettings`, the dataparser's options); what a
file says is used otherwise. DJI's SDK takes an object distance only within the camera's range (1-25 m on most
of its cameras): a farther one (a drone at 40-120 m) is clamped to the range's end, and the run says so.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import warnings
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple, Union

import cv2
import numpy as np

from thermal_wild_ns.errors import InputError

DJI_CONVERTER = "dji-thermal-cli"
"""The command that turns DJI-format R-JPEGs into °C (`dji-thermal-cli` 1.4.0, AGPL-3.0), run as a program."""
DJI_CONVERTER_ENV = "THERMAL_WILD_NS_DJI_CLI"
"""Environment variable naming that command where it is neither beside this Python nor on PATH."""
DJI_CONVERTER_INSTALL = (
    "run the README's setup command, which installs DJI's converter in an environment of its own "
    "(.venv/dji-converter); elsewhere `pipx install --python python3.12 dji-thermal-cli`, or name it with "
    f"{DJI_CONVERTER_ENV}=/path/to/dji-thermal-cli. DJI's format has no published formula; without the converter "
    "the raw counts train the model all the same, without °C"
)


class NoCelsiusDecoder(InputError):
    """The file's raw counts are read, but what converts them to °C is not installed (or refused the file)."""


@dataclass(frozen=True)
class MeasurementSettings:
    """Measurement settings for every file of a capture, in place of what each file says (None: the file's)."""

    emissivity: Optional[float] = None
    """0..1."""
    object_distance: Optional[float] = None
    """Metres."""
    reflected_temperature: Optional[float] = None
    """°C."""
    atmospheric_temperature: Optional[float] = None
    """°C (DJI: the ambient temperature)."""
    relative_humidity: Optional[float] = None
    """Percent."""

    def __post_init__(self) -> None:
        checks = {
            "emissivity": (self.emissivity, 0.0, 1.0),
            "object_distance": (self.object_distance, 0.0, math.inf),
            "relative_humidity": (self.relative_humidity, 0.0, 100.0),
        }
        for name, (value, low, high) in checks.items():
            if value is not None and not (low < value <= high and math.isfinite(value)):
                raise InputError(f"measurement setting {name} {value}: must be in ({low:g}, {high:g}]")

    def given(self) -> Dict[str, float]:
        return {k: v for k, v in asdict(self).items() if v is not None}

    def describe(self) -> str:
        given = self.given()
        return ", ".join(f"{k} {v:g}" for k, v in given.items()) if given else "as each file says"


@dataclass(frozen=True)
class FlirCalibration:
    """A FLIR-format file's calibration: what turns its raw counts into °C."""

    planck_r1: float
    planck_r2: float
    planck_b: float
    planck_f: float
    planck_o: float
    emissivity: float
    object_distance: float
    """Metres."""
    reflected_temperature: float
    """Kelvin, as stored."""
    atmospheric_temperature: float
    """Kelvin."""
    ir_window_temperature: float
    """Kelvin."""
    ir_window_transmission: float
    relative_humidity: float
    """Fraction 0..1."""
    alpha1: float
    alpha2: float
    beta1: float
    beta2: float
    atmospheric_trans_x: float

    def with_settings(self, settings: MeasurementSettings) -> "FlirCalibration":
        """This calibration with the user's settings in place of the file's."""
        given = settings.given()
        changes = {k: given[k] for k in ("emissivity", "object_distance") if k in given}
        for name in ("reflected_temperature", "atmospheric_temperature"):
            if name in given:
                changes[name] = given[name] + 273.15
        if "relative_humidity" in given:
            changes["relative_humidity"] = given["relative_humidity"] / 100.0
        return replace(self, **changes)

    def _radiance(self, kelvin: float) -> float:
        """A black body at `kelvin`, in raw counts (the inverse of the Planck curve below)."""
        return self.planck_r1 / (self.planck_r2 * (math.exp(self.planck_b / kelvin) - self.planck_f)) - self.planck_o

    def atmospheric_transmission(self) -> float:
        """Of the air between object and camera (half the distance each side of the IR window)."""
        t_c = self.atmospheric_temperature - 273.15
        h2o = self.relative_humidity * math.exp(1.5587 + 0.06939 * t_c - 0.00027816 * t_c**2 + 0.00000068455 * t_c**3)
        d, x = math.sqrt(self.object_distance / 2), self.atmospheric_trans_x
        return x * math.exp(-d * (self.alpha1 + self.beta1 * math.sqrt(h2o))) + (1 - x) * math.exp(
            -d * (self.alpha2 + self.beta2 * math.sqrt(h2o))
        )

    def celsius(self, raw: np.ndarray) -> np.ndarray:
        """Raw counts [H, W] -> °C [H, W] float32: the object's own radiance, after the reflected
        surroundings, the atmosphere and the IR window are taken out."""
        e, tau, window = self.emissivity, self.atmospheric_transmission(), self.ir_window_transmission
        reflected = (1 - e) / e * self._radiance(self.reflected_temperature)
        atmosphere = (1 - tau) / e / tau * self._radiance(self.atmospheric_temperature)
        window_own = (1 - window) / e / tau / window * self._radiance(self.ir_window_temperature)
        atmosphere_2 = (1 - tau) / e / tau / window / tau * self._radiance(self.atmospheric_temperature)
        obj = raw.astype(np.float64) / e / tau / window / tau - atmosphere - atmosphere_2 - window_own - reflected
        kelvin = self.planck_b / np.log(self.planck_r1 / (self.planck_r2 * (obj + self.planck_o)) + self.planck_f)
        return (kelvin - 273.15).astype(np.float32)


@dataclass(frozen=True)
class DjiCalibration:
    """DJI-format files' °C as DJI's converter gives them: a table of raw count -> °C, read off the converter's
    output (DJI's conversion is a function of the raw count for a file's measurement settings). Linear beyond
    the table's ends."""

    raw: Tuple[float, ...]
    """Raw counts, ascending."""
    celsius_of_raw: Tuple[float, ...]
    source: str
    """What made the table (the converter, the files and the settings used)."""

    def celsius(self, raw: np.ndarray) -> np.ndarray:
        table_raw, table_c = np.asarray(self.raw), np.asarray(self.celsius_of_raw)
        values = np.asarray(raw, dtype=np.float64)
        out = np.interp(values, table_raw, table_c)
        if len(table_raw) > 1:  # the table's end slopes beyond its ends
            span = max(1, len(table_raw) // 20)
            low_slope = (table_c[span] - table_c[0]) / (table_raw[span] - table_raw[0])
            high_slope = (table_c[-1] - table_c[-1 - span]) / (table_raw[-1] - table_raw[-1 - span])
            out = np.where(values < table_raw[0], table_c[0] + (values - table_raw[0]) * low_slope, out)
            out = np.where(values > table_raw[-1], table_c[-1] + (values - table_raw[-1]) * high_slope, out)
        return out.astype(np.float32)


FILE_SETTINGS = MeasurementSettings()
"""Each file's own measurement settings (no override)."""

CelsiusCalibration = Union[FlirCalibration, DjiCalibration]
"""What turns a file's raw counts into °C (`.celsius(raw)`)."""


def dji_converter() -> Optional[str]:
    """DJI's converter where it is installed: named by `DJI_CONVERTER_ENV`, beside the Python running this
    package (the setup command links it there), or on PATH; else None."""
    named = os.environ.get(DJI_CONVERTER_ENV)
    if named:
        return shutil.which(named)
    beside = Path(sys.executable).parent / DJI_CONVERTER
    return str(beside) if beside.is_file() and os.access(beside, os.X_OK) else shutil.which(DJI_CONVERTER)


def dji_calibrations(
    paths: Sequence[Path],
    raws: Sequence[np.ndarray],
    cameras: Sequence[str],
    settings: MeasurementSettings = FILE_SETTINGS,
) -> List[DjiCalibration]:
    """Each DJI-format file's own raw -> °C table (its raw raster `raws[k]`, its EXIF camera `cameras[k]` for the
    messages), from DJI's converter run on the files with their embedded settings or the user's `settings`.
    `NoCelsiusDecoder` naming the file where the converter is not installed or gives no °C for it; an
    `InputError` where a setting is outside what the camera accepts (the object distance is clamped instead)."""
    command = dji_converter()
    if command is None:
        raise NoCelsiusDecoder(
            f"{paths[0]}: a DJI-format R-JPEG ({cameras[0]}): to read it in °C, {DJI_CONVERTER_INSTALL}"
        )
    with tempfile.TemporaryDirectory(prefix="dji-celsius-") as work:
        names = [f"{k:05d}_{Path(p).stem}" for k, p in enumerate(paths)]
        inputs = Path(work) / "in"
        inputs.mkdir()
        for name, path in zip(names, paths):  # unique names, whatever folders the files come from
            shutil.copyfile(path, inputs / f"{name}.jpg")
        ranges = _distance_ranges(command, inputs, names)
        groups: Dict[str, List[int]] = {}  # the --distance each file is converted at -> its files
        for k, name in enumerate(names):
            groups.setdefault(_distance_argument(settings, ranges.get(name), paths[k], cameras[k]), []).append(k)
        tables: Dict[int, DjiCalibration] = {}
        for distance, members in groups.items():
            group = Path(work) / f"group-{len(tables)}"
            group.mkdir()
            for k in members:
                (inputs / f"{names[k]}.jpg").rename(group / f"{names[k]}.jpg")
            outputs = Path(work) / f"out-{len(tables)}"
            done = subprocess.run(
                [command, "process", "--input-dir", str(group), "--output-dir", str(outputs), "--quiet"]
                + ["--output", "temp_c:tiff", "--distance", distance]
                + _other_arguments(settings),
                capture_output=True,
                text=True,
            )
            for k in members:
                tables[k] = _table(outputs / f"{names[k]}_temp_c.tiff", raws[k], paths[k], command, done, distance)
    return [tables[k] for k in range(len(paths))]


def _distance_ranges(command: str, folder: Path, names: Sequence[str]) -> Dict[str, Tuple[float, float]]:
    """The object distances (min, max) the camera of each file accepts, as DJI's converter lists them."""
    listed = subprocess.run(
        [command, "list", "--input-dir", str(folder), "--format", "json", "--no-stats"], capture_output=True, text=True
    )
    ranges = {}
    try:
        for entry in json.loads(listed.stdout or "[]"):
            low, high = entry["thermal"]["measurement_params_range"]["distance"]
            ranges[Path(entry["file"]["name"]).stem] = (float(low), float(high))
    except (ValueError, KeyError, TypeError):
        pass  # no ranges listed: the distances go as they are, and the converter says where it refuses one
    return {name: ranges[name] for name in names if name in ranges}


_told_clamped: set = set()  # (asked, used) distances already said in this run's log


def _distance_argument(settings: MeasurementSettings, accepted, path: Path, camera: str) -> str:
    """The converter's --distance for one file: 'embedded' (the file's), else the user's, clamped into the range
    its camera accepts (said once per run)."""
    asked = settings.object_distance
    if asked is None:
        return "embedded"
    if accepted is None:
        return f"{asked:g}"
    used = min(max(asked, accepted[0]), accepted[1])
    if used != asked and (asked, used) not in _told_clamped:
        _told_clamped.add((asked, used))
        warnings.warn(
            f"{path}: DJI's SDK takes object distances of {accepted[0]:g}-{accepted[1]:g} m for the {camera}: "
            f"{used:g} m used for its °C, not the {asked:g} m asked (the atmosphere's correction stops there)",
            stacklevel=4,
        )
    return f"{used:g}"


def _other_arguments(settings: MeasurementSettings) -> List[str]:
    flags = {
        "emissivity": "--emissivity",
        "reflected_temperature": "--reflected-temp",
        "atmospheric_temperature": "--ambient-temp",
        "relative_humidity": "--humidity",
    }
    given = settings.given()
    return [arg for name, flag in flags.items() if name in given for arg in (flag, f"{given[name]:g}")]


def _table(produced: Path, raw: np.ndarray, path: Path, command: str, done, distance: str) -> DjiCalibration:
    """One file's raw -> °C table from the converter's °C raster of it."""
    image = cv2.imread(str(produced), cv2.IMREAD_UNCHANGED) if produced.is_file() else None
    if image is None:
        said = (done.stdout + done.stderr).strip()
        refused = next((line for line in said.splitlines() if "refused" in line or "skip" in line), said[-300:])
        raise NoCelsiusDecoder(f"{path}: DJI's converter ({command}) gave no °C for it: {refused}")
    celsius = image.astype(np.float32)
    if celsius.shape != raw.shape:
        raise NoCelsiusDecoder(f"{path}: DJI's converter gave {celsius.shape[::-1]} °C for a {raw.shape[::-1]} raster")
    counts, first = np.unique(raw.ravel(), return_index=True)
    values = celsius.ravel()[first].astype(np.float64)
    source = f"{Path(command).name} on {Path(path).name}, distance {distance}"
    return DjiCalibration(tuple(float(c) for c in counts), tuple(float(v) for v in values), source)


def merged_calibration(calibrations: Sequence[DjiCalibration]) -> DjiCalibration:
    """One table over several files' (a capture's reference, for renders at no file's state: its counts cover
    every file's): each count's value from the first file that has it."""
    table: Dict[float, float] = {}
    for calibration in calibrations:
        for count, value in zip(calibration.raw, calibration.celsius_of_raw):
            table.setdefault(count, value)
    counts = sorted(table)
    first = calibrations[0].source.split(" on ")[0]
    return DjiCalibration(tuple(counts), tuple(table[c] for c in counts), f"{first} on {len(calibrations)} file(s)")
