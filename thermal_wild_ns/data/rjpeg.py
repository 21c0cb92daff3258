"""Radiometric JPEGs (R-JPEG), as thermal cameras and drones write them: the sensor's raw counts
behind the 8-bit colour-mapped preview, and what turns them into °C.

Two formats:
- **FLIR** (FLIR cameras; DJI Zenmuse XT, XT2, XT R, whose cores are FLIR's): APP1 segments
  `FLIR\\0` hold an FFF container whose records give the raw raster (`RawData`, a PNG or plain
  16-bit) and the camera's calibration (`CameraInfo`: Planck constants R1, R2, B, F, O; emissivity,
  distance, reflected and atmospheric temperature, humidity, the atmosphere's transmission
  constants). FLIR cameras write the container big-endian, DJI's FLIR-core cameras little-endian
  (ExifTool tells them apart by the header's version number, as here).
- **DJI** (Zenmuse H20T/H20N/H30T, Matrice 30T, Mavic 3T, Matrice 3TD, Matrice 4T, Mavic 2
  Enterprise Advanced, Zenmuse XT S): the raw 16-bit raster sits in APP3 segments (APP4 on the
  XT S), little-endian. DJI's conversion to °C is not a published formula: the raw raster is read
  here, its °C by DJI's converter (`celsius.py`).

FLIR's raw image is stored plain (16-bit, either byte order), as a PNG, or compressed as JPEG-LS
(FLIR's E-series and others), which `pyjpegls` (CharLS) decodes. Every structural fault of a file (cut
short, a byte flipped in its records) is an `InputError` naming it.

The layout of the FLIR records follows ExifTool's `FLIR.pm` tag tables (the offsets below); the
°C conversion is `celsius.FlirCalibration`'s. Each is checked against ExifTool's dumps and the
camera vendor's own temperature rasters (`tests/test_rjpeg.py`).
No library does both formats: flyr, the maintained pure-Python FLIR reader, assumes the
big-endian container and fails on DJI's FLIR-core files (`docs/rjpeg.md` has the comparison).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import cv2
import numpy as np

from thermal_wild_ns.data.celsius import FILE_SETTINGS, FlirCalibration, MeasurementSettings, dji_calibrations
from thermal_wild_ns.data.frame_files import file_kind
from thermal_wild_ns.errors import InputError, faults_named


class NotRadiometric(InputError):
    """A JPEG with no thermal data behind its preview (a visual camera's photo, an exported
    colour-mapped image): never read as temperatures."""


@dataclass(frozen=True)
class RadiometricJpeg:
    """One R-JPEG's thermal content."""

    path: Path
    camera: str
    """EXIF make and model, e.g. 'DJI FLIR' (a Zenmuse XT), 'DJI M3T'."""
    format: str
    """'flir' or 'dji'."""
    raw: Optional[np.ndarray]
    """[H, W] uint16 raw sensor counts, at the thermal sensor's resolution (None where only the
    calibration was read: `read_calibration`)."""
    calibration: Optional[FlirCalibration]
    """FLIR format only."""

    def celsius(self, settings: MeasurementSettings = FILE_SETTINGS) -> np.ndarray:
        """[H, W] float32 °C at the file's measurement settings or the user's `settings`: the FLIR formula, or
        DJI's converter where it is installed; else `NoCelsiusDecoder` naming the file, the camera and how to
        install the converter."""
        if self.calibration is None:
            return dji_calibrations([self.path], [self.raw], [self.camera], settings)[0].celsius(self.raw)
        return self.calibration.with_settings(settings).celsius(self.raw)


# ------------------------------------------------------------------ JPEG segments
def jpeg_segments(data: bytes, path: Path) -> List[Tuple[int, bytes]]:
    """(marker, payload) of each segment before the image data; an `InputError` if not a JPEG."""
    if data[:2] != b"\xff\xd8":
        raise InputError(f"{path}: not a JPEG file")
    segments, i = [], 2
    while i + 4 <= len(data):
        if data[i] != 0xFF:
            raise InputError(f"{path}: damaged JPEG (no segment marker at byte {i})")
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker in (0xDA, 0xD9):  # the image data starts (or the file ends): no metadata after it
            break
        length = struct.unpack(">H", data[i + 2 : i + 4])[0]
        segments.append((marker, data[i + 4 : i + 2 + length]))
        i += 2 + length
    return segments


def _exif_camera(segments: List[Tuple[int, bytes]]) -> str:
    """EXIF Make and Model (the first APP1 'Exif' segment's IFD0), '' where absent."""
    for marker, payload in segments:
        if marker != 0xE1 or not payload.startswith(b"Exif\0\0"):
            continue
        tiff = payload[6:]
        order = "<" if tiff[:2] == b"II" else ">"
        (ifd,) = struct.unpack(order + "I", tiff[4:8])
        (count,) = struct.unpack(order + "H", tiff[ifd : ifd + 2])
        found: Dict[int, str] = {}
        for k in range(count):
            tag, kind, n, value = struct.unpack(order + "HHII", tiff[ifd + 2 + 12 * k : ifd + 14 + 12 * k])
            if tag in (0x010F, 0x0110) and kind == 2:  # Make, Model (ASCII)
                raw = tiff[ifd + 10 + 12 * k : ifd + 14 + 12 * k] if n <= 4 else tiff[value : value + n]
                found[tag] = raw.split(b"\0")[0].decode("latin-1").strip()
        return " ".join(v for v in (found.get(0x010F, ""), found.get(0x0110, "")) if v)
    return ""


# ------------------------------------------------------------------ FLIR
def _flir_container(segments: List[Tuple[int, bytes]]) -> Optional[bytes]:
    """The FFF container of the FLIR APP1 segments, joined in their chunk order; None if none."""
    chunks = {}
    for marker, payload in segments:
        if marker == 0xE1 and payload.startswith(b"FLIR\0") and len(payload) >= 8:
            chunks[payload[6]] = payload[8:]
    return b"".join(chunks[k] for k in sorted(chunks)) if chunks else None


def _flir_records(fff: bytes, path: Path) -> Tuple[str, Dict[int, bytes]]:
    """The container's byte order ('<' or '>') and its records by type."""
    if fff[:4] not in (b"FFF\0", b"AFF\0"):
        raise InputError(f"{path}: its FLIR segments hold no FFF container")
    order = ">"
    version = struct.unpack(">I", fff[20:24])[0]
    if not 100 <= version < 200:  # as ExifTool: a version out of range means the other byte order
        order = "<"
    offset, count = struct.unpack(order + "II", fff[24:32])
    records = {}
    for k in range(count):
        entry = fff[offset + 32 * k : offset + 32 * k + 32]
        if len(entry) < 20:
            raise InputError(f"{path}: FLIR record directory cut short")
        kind, _, _, _, start, length = struct.unpack(order + "HHIIII", entry[:20])
        if kind and kind not in records:
            records[kind] = fff[start : start + length]
    return order, records


def _record_order(record: bytes) -> str:
    """A record's own byte order: its first 16-bit word is 2 (ExifTool's check)."""
    return "<" if struct.unpack("<H", record[:2])[0] < 0x100 else ">"


RAW_DATA, CAMERA_INFO = 1, 32
"""FFF record types (ExifTool FLIR.pm: RawData, CameraInfo)."""
FIELD_OF_VIEW = 0x1B4
"""CameraInfo's horizontal field of view in degrees (float; ExifTool FLIR::CameraInfo FieldOfView)."""

_CAMERA_INFO = {  # field: (byte offset, struct format), ExifTool FLIR::CameraInfo
    "emissivity": (0x20, "f"),
    "object_distance": (0x24, "f"),
    "reflected_temperature": (0x28, "f"),
    "atmospheric_temperature": (0x2C, "f"),
    "ir_window_temperature": (0x30, "f"),
    "ir_window_transmission": (0x34, "f"),
    "relative_humidity": (0x3C, "f"),
    "planck_r1": (0x58, "f"),
    "planck_b": (0x5C, "f"),
    "planck_f": (0x60, "f"),
    "alpha1": (0x70, "f"),
    "alpha2": (0x74, "f"),
    "beta1": (0x78, "f"),
    "beta2": (0x7C, "f"),
    "atmospheric_trans_x": (0x80, "f"),
    "planck_o": (0x308, "i"),
    "planck_r2": (0x30C, "f"),
}


def _flir_raw(record: bytes, path: Path) -> np.ndarray:
    order = _record_order(record)
    width, height = struct.unpack(order + "HH", record[2:6])
    image = record[0x20:]
    if image[:4] == b"\xff\xd8\xff\xf7":  # JPEG-LS (FLIR's E-series and others): CharLS decodes it
        try:
            import jpeg_ls  # here: the light GPU install may have none, and only these files need it
        except ImportError:
            raise InputError(f"{path}: its raw image is JPEG-LS: `pip install pyjpegls` to read it") from None
        try:
            raw = np.asarray(jpeg_ls.decode(np.frombuffer(image, np.uint8)))
        except Exception as err:  # CharLS raises RuntimeError / ValueError on a damaged stream
            raise InputError(f"{path}: its FLIR raw image (JPEG-LS) cannot be decoded ({err})") from None
        if raw.dtype != np.uint16:
            raise InputError(f"{path}: its FLIR raw image (JPEG-LS) holds {raw.dtype} samples, not 16-bit counts")
    elif image[:4] == b"\x89PNG":
        raw = cv2.imdecode(np.frombuffer(image, np.uint8), cv2.IMREAD_UNCHANGED)
        if raw is None or raw.dtype != np.uint16:
            raise InputError(f"{path}: its FLIR raw image (PNG) cannot be decoded")
        raw = raw.byteswap()  # FLIR writes the PNG's 16-bit samples little-endian (ExifTool notes it)
    else:
        if len(image) < 2 * width * height:
            raise InputError(f"{path}: its FLIR raw image is cut short ({len(image)} bytes for {width}x{height})")
        raw = np.frombuffer(image[: 2 * width * height], np.dtype(np.uint16).newbyteorder(order))
        raw = raw.reshape(height, width).astype(np.uint16)
    if raw.shape != (height, width):
        size = f"{raw.shape[1]}x{raw.shape[0]}"
        raise InputError(f"{path}: its FLIR raw image is {size}, its record says {width}x{height}")
    return raw


def _flir_calibration(record: bytes) -> FlirCalibration:
    order = _record_order(record)
    values = {name: struct.unpack_from(order + kind, record, at)[0] for name, (at, kind) in _CAMERA_INFO.items()}
    if values["relative_humidity"] > 2:  # some cameras store percent (ExifTool's conversion)
        values["relative_humidity"] /= 100
    return FlirCalibration(**{k: float(v) for k, v in values.items()})


# ------------------------------------------------------------------ DJI
def _dji_raw(segments: List[Tuple[int, bytes]], preview: Tuple[int, int]) -> Optional[np.ndarray]:
    """The raw raster of a DJI-format file: the APP3 (or, on the XT S, APP4) segments joined, 16-bit
    little-endian, at the preview's aspect ratio (the thermal sensor may be smaller than the preview)."""
    width, height = preview
    for marker in (0xE3, 0xE4):
        data = b"".join(payload for m, payload in segments if m == marker)
        pixels = len(data) // 2
        if pixels < 64 * 64 or len(data) % 2:
            continue
        w = round(math.sqrt(pixels * width / height))
        if w and pixels % w == 0 and abs(w / (pixels // w) - width / height) < 1e-3:
            return np.frombuffer(data, "<u2").reshape(pixels // w, w).astype(np.uint16)
    return None


def _preview_size(segments: List[Tuple[int, bytes]], path: Path) -> Tuple[int, int]:
    for marker, payload in segments:
        if marker in (0xC0, 0xC1, 0xC2):  # start of frame
            height, width = struct.unpack(">HH", payload[1:5])
            return width, height
    raise InputError(f"{path}: a JPEG without an image frame header")


# ------------------------------------------------------------------ reading
def _read_bytes(path: Path) -> bytes:
    try:
        return Path(path).read_bytes()
    except OSError as err:
        raise InputError(f"{path}: unreadable ({err.strerror or err})") from err


def _damaged(path: Path):
    return faults_named(path, "a damaged radiometric JPEG: its thermal records cannot be read")


def _thermal_content(data: bytes, path: Path, decode: bool = True) -> Optional[RadiometricJpeg]:
    """The file's thermal content (with `decode` False, `raw` is None: only the calibration is
    read), or None where the JPEG has none. Damaged thermal segments raise, naming the file."""
    with _damaged(path):
        segments = jpeg_segments(data, path)
        camera = _exif_camera(segments)
        fff = _flir_container(segments)
        if fff is not None:
            _, records = _flir_records(fff, path)
            if RAW_DATA not in records or CAMERA_INFO not in records:
                raise NotRadiometric(f"{path}: its FLIR segments hold no raw thermal image or no calibration")
            raw = _flir_raw(records[RAW_DATA], path) if decode else None
            return RadiometricJpeg(path, camera, "flir", raw, _flir_calibration(records[CAMERA_INFO]))
        if not camera.startswith("DJI"):
            return None
        raw = _dji_raw(segments, _preview_size(segments, path))
        if raw is None and _dji_thermal_bytes(segments) >= 2 * 64 * 64:
            raise InputError(
                f"{path}: a damaged DJI R-JPEG: its thermal segments hold {_dji_thermal_bytes(segments):,} bytes, "
                "no raster at its preview's shape (cut short?)"
            )
        return None if raw is None else RadiometricJpeg(path, camera, "dji", raw, None)


def _dji_thermal_bytes(segments: List[Tuple[int, bytes]]) -> int:
    return max(sum(len(payload) for m, payload in segments if m == marker) for marker in (0xE3, 0xE4))


def _not_radiometric(path: Path, data: bytes) -> NotRadiometric:
    with _damaged(path):
        camera = _exif_camera(jpeg_segments(data, path))
    return NotRadiometric(
        f"{path}: no radiometric data (neither FLIR records nor DJI's thermal segments) behind the JPEG"
        f"{' of ' + camera if camera else ''}: only its colour preview, which is not temperatures. Use the files "
        f"as the thermal camera wrote them (DJI: the *_R.jpg / *_T.jpg ones)"
    )


def read_rjpeg(path: Path, decode: bool = True) -> RadiometricJpeg:
    """The thermal content of one R-JPEG, FLIR or DJI format; `NotRadiometric` naming the file
    where it has none (never its colour preview). `decode` False: a FLIR file's raw image is not decoded
    (`raw` None; a DJI file's raster is read all the same: it is stored plain)."""
    data = _read_bytes(path)
    content = _thermal_content(data, Path(path), decode)
    if content is None:
        raise _not_radiometric(Path(path), data)
    return content


def read_calibration(path: Path) -> Optional[FlirCalibration]:
    """An R-JPEG's °C calibration (None: DJI's format), without decoding its raw image;
    `NotRadiometric` naming the file where it has no thermal data."""
    data = _read_bytes(path)
    content = _thermal_content(data, Path(path), decode=False)
    if content is None:
        raise _not_radiometric(Path(path), data)
    return content.calibration


def radiometric_raw(path: Path) -> Optional[np.ndarray]:
    """[H, W] uint16 raw counts of a radiometric JPEG (whatever its name: `file_kind`), read once; None for any
    other file (a plain or colour-mapped JPEG, another format)."""
    if file_kind(path) != "jpeg":
        return None
    content = _thermal_content(_read_bytes(path), Path(path))
    return None if content is None else content.raw


def flir_field_of_view(path: Path) -> Optional[float]:
    """The horizontal field of view (degrees) a FLIR-format file records; None where it records none
    (DJI's FLIR-core cameras write 0) or has no FLIR records."""
    with _damaged(path):
        fff = _flir_container(jpeg_segments(_read_bytes(path), Path(path)))
        if fff is None:
            return None
        record = _flir_records(fff, Path(path))[1].get(CAMERA_INFO)
        if record is None or len(record) < FIELD_OF_VIEW + 4:
            return None
        degrees = struct.unpack_from(_record_order(record) + "f", record, FIELD_OF_VIEW)[0]
    return float(degrees) if 1.0 < degrees < 179.0 else None


def is_radiometric_jpeg(path: Path) -> bool:
    """Whether the file is a JPEG (whatever its name) with FLIR records or DJI thermal segments (reads its header
    only)."""
    path = Path(path)
    if file_kind(path) != "jpeg":
        return False
    with open(path, "rb") as handle:
        head = handle.read(4 << 20)  # DJI's raw segments come within the first few MB
    try:
        segments = jpeg_segments(head, path)
    except InputError:
        return False
    if _flir_container(segments) is not None:
        return True
    try:
        if not _exif_camera(segments).startswith("DJI"):
            return False
        return _dji_raw(segments, _preview_size(segments, path)) is not None
    except (InputError, struct.error, IndexError, ValueError):
        return False
