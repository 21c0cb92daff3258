"""Reading thermal frames and the dataset-level radiometric range.

Thermal frames are kept in their native radiometric units (uint8/uint16 counts, float
temperatures) and normalised with ONE range per dataset, never per frame: per-frame
normalisation would erase exactly the frame-to-frame radiometric consistency the method relies on.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence

import cv2
import numpy as np

IMAGE_SUFFIXES = {".png", ".tif", ".tiff", ".jpg", ".jpeg"}


def read_raw_frame(path: Path) -> np.ndarray:
    """One thermal frame as a 2D array in its native units and dtype ([H, W]).

    8/16-bit PNG/TIFF/JPG and float `.npy` arrays. A 3-channel image is accepted only if it is
    grey (all channels equal); colour-mapped frames need a palette inversion.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: thermal frame not found")
    if path.suffix.lower() == ".npy":
        try:
            image = np.load(path, allow_pickle=False)
        except (ValueError, OSError) as err:
            raise ValueError(f"{path}: unreadable .npy thermal frame ({err})") from err
    elif path.suffix.lower() in IMAGE_SUFFIXES:
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise ValueError(f"{path}: unreadable image file")
    else:
        raise ValueError(f"{path}: unsupported thermal frame type '{path.suffix}' (use {sorted(IMAGE_SUFFIXES)} or .npy)")
    if image.ndim == 3:
        if image.shape[2] == 4:
            image = image[..., :3]
        if image.shape[2] == 1 or (np.all(image[..., :1] == image) if image.shape[2] == 3 else False):
            image = image[..., 0]
        else:
            raise ValueError(
                f"{path}: {image.shape[2]}-channel colour image; thermal frames must be single-channel "
                "(colour-mapped frames need their palette inverted first)"
            )
    if image.ndim != 2:
        raise ValueError(f"{path}: expected a 2D thermal frame, got shape {image.shape}")
    if image.dtype not in (np.uint8, np.uint16) and not np.issubdtype(image.dtype, np.floating):
        raise ValueError(f"{path}: unsupported pixel type {image.dtype} (uint8, uint16 or float)")
    return image


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

    def normalize(self, raw: np.ndarray) -> np.ndarray:
        return ((raw.astype(np.float64) - self.low) / (self.high - self.low)).astype(np.float32)


def measure_range(paths: Sequence[Path], percentiles: tuple[float, float] = (0.1, 99.9)) -> RadiometricRange:
    """Robust dataset-level range over all frames: the given percentiles of all pixels.

    Every frame must have the same pixel type (mixing bit depths would mix radiometric scales).
    Integer data is histogrammed exactly; float data is sampled on a strided grid.
    """
    if not paths:
        raise ValueError("No thermal frames to measure a radiometric range from")
    dtype = None
    hist = None
    samples = []
    for path in paths:
        raw = read_raw_frame(path)
        if dtype is None:
            dtype = raw.dtype
        elif raw.dtype != dtype:
            raise ValueError(f"{path}: pixel type {raw.dtype} differs from the dataset's {dtype} (mixed bit depths)")
        if raw.dtype in (np.uint8, np.uint16):
            counts = np.bincount(raw.reshape(-1), minlength=1 << (8 * raw.dtype.itemsize))
            hist = counts if hist is None else hist + counts
        else:
            finite = raw[np.isfinite(raw)]
            samples.append(finite.reshape(-1)[:: max(1, finite.size // 65536)])
    if hist is not None:
        cdf = np.cumsum(hist) / hist.sum()
        low = float(np.searchsorted(cdf, percentiles[0] / 100.0))
        high = float(np.searchsorted(cdf, percentiles[1] / 100.0))
    else:
        values = np.concatenate(samples)
        low, high = (float(v) for v in np.percentile(values, percentiles))
    if not high > low:
        raise ValueError(f"Thermal frames ({paths[0].parent}) have no contrast: range [{low}, {high}] is empty")
    return RadiometricRange(low=low, high=high, dtype=str(np.dtype(dtype)))

