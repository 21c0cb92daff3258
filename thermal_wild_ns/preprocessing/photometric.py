"""Photometric stabilization + brightness-preserving bi-histogram equalization as per-frame LUTs.

Pure numpy, independent of nerfstudio. Frames are integer levels (uint8: 256 levels, uint16:
65,536; float data is quantised onto a 16-bit grid first, see `LevelGrid`). For frame t with
level histogram h_t and CDF F_t:

- stabilization (streaming, capture order): reference F*_t = (1-alpha) F*_{t-1} + alpha F_t with
  F*_0 = F_0, and s_t(x) = (1-beta) x + beta F*_t^{-1}(F_t(x)): each frame's distribution is pulled
  toward a slowly moving reference, which removes gain/offset drift and jitter but follows real
  content changes at the rate alpha;
- BBHE on the stabilized values (Kim 1997): split at their mean m; levels at or below m are
  equalised onto [low, m], those above onto [m, high], each with its own half's CDF, where
  [low, high] is the dataset's radiometric range (the output stays in native units, so the
  dataset normalisation still applies);
- optionally a weaker equalization, s + k (bbhe_t(s) - s) with k = `equalization_strength` < 1;
- the composite y = bbhe_t(s_t(x)) is kept per frame as a LUT over every native level, made
  strictly increasing (slope 1 beyond the frame's lowest/highest level, at least 0.05 of a level
  per level inside, which breaks the ties of empty levels and leaves an already increasing LUT
  untouched), so it has an exact inverse: renders map back to the original radiometric scale.

Only one histogram, the running reference and the LUTs are kept: memory does not grow with the
sequence beyond the LUTs themselves.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Iterator, Literal, Optional, Sequence, Tuple, get_args

import numpy as np

from thermal_wild_ns.errors import InputError

Variant = Literal["none", "histeq", "bbhe", "stab", "stab+bbhe"]
VARIANTS = get_args(Variant)
MIN_STEP = 0.05
"""Smallest rise of a LUT from one level to the next, in levels (ties of empty levels are broken by it).
Large enough that processed frames stored as float32 still resolve every level (float data sits
on a fine 16-bit grid whose levels are mostly empty)."""


@dataclass(frozen=True)
class LevelGrid:
    """The native levels a LUT is defined on: integers 0..num_levels-1 standing for values
    offset + level * step (step 1, offset 0 for integer frames)."""

    num_levels: int
    offset: float = 0.0
    step: float = 1.0

    @staticmethod
    def for_dtype(dtype: str, low: float, high: float) -> "LevelGrid":
        if dtype == "uint8":
            return LevelGrid(256)
        if dtype == "uint16":
            return LevelGrid(65536)
        # float data: 65,536 levels spanning the dataset range with a quarter-range margin each side
        margin = 0.25 * (high - low)
        return LevelGrid(65536, low - margin, (high - low + 2 * margin) / 65535)

    def levels(self, frame: np.ndarray) -> np.ndarray:
        """Frame values -> integer levels (int64 [H, W])."""
        if self.step == 1.0 and self.offset == 0.0 and np.issubdtype(frame.dtype, np.integer):
            return frame.astype(np.int64)
        return np.clip(np.round((frame.astype(np.float64) - self.offset) / self.step), 0, self.num_levels - 1).astype(
            np.int64
        )

    def values(self, levels: np.ndarray) -> np.ndarray:
        return self.offset + np.asarray(levels, dtype=np.float64) * self.step


def histogram(levels: np.ndarray, num_levels: int) -> np.ndarray:
    return np.bincount(levels.reshape(-1), minlength=num_levels).astype(np.float64)


def cdf_of(hist: np.ndarray) -> np.ndarray:
    total = hist.sum()
    if total <= 0:
        raise ValueError("empty frame: no pixels to build a histogram from")
    return np.cumsum(hist) / total


def quantile(cdf: np.ndarray, p: np.ndarray) -> np.ndarray:
    """F^{-1}(p) in continuous levels: linear between the levels where the CDF steps."""
    levels = np.arange(len(cdf), dtype=np.float64)
    rising = np.concatenate([[True], np.diff(cdf) > 0])  # np.interp needs increasing x
    return np.interp(p, cdf[rising], levels[rising])


def stabilize_mapping(cdf: np.ndarray, reference_cdf: np.ndarray, beta: float) -> np.ndarray:
    """s_t(x) = (1-beta) x + beta F*^{-1}(F_t(x)) for every level x (continuous levels)."""
    x = np.arange(len(cdf), dtype=np.float64)
    return (1.0 - beta) * x + beta * quantile(reference_cdf, cdf)


def bbhe_mapping(values: np.ndarray, hist: np.ndarray, low: float, high: float) -> np.ndarray:
    """BBHE of a frame whose level x has value values[x] and count hist[x] (values increasing):
    each level's output in [low, high]."""
    total = hist.sum()
    mean = float(np.clip((hist * values).sum() / total, low, high))
    lower = values <= mean
    out = np.empty_like(values)
    n_low = hist[lower].sum()
    n_high = total - n_low
    c_low = np.cumsum(np.where(lower, hist, 0.0)) / max(n_low, 1.0)
    c_high = np.cumsum(np.where(lower, 0.0, hist)) / max(n_high, 1.0)
    out[lower] = low + (mean - low) * c_low[lower]
    out[~lower] = mean + (high - mean) * c_high[~lower]
    return out


def equalize_mapping(hist: np.ndarray, low: float, high: float) -> np.ndarray:
    """Plain histogram equalization onto [low, high]."""
    return low + (high - low) * cdf_of(hist)


def strictly_increasing(lut: np.ndarray, hist: np.ndarray) -> np.ndarray:
    """An invertible version of `lut`: below the frame's lowest and above its highest occupied
    level it continues with slope 1 (equalization would flatten those tails onto one value and
    lose them), and inside it rises by at least MIN_STEP per level (ties of empty levels).
    A LUT that already does both is returned unchanged."""
    occupied = np.flatnonzero(hist)
    first, last = occupied[0], occupied[-1]
    levels = np.arange(len(lut), dtype=np.float64)
    lut = lut.astype(np.float64, copy=True)
    lut[:first] = lut[first] - (first - levels[:first])
    lut[last + 1 :] = lut[last] + (levels[last + 1 :] - last)
    ramp = MIN_STEP * levels
    return np.maximum.accumulate(lut - ramp) + ramp


PREPROCESSING_FLAG = "--pipeline.datamanager.preprocessing.variant"
"""The `ns-train` option that asks for preprocessing (said where a run trains on the raw frames)."""


@dataclass(frozen=True)
class PhotometricConfig:
    variant: Variant = "stab+bbhe"
    alpha: float = 0.01
    """Reference CDF update rate: F*_t = (1-alpha) F*_{t-1} + alpha F_t (time constant ~1/alpha frames).
    Larger alpha follows the drift instead of removing it (the alpha/beta sweep: docs/results.md)."""
    beta: float = 0.5
    """Blend of the stabilized mapping: I' = (1-beta) x + beta F*_t^{-1}(F_t(x)); 1 overcorrects real
    content changes as the camera moves."""
    equalization_strength: float = 0.5
    """Blend of the equalization step (BBHE or histeq) with its input: y = s + k (eq(s) - s); 1 is
    the paper's full equalization. Equalization squeezes rare levels (hot objects, the gaps of a
    bimodal scene), so a rendering error there grows when mapped back: `wild-thermal-diagnose`
    reports by how much (`error_amplification`). Lower k trades contrast for that. The default
    0.5 is chosen by a measurement (docs/results.md)."""
    skip_when_stable: bool = False
    """Train on the raw frames unless preprocessing pays for this capture (`preprocessing_pays`):
    it must make the training frames' mean levels steadier, and their contrast must vary (as a
    sensor's automatic gain control makes it); level offsets alone the frame embeddings follow,
    and there equalization only costs accuracy. Decided from the training frames at setup and
    logged; the full method turns it on for when its preprocessing is asked for (the runs that chose the
    rule: docs/results/preprocessing_rule; by default it trains on the raw frames:
    docs/results/preprocessing_camera_h200), the ablations keep their fixed preprocessing."""

    @property
    def equalizes(self) -> bool:
        """Whether this variant has an equalization step (which `equalization_strength` blends)."""
        return self.variant in ("histeq", "bbhe", "stab+bbhe")

    def __post_init__(self):
        if self.variant not in VARIANTS:
            raise InputError(f"unknown preprocessing variant '{self.variant}' (one of {', '.join(VARIANTS)})")
        if not (0.0 < self.alpha <= 1.0 and 0.0 <= self.beta <= 1.0):
            raise InputError(f"alpha must be in (0, 1] and beta in [0, 1], got alpha={self.alpha}, beta={self.beta}")
        if not 0.0 <= self.equalization_strength <= 1.0:
            raise InputError(f"equalization_strength must be in [0, 1], got {self.equalization_strength}")


def frame_luts(
    frames: Iterable[np.ndarray],
    grid: LevelGrid,
    low: float,
    high: float,
    config: PhotometricConfig,
    in_reference: Optional[Sequence[bool]] = None,
) -> Iterator[np.ndarray]:
    """One LUT per frame (float64 [num_levels], native values), streaming in capture order.

    `low`/`high`: the dataset's radiometric range in native values (the equalization target).
    `in_reference[t]`: whether frame t updates the stabilization reference (default: every frame).
    Held-out frames must not: their histograms would shape the LUTs of the training frames after
    them. Such a frame still gets a LUT, from its own histogram and the reference of the training
    frames before it; only an oracle may use it (it is built from the frame's own pixels).
    """
    reference: Optional[np.ndarray] = None
    lo, hi = (low - grid.offset) / grid.step, (high - grid.offset) / grid.step  # in levels
    identity = np.arange(grid.num_levels, dtype=np.float64)
    for t, frame in enumerate(frames):
        if frame.size == 0:
            raise ValueError(f"frame {t} is empty")
        if np.issubdtype(frame.dtype, np.floating) and not np.all(np.isfinite(frame)):
            raise InputError(f"frame {t} has non-finite values (NaN/inf); preprocessing needs finite frames")
        hist = histogram(grid.levels(frame), grid.num_levels)
        cdf = cdf_of(hist)
        if config.variant in ("stab", "stab+bbhe"):
            if in_reference is None or in_reference[t]:
                reference = cdf if reference is None else (1.0 - config.alpha) * reference + config.alpha * cdf
            # a held-out frame before the first training frame has no reference yet: its own CDF (identity)
            mapped = stabilize_mapping(cdf, cdf if reference is None else reference, config.beta)
        else:
            mapped = identity
        if config.equalizes:
            equalized = (
                equalize_mapping(hist, lo, hi) if config.variant == "histeq" else bbhe_mapping(mapped, hist, lo, hi)
            )
            mapped = mapped + config.equalization_strength * (equalized - mapped)
        if config.variant != "none":
            mapped = strictly_increasing(mapped, hist)
        yield grid.values(mapped)


def apply_lut(lut: np.ndarray, frame: np.ndarray, grid: LevelGrid) -> np.ndarray:
    """Processed frame (float32 native values)."""
    return lut[grid.levels(frame)].astype(np.float32)


def invert_lut(lut: np.ndarray, values: np.ndarray, grid: LevelGrid) -> np.ndarray:
    """Processed values -> original native values (the LUT is strictly increasing; values
    outside its range clamp to the end levels)."""
    return grid.values(np.interp(values, lut, np.arange(len(lut), dtype=np.float64)))


def time_weights(times: Sequence[float], t: float) -> Tuple[int, int, float]:
    """Where capture position `t` falls among the increasing capture positions `times` (of the
    training frames): (i, j, w) such that a per-frame quantity x at t is (1 - w) x[i] + w x[j].
    At a training frame's own position i == j and w == 0, so its state is returned exactly;
    before the first or after the last training frame, the nearest one's state (no extrapolation)."""
    times = np.asarray(times, dtype=np.float64)
    if len(times) == 0:
        raise ValueError("no training frames to interpolate between")
    if not np.all(np.diff(times) > 0):
        raise ValueError("training frame positions must be strictly increasing")
    if not np.isfinite(t):
        raise ValueError(f"capture position must be finite, got {t}")
    j = int(np.searchsorted(times, t, side="left"))
    if j < len(times) and times[j] == t:
        return j, j, 0.0
    if j == 0:
        return 0, 0, 0.0
    if j == len(times):
        return j - 1, j - 1, 0.0
    return j - 1, j, float((t - times[j - 1]) / (times[j] - times[j - 1]))


def blend_luts(lut_a: np.ndarray, lut_b: np.ndarray, weight: float) -> np.ndarray:
    """The LUT a weight `weight` of the way from frame a's LUT to frame b's [levels]: the one whose
    inverse is (1 - w) a^-1 + w b^-1, so a processed value maps back to the blend of the original
    levels the two frames gave it. For frames that differ by a drifting offset or gain this is the
    in-between frame's LUT (a blend of the maps' outputs, level by level, is not; it predicted a
    held-out frame's own LUT worse on a real flight: docs/results/lut_prediction). Exact: both
    inverses are piecewise linear between the two LUTs' values, where they are blended. Strictly
    increasing when both are; a itself at w = 0, b at w = 1."""
    if not 0.0 <= weight <= 1.0:
        raise ValueError(f"blend weight must be in [0, 1], got {weight}")
    if weight == 0.0:
        return lut_a
    if weight == 1.0:
        return lut_b
    return blend_inverses([lut_a, lut_b], [1.0 - weight, weight])


def blend_inverses(luts: Sequence[np.ndarray], weights: Sequence[float]) -> np.ndarray:
    """The LUT [L] whose inverse is sum_i weights[i] * luts[i]^-1 (each LUT [L] strictly increasing,
    the weights non-negative and summing to 1): per processed value, the weighted mean of the original
    levels the frames gave it. Exact at every corner of any inverse (the union of the LUTs' values),
    linear between them; strictly increasing. `blend_luts` for two frames; the equal-weight mean of
    many is the fixed map with the least expected squared error over their states."""
    levels = np.arange(len(luts[0]), dtype=np.float64)  # [L]
    outputs = np.unique(np.concatenate(luts))  # [<= n L] every corner of any inverse
    inverse = np.zeros_like(outputs)  # [M], one LUT at a time: memory stays flat in the frame count
    for lut, weight in zip(luts, weights):
        inverse += weight * np.interp(outputs, lut, levels)
    return np.interp(levels, inverse, outputs)
