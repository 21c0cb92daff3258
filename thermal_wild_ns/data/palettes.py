"""Inverting colour-mapped thermal frames back to scalar levels.

Many thermal datasets ship 8-bit colour-mapped images (MSX/RGBT-Scenes: "iron"). Each pixel's
colour is looked up as the nearest entry of a 256-entry palette; the entry's index (0..255) is
the scalar level. The palettes here are 256 distinct uint8 colours, so an exactly colour-mapped
image inverts exactly; JPEG-compressed ones invert to the nearest level.

An image whose colours are far from every known palette is refused (the error lists how far
each palette was) rather than silently decoded into nonsense.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Dict, Optional, Tuple

import cv2
import numpy as np
from scipy.spatial import cKDTree

from thermal_wild_ns.errors import InputError

PALETTE_NAMES = ("grey", "iron", "inferno", "jet")
MAX_MEDIAN_DISTANCE = 12.0
"""A palette fits an image when the median RGB distance (0..255 units) of its pixels to the palette
is at most this; JPEG artefacts on real colour-mapped frames stay well below it."""

# FLIR-style "iron"/"ironbow": black -> indigo -> purple -> magenta -> red -> orange -> yellow -> white.
# Control points (position, RGB), linearly interpolated.
_IRON_STOPS = (
    (0.00, (0, 0, 0)),
    (0.15, (40, 0, 110)),
    (0.30, (120, 0, 150)),
    (0.45, (190, 25, 130)),
    (0.60, (230, 70, 50)),
    (0.75, (250, 140, 0)),
    (0.90, (255, 210, 40)),
    (1.00, (255, 255, 240)),
)


@lru_cache(maxsize=None)
def palette_rgb(name: str) -> np.ndarray:
    """The palette's 256 colours, level 0 (coldest) first: uint8 [256, 3], RGB order."""
    t = np.linspace(0.0, 1.0, 256)
    if name == "grey":
        rgb = np.repeat(t[:, None], 3, axis=1)
    elif name == "iron":
        pos = np.array([p for p, _ in _IRON_STOPS])
        stops = np.array([c for _, c in _IRON_STOPS], dtype=np.float64) / 255.0
        rgb = np.stack([np.interp(t, pos, stops[:, c]) for c in range(3)], axis=1)
    elif name in ("inferno", "jet"):
        # OpenCV's tables (what cv2.applyColorMap writes): 256 distinct colours each, unlike
        # matplotlib's jet, which repeats one colour over 5 levels after 8-bit rounding
        code = cv2.COLORMAP_INFERNO if name == "inferno" else cv2.COLORMAP_JET
        return cv2.applyColorMap(np.arange(256, dtype=np.uint8)[:, None], code)[:, 0, ::-1].copy()
    else:
        raise InputError(f"unknown palette '{name}' (known: {', '.join(PALETTE_NAMES)})")
    return np.round(rgb * 255.0).astype(np.uint8)


@lru_cache(maxsize=None)
def _tree(name: str) -> cKDTree:
    return cKDTree(palette_rgb(name).astype(np.float32))


def apply_palette(levels: np.ndarray, name: str) -> np.ndarray:
    """Colour-map uint8 levels [H, W] -> RGB uint8 [H, W, 3] (what a camera's export does)."""
    return palette_rgb(name)[levels]


def false_colour(values: np.ndarray, name: str = "inferno") -> np.ndarray:
    """Normalised values [H, W] (clipped to [0, 1]) -> BGR uint8 [H, W, 3] in a palette, ready for cv2.imwrite."""
    return np.ascontiguousarray(apply_palette((np.clip(values, 0.0, 1.0) * 255.0).astype(np.uint8), name)[..., ::-1])


def invert_palette(rgb: np.ndarray, name: str) -> Tuple[np.ndarray, np.ndarray]:
    """Nearest palette level of every pixel: levels uint8 [H, W] and RGB distances float32 [H, W]."""
    distance, index = _tree(name).query(rgb.reshape(-1, 3).astype(np.float32))
    return index.astype(np.uint8).reshape(rgb.shape[:2]), distance.astype(np.float32).reshape(rgb.shape[:2])


def palette_fit(rgb: np.ndarray) -> Dict[str, float]:
    """Median distance of the image's colours to each known palette (lower fits better)."""
    sample = rgb.reshape(-1, 3)[:: max(1, rgb.shape[0] * rgb.shape[1] // 20000)]
    return {name: float(np.median(_tree(name).query(sample.astype(np.float32))[0])) for name in PALETTE_NAMES}


def detect_palette(rgb: np.ndarray, path: Path) -> str:
    """The known palette that fits this RGB image [H, W, 3]; a clear error if none does."""
    fit = palette_fit(rgb)
    best = min(fit, key=fit.get)
    if fit[best] > MAX_MEDIAN_DISTANCE:
        report = ", ".join(f"{n}: {d:.1f}" for n, d in sorted(fit.items(), key=lambda kv: kv[1]))
        raise InputError(
            f"{path}: colour-mapped frame in an unknown palette (median RGB distance to each known palette: "
            f"{report}; at most {MAX_MEDIAN_DISTANCE:g} is accepted). Export the frames as raw/greyscale "
            f"values or add the palette to thermal_wild_ns/data/palettes.py"
        )
    return best


def decode_colour_frame(rgb: np.ndarray, path: Path, palette: Optional[str]) -> np.ndarray:
    """uint8 levels [H, W] of a colour-mapped RGB frame, with `palette` or the detected one."""
    name = palette or detect_palette(rgb, path)
    levels, distance = invert_palette(rgb, name)
    if float(np.median(distance)) > MAX_MEDIAN_DISTANCE:
        raise InputError(
            f"{path}: colours do not match the dataset's '{name}' palette (median RGB distance "
            f"{float(np.median(distance)):.1f} > {MAX_MEDIAN_DISTANCE:g}); were frames exported with different "
            f"palettes?"
        )
    return levels
