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
FIT_PERCENTILE = 90.0
MAX_DISTANCE = 25.0
"""A palette fits an image when the `FIT_PERCENTILE`th percentile of its pixels' RGB distance
(0..255 units) to the palette is at most this. A high percentile, not the median: a wrong palette
(jet on an iron frame) can sit close to many pixels and still be far from a tenth of them, while
JPEG artefacts on real colour-mapped frames keep the right palette well below it."""

# "iron" (ironbow): black -> indigo -> purple -> magenta -> red -> orange -> yellow -> white, as
# real cameras export it. The stops (position, RGB; linearly interpolated) were fitted to the 7
# real RGBT-Scenes frames in ../shared/data/rgbt_frames with
#     python -m experiments.fit_palette --frames ../shared/data/rgbt_frames/*.jpg
# (a principal curve through their pixels, started from a hand-drawn ironbow; docs/datasets.md).
_IRON_STOPS = (
    (0.0000, (1, 0, 15)),
    (0.0312, (2, 1, 39)),
    (0.0625, (3, 2, 63)),
    (0.0938, (9, 2, 86)),
    (0.1250, (23, 1, 106)),
    (0.1562, (41, 1, 123)),
    (0.1875, (59, 1, 138)),
    (0.2188, (80, 1, 151)),
    (0.2500, (102, 1, 160)),
    (0.2812, (126, 1, 165)),
    (0.3125, (149, 6, 162)),
    (0.3438, (170, 14, 153)),
    (0.3750, (187, 25, 140)),
    (0.4062, (201, 36, 124)),
    (0.4375, (213, 49, 107)),
    (0.4688, (223, 62, 90)),
    (0.5000, (232, 76, 72)),
    (0.5312, (240, 92, 55)),
    (0.5625, (247, 108, 39)),
    (0.5938, (252, 125, 23)),
    (0.6250, (254, 145, 9)),
    (0.6562, (254, 169, 4)),
    (0.6875, (254, 192, 9)),
    (0.7188, (254, 210, 25)),
    (0.7500, (254, 220, 46)),
    (0.7812, (253, 229, 69)),
    (0.8125, (253, 236, 92)),
    (0.8438, (252, 242, 115)),
    (0.8750, (251, 247, 139)),
    (0.9062, (250, 250, 163)),
    (0.9375, (249, 252, 187)),
    (0.9688, (249, 254, 211)),
    (1.0000, (251, 254, 235)),
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
    """The `FIT_PERCENTILE`th-percentile distance of the image's colours to each known palette
    (lower fits better)."""
    sample = rgb.reshape(-1, 3)[:: max(1, rgb.shape[0] * rgb.shape[1] // 20000)].astype(np.float32)
    return {name: float(np.percentile(_tree(name).query(sample)[0], FIT_PERCENTILE)) for name in PALETTE_NAMES}


def detect_palette(rgb: np.ndarray, path: Path) -> str:
    """The known palette that fits this RGB image [H, W, 3]; a clear error if none does."""
    fit = palette_fit(rgb)
    best = min(fit, key=fit.get)
    if fit[best] > MAX_DISTANCE:
        report = ", ".join(f"{n}: {d:.1f}" for n, d in sorted(fit.items(), key=lambda kv: kv[1]))
        raise InputError(
            f"{path}: colour-mapped frame in an unknown palette ({FIT_PERCENTILE:g}th-percentile RGB distance to "
            f"each known palette: {report}; at most {MAX_DISTANCE:g} is accepted). Export the frames as "
            "raw/greyscale values or add the palette to thermal_wild_ns/data/palettes.py"
        )
    return best


def decode_colour_frame(rgb: np.ndarray, path: Path, palette: Optional[str]) -> np.ndarray:
    """uint8 levels [H, W] of a colour-mapped RGB frame, with `palette` or the detected one."""
    name = palette or detect_palette(rgb, path)
    levels, distance = invert_palette(rgb, name)
    far = float(np.percentile(distance, FIT_PERCENTILE))
    if far > MAX_DISTANCE:
        raise InputError(
            f"{path}: colours do not match the dataset's '{name}' palette ({FIT_PERCENTILE:g}th-percentile RGB "
            f"distance {far:.1f} > {MAX_DISTANCE:g}); were frames exported with different palettes?"
        )
    return levels
