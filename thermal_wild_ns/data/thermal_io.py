"""Reading thermal frames and the dataset-level radiometric range.

Thermal frames are kept in their native radiometric units (uint8/uint16 counts, float
temperatures) and normalised with ONE range per dataset, never per frame: per-frame
normalisation would erase exactly the frame-to-frame radiometric consistency the method relies on.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
import threading
import warnings
from dataclasses import dataclass, replace
from pathlib import Path
from typing import List, Optional, Sequence, Tuple

import cv2
import numpy as np

from thermal_wild_ns.data.celsius import CelsiusCalibration
from thermal_wild_ns.data.frame_files import IMAGE_SUFFIXES, file_kind
from thermal_wild_ns.data.palettes import decode_colour_frame, detect_palette
from thermal_wild_ns.data.rjpeg import radiometric_raw
from thermal_wild_ns.errors import InputError, MissingInput
from thermal_wild_ns.progress import track

# numpy parses a .npy header with `ast.literal_eval`, and CPython 3.11's AST constructor keeps its
# recursion depth in interpreter-wide state: two threads parsing at once can raise "SystemError: AST
# constructor recursion depth mismatch" (cpython gh-106905). nerfstudio caches images from a thread pool.
_NPY_HEADER_LOCK = threading.Lock()


def process_alive(pid: int) -> bool:
    """Whether process `pid` of this host still runs (its temporary files are then in use)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, another user's
        return True
    return True


def make_work_folder(parent: Path, prefix: str) -> Path:
    """A fresh temporary folder `parent/{prefix}{pid}-XXXX` for a cache being built (published with
    `publish_cache_folder`). Folders of the same prefix left by a process that is gone (killed
    during setup) are removed first; a live process's folder, a concurrent run's, is never touched.
    Assumes the cache is not shared between hosts (PIDs are per host)."""
    parent.mkdir(parents=True, exist_ok=True)
    for stale in parent.glob(f"{prefix}*"):
        pid = stale.name[len(prefix) :].split("-")[0]
        if stale.is_dir() and pid.isdigit() and not process_alive(int(pid)):
            shutil.rmtree(stale, ignore_errors=True)
    return Path(tempfile.mkdtemp(prefix=f"{prefix}{os.getpid()}-", dir=parent))


def publish_cache_folder(work: Path, final: Path, complete_marker: str) -> None:
    """Move a finished cache folder `work` into place as `final` in one rename, so no reader sees it
    half-written. Another process with the same inputs (a bench run on the next GPU) may have
    published `final` first: its copy is kept, having the same content, and `work` discarded."""
    try:
        work.rename(final)
    except OSError:
        if not (final / complete_marker).is_file():
            raise
        shutil.rmtree(work, ignore_errors=True)


def discard_cache_folder(folder: Path) -> None:
    """Take a damaged cache folder out of the way in one rename (a concurrent reader finds it gone,
    never half-deleted), then delete it."""
    aside = folder.parent / f".damaged-{os.getpid()}-{folder.name}"
    try:
        folder.rename(aside)
    except OSError:  # another process took it away first
        return
    shutil.rmtree(aside, ignore_errors=True)


def file_fingerprint(path: Path) -> bytes:
    """A file's name, size and a digest of its first and last 64 KiB: what a cache is keyed on,
    stable across copies (modification times are not) and quick on large files."""
    path = Path(path)
    size = path.stat().st_size
    with open(path, "rb") as file:
        head = file.read(1 << 16)
        file.seek(max(0, size - (1 << 16)))
        tail = file.read()
    return f"{path.name}:{size}:".encode() + hashlib.sha1(head + tail).digest()


def load_npy(path: Path, mmap_mode: Optional[str] = None) -> np.ndarray:
    """`np.load` of one plain (no pickle) array, safe to call from several threads at once."""
    with _NPY_HEADER_LOCK:
        return np.load(path, mmap_mode=mmap_mode, allow_pickle=False)


def _stored_frame(path: Path, radiometric_jpeg: bool = True) -> Tuple[np.ndarray, bool]:
    """The file's pixels, a grey 3-channel image collapsed to [H, W]; and whether it is a
    colour-mapped frame (then RGB uint8 [H, W, 3]). What the file is comes from its bytes (`file_kind`),
    whatever its name. A radiometric JPEG (`rjpeg.py`) gives its raw sensor counts [H, W] uint16, not
    its colour preview, unless `radiometric_jpeg` is False (a layout of colour-mapped exports, which may
    keep part of the camera's records)."""
    path = Path(path)
    if not path.is_file():
        raise MissingInput(f"{path}: thermal frame not found")
    kind = file_kind(path)
    raw = radiometric_raw(path) if radiometric_jpeg and kind == "jpeg" else None
    if raw is not None:
        return raw, False
    if kind == "npy" or (kind == "unknown" and path.suffix.lower() == ".npy"):
        try:
            image = load_npy(path)
        except (ValueError, OSError, EOFError) as err:
            raise InputError(f"{path}: unreadable .npy thermal frame ({err})") from err
    elif kind in ("jpeg", "png", "tiff") or path.suffix.lower() in IMAGE_SUFFIXES:
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)  # OpenCV decodes by content, as named or not
        if image is None:
            what = kind.upper() if kind != "unknown" else "image"
            raise InputError(f"{path}: unreadable {what} file (damaged, cut short, or not an image)")
    else:
        raise InputError(
            f"{path}: unsupported thermal frame type '{path.suffix}' (use {sorted(IMAGE_SUFFIXES)} or .npy)"
        )
    if image.ndim == 3 and image.shape[2] in (1, 3, 4):
        image = image[..., :3]
        if np.all(image[..., :1] == image):
            return image[..., 0], False
        if image.dtype != np.uint8:
            raise InputError(f"{path}: {image.dtype} colour image; colour-mapped frames must be 8-bit")
        return image[..., ::-1], True  # OpenCV reads BGR
    return image, False


def read_raw_frame(path: Path, palette: Optional[str] = None) -> np.ndarray:
    """One thermal frame as a 2D array in its native units and dtype ([H, W]).

    8/16-bit PNG/TIFF/JPG, radiometric JPEGs (their raw counts, where no `palette` is given) and
    float `.npy` arrays. A 3-channel grey image (all channels equal) is read as grey; a
    colour-mapped one is inverted to its palette levels (uint8) with `palette`, or with the
    detected palette when `palette` is None (see `palettes.py`).
    """
    image, colour = _stored_frame(path, radiometric_jpeg=palette is None)
    if colour:
        image = decode_colour_frame(image, Path(path), palette)
    if image.ndim != 2:
        raise InputError(f"{path}: expected a 2D thermal frame, got shape {image.shape}")
    if image.dtype not in (np.uint8, np.uint16) and not np.issubdtype(image.dtype, np.floating):
        raise InputError(f"{path}: unsupported pixel type {image.dtype} (uint8, uint16 or float)")
    return image


def frame_size(path: Path) -> Tuple[int, int]:
    """(width, height) of a frame file."""
    h, w = read_raw_frame(path).shape
    return w, h


def frame_palette(path: Path) -> Optional[str]:
    """The palette of a colour-mapped frame (detected), or None for a scalar frame."""
    image, colour = _stored_frame(path)
    return detect_palette(image, Path(path)) if colour else None


@dataclass(frozen=True)
class RadiometricRange:
    """Dataset-level mapping of native units to the normalised [0, 1]-ish training scale."""

    low: float
    """Native value mapped to 0."""
    high: float
    """Native value mapped to 1."""
    dtype: str
    """Native pixel type of the dataset's frames (uint8, uint16, float32, ...)."""
    celsius_low: Optional[float] = None
    """Temperature (degC) of `low`, when the dataset documents it."""
    celsius_high: Optional[float] = None
    """Temperature (degC) of `high`, when the dataset documents it."""
    palette: Optional[str] = None
    """Colour palette the frames were exported with (native values are its levels 0..255), if any."""
    planck: Optional[CelsiusCalibration] = None
    """The camera's own calibration of its raw counts (radiometric JPEGs: the FLIR format's Planck
    curve, or DJI's converter's table), not linear between bounds: the capture's reference, for a render
    at no frame's own state (the canonical state, the exports)."""
    frame_celsius: Optional[Tuple[Optional[CelsiusCalibration], ...]] = None
    """Each frame's own calibration at its measurement settings (capture order; None where a frame has none)."""

    @property
    def has_celsius(self) -> bool:
        """Whether native values convert to °C (a camera calibration, or documented bounds)."""
        return self.planck is not None or (self.celsius_low is not None and self.celsius_high is not None)

    def normalize(self, raw: np.ndarray) -> np.ndarray:
        return ((raw.astype(np.float64) - self.low) / (self.high - self.low)).astype(np.float32)

    def to_native(self, normalised: np.ndarray) -> np.ndarray:
        """Normalised values -> native units (the inverse of `normalize`)."""
        return self.low + normalised * (self.high - self.low)

    def read(self, path: Path) -> np.ndarray:
        """One frame, normalised: float32 [H, W]."""
        return self.normalize(read_raw_frame(path, self.palette))

    def to_celsius(self, normalised: np.ndarray, frame: Optional[int] = None) -> np.ndarray:
        """Normalised values -> degC: through frame `frame`'s own calibration (its capture position) where it
        has one, else the capture's reference calibration, else linear between the documented bounds."""
        own = None if frame is None or self.frame_celsius is None else self.frame_celsius[frame]
        calibration = own if own is not None else self.planck
        if calibration is not None:
            return calibration.celsius(self.to_native(np.asarray(normalised, dtype=np.float64)))
        if self.celsius_low is None or self.celsius_high is None:
            raise InputError("this dataset documents no temperature bounds (celsius_low/celsius_high)")
        return self.celsius_low + normalised * (self.celsius_high - self.celsius_low)


DEGENERATE_SHARE = 0.95
"""A frame with at least this share of its pixels at one value (an all-zero read-out, a frozen or
shutter-closed frame) carries no scene: it is reported, excluded by default, and never measures
the dataset's range."""


@dataclass(frozen=True)
class FrameScan:
    range: "RadiometricRange"
    degenerate: List[int]
    """Indices of the frames with no contrast (`DEGENERATE_SHARE` of their pixels at one value)."""


def _dominant_share(raw: np.ndarray, counts: Optional[np.ndarray]) -> float:
    """Share of the pixels at the frame's most common value."""
    if counts is not None:
        return float(counts.max()) / raw.size
    _, repeats = np.unique(raw, return_counts=True)
    return float(repeats.max()) / raw.size


def scan_frames(
    paths: Sequence[Path],
    sizes: Optional[Sequence[Tuple[int, int]]] = None,
    declared: Optional[RadiometricRange] = None,
    palette: Optional[str] = None,
    percentiles: Tuple[float, float] = (0.1, 99.9),
    measure: Optional[Sequence[bool]] = None,
) -> FrameScan:
    """Read every frame once: check it, find the degenerate ones, and measure the dataset-level
    range unless one is declared.

    Checks: each file is readable, all frames share one pixel type (mixing bit depths would mix
    radiometric scales) and one palette, each frame's size matches its camera (`sizes`, (W, H)),
    and float frames are finite. The measured range is the given percentiles of all pixels of all
    frames (integers histogrammed exactly, floats sampled on a strided grid). Frames with more than
    `OUT_OF_RANGE_SHARE` of their pixels outside the range (declared or measured) are named in a
    warning: preprocessing clips those pixels, and a frame mostly outside the range is saturated.
    `measure[i]`: whether frame i counts towards the measured range and the palette detection
    (default: all). The dataparser passes the training frames: a held-out frame's pixels must not
    shape the scale the model trains in. Degenerate frames never count towards the range either.
    """
    if not paths:
        raise InputError("No thermal frames to read")
    if palette is None and declared is not None:
        palette = declared.palette
    measure = [True] * len(paths) if measure is None else list(measure)
    if not any(measure):
        raise InputError(f"{Path(paths[0]).parent}: no frames to measure the radiometric range from")
    if palette is None:
        palette = frame_palette(paths[measure.index(True)])
    dtype = None
    hist = None
    samples = []
    tails = []  # per frame: the values with OUT_OF_RANGE_SHARE of its pixels below / above them
    degenerate = []
    for i, path in enumerate(track(paths, "Reading thermal frames", min_items=20)):
        raw = read_raw_frame(path, palette)
        if dtype is None:
            dtype = raw.dtype
        elif raw.dtype != dtype:
            raise InputError(f"{path}: pixel type {raw.dtype} differs from the dataset's {dtype} (mixed bit depths)")
        if sizes is not None and (raw.shape[1], raw.shape[0]) != tuple(sizes[i]):
            raise InputError(
                f"{path}: image is {raw.shape[1]}x{raw.shape[0]} but its camera says {sizes[i][0]}x{sizes[i][1]}"
            )
        if raw.dtype not in (np.uint8, np.uint16) and not np.all(np.isfinite(raw)):
            raise InputError(f"{path}: {int((~np.isfinite(raw)).sum())} non-finite pixel values")
        counts = None
        if raw.dtype in (np.uint8, np.uint16):
            counts = np.bincount(raw.reshape(-1), minlength=1 << (8 * raw.dtype.itemsize))
        if _dominant_share(raw, counts) >= DEGENERATE_SHARE:
            degenerate.append(i)
            tails.append((np.inf, -np.inf))  # never flagged out of range: it is reported as degenerate
            continue
        if counts is not None:
            if measure[i]:
                hist = counts if hist is None else hist + counts
            cdf = np.cumsum(counts) / raw.size
            tails.append(
                (float(np.searchsorted(cdf, OUT_OF_RANGE_SHARE)), float(np.searchsorted(cdf, 1.0 - OUT_OF_RANGE_SHARE)))
            )
        else:
            if measure[i]:
                samples.append(raw.reshape(-1)[:: max(1, raw.size // 65536)])
            tails.append(tuple(float(v) for v in np.quantile(raw, [OUT_OF_RANGE_SHARE, 1.0 - OUT_OF_RANGE_SHARE])))
    if declared is not None:
        if declared.dtype != str(np.dtype(dtype)):
            raise InputError(f"{paths[0]}: frames are {dtype} but the dataset declares {declared.dtype}")
        _warn_out_of_range(paths, tails, declared.low, declared.high, "declared")
        return FrameScan(replace(declared, palette=palette), degenerate)
    if hist is None and not samples:
        raise InputError(f"{Path(paths[0]).parent}: every frame to measure the range from is degenerate (one value)")
    if hist is not None:
        cdf = np.cumsum(hist) / hist.sum()
        low = float(np.searchsorted(cdf, percentiles[0] / 100.0, side="right"))  # first level above the percentile
        high = float(np.searchsorted(cdf, percentiles[1] / 100.0))
    else:
        low, high = (float(v) for v in np.percentile(np.concatenate(samples), percentiles))
    if not high > low:
        raise InputError(f"Thermal frames ({paths[0].parent}) have no contrast: range [{low}, {high}] is empty")
    _warn_out_of_range(paths, tails, low, high, "measured")
    return FrameScan(RadiometricRange(low=low, high=high, dtype=str(np.dtype(dtype)), palette=palette), degenerate)


OUT_OF_RANGE_SHARE = 0.01
"""A frame with more of its pixels than this below or above the dataset's range is named in a warning."""


def _warn_out_of_range(
    paths: Sequence[Path], tails: Sequence[Tuple[float, float]], low: float, high: float, kind: str
) -> None:
    """Warn about the frames whose low or high tail (`OUT_OF_RANGE_SHARE` of pixels) lies outside [low, high]."""
    advice = {
        "declared": "Check the range the dataset declares, or those frames.",
        "measured": "Widen the dataparser's --range-percentiles, or check those frames.",
    }
    below = [Path(p).name for p, (lo, _) in zip(paths, tails) if lo < low]
    above = [Path(p).name for p, (_, hi) in zip(paths, tails) if hi > high]
    for names, side, bound in ((below, "below", low), (above, "above", high)):
        if names:
            listed = ", ".join(names[:5]) + (f" and {len(names) - 5} more" if len(names) > 5 else "")
            warnings.warn(
                f"{Path(paths[0]).parent}: {len(names)} frame(s) have over {OUT_OF_RANGE_SHARE:.0%} of their pixels "
                f"{side} the {kind} radiometric range ({side} {bound:g}): {listed}. Preprocessing clips those "
                f"pixels; a frame mostly outside the range is saturated. {advice[kind]}",
                stacklevel=3,
            )
