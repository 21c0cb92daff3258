"""How wild is a thermal sequence: the paper's dataset diagnostics, as pure functions.

- relative mean change per frame: dI_t = (mu_t - mean(mu)) / mean(mu) (its std summarises drift);
- radially averaged power spectrum of a frame (and the share of energy above half Nyquist);
- intensity histogram and the used dynamic range;
- SIFT features tracked from each frame to the next (ratio test + RANSAC on the fundamental matrix);
- how much preprocessing's inverse LUT magnifies a rendering error, per pixel (`inverse_lut_gain`)
  and for a simulated error across the frame (`error_amplification`).

Frames are given in the dataset's normalised scale (0..1 over its radiometric range), so numbers
are comparable between datasets and before/after preprocessing.
"""

from __future__ import annotations

from typing import Dict, Iterable, List, Sequence, Tuple

import cv2
import numpy as np


def relative_mean_change(means: Sequence[float]) -> np.ndarray:
    """dI_t = (mu_t - mu_bar) / mu_bar for per-frame means mu_t (native units, positive)."""
    means = np.asarray(means, dtype=np.float64)
    bar = means.mean()
    if bar == 0:
        raise ValueError("mean intensity is zero: the relative change is undefined (use native units)")
    return (means - bar) / bar


def radial_power_spectrum(frame: np.ndarray, bins: int = 64) -> Tuple[np.ndarray, np.ndarray]:
    """Radially averaged power of the mean-removed frame: frequencies [bins] (fraction of
    Nyquist, bin centres) and mean power per bin [bins]."""
    f = np.fft.fftshift(np.fft.fft2(frame - frame.mean()))
    power = np.abs(f) ** 2 / frame.size
    h, w = frame.shape
    fy = (np.arange(h) - h // 2) / (h / 2)
    fx = (np.arange(w) - w // 2) / (w / 2)
    radius = np.sqrt(fy[:, None] ** 2 + fx[None, :] ** 2)
    index = np.minimum((radius * bins).astype(np.int64), bins)  # radius 1 = Nyquist; corners beyond are dropped
    sums = np.bincount(index.ravel(), power.ravel(), minlength=bins + 1)[:bins]
    counts = np.bincount(index.ravel(), minlength=bins + 1)[:bins]
    return (np.arange(bins) + 0.5) / bins, sums / np.maximum(counts, 1)


def high_frequency_ratio(freqs: np.ndarray, power: np.ndarray, cutoff: float = 0.5) -> float:
    """Share of the (radially averaged) spectral energy above `cutoff` x Nyquist, weighted by ring area."""
    energy = power * freqs  # ring area grows with radius
    total = energy.sum()
    return float(energy[freqs > cutoff].sum() / total) if total > 0 else 0.0


def used_dynamic_range(frames: Iterable[np.ndarray], bins: int = 256) -> Dict:
    """Histogram over all frames (normalised scale, streamed) and how much of [0, 1] the p1..p99
    span covers, plus the share of the `bins` display bins holding at least 0.01 % of the pixels."""
    fine_edges = np.linspace(-0.5, 1.5, 8193)  # percentiles from a fine histogram: no frame is kept
    fine = np.zeros(8192)
    for frame in frames:
        fine += np.histogram(np.clip(frame, -0.5, 1.5), bins=fine_edges)[0]
    cdf = np.cumsum(fine) / fine.sum()
    centres = (fine_edges[:-1] + fine_edges[1:]) / 2
    p1, p99 = (float(centres[np.searchsorted(cdf, q)]) for q in (0.01, 0.99))
    inside = (centres >= 0) & (centres < 1)
    hist = fine[inside].reshape(bins, -1).sum(1)  # 4096 fine bins in [0, 1) -> `bins`
    return {
        "p1": p1,
        "p99": p99,
        "used_range": float(np.clip(p99, 0, 1) - np.clip(p1, 0, 1)),
        "occupied_bins": float(np.mean(hist > 1e-4 * fine.sum())),
        "histogram": hist.tolist(),
    }


def to_uint8(frame: np.ndarray) -> np.ndarray:
    return (np.clip(frame, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def tracked_features(frames: Sequence[np.ndarray], max_features: int = 4000, ratio: float = 0.8) -> List[int]:
    """SIFT matches from frame t to t+1 that survive the ratio test and a RANSAC fundamental
    matrix (1 px): one count per consecutive pair [T-1]."""
    sift = cv2.SIFT_create(nfeatures=max_features)
    matcher = cv2.BFMatcher(cv2.NORM_L2)
    features = [sift.detectAndCompute(to_uint8(f), None) for f in frames]
    counts = []
    for (kp_a, des_a), (kp_b, des_b) in zip(features[:-1], features[1:]):
        if des_a is None or des_b is None or len(des_a) < 8 or len(des_b) < 8:
            counts.append(0)
            continue
        good = [
            m[0] for m in matcher.knnMatch(des_a, des_b, k=2) if len(m) == 2 and m[0].distance < ratio * m[1].distance
        ]
        if len(good) < 8:
            counts.append(0)
            continue
        a = np.float32([kp_a[m.queryIdx].pt for m in good])
        b = np.float32([kp_b[m.trainIdx].pt for m in good])
        _, inliers = cv2.findFundamentalMat(a, b, cv2.FM_RANSAC, 1.0, 0.999)
        counts.append(int(inliers.sum()) if inliers is not None else 0)
    return counts


def inverse_lut_gain(lut: np.ndarray, levels: np.ndarray, span: int = 2) -> np.ndarray:
    """How much a small error in a processed frame grows when mapped back through the inverse of its
    LUT: 1 / the LUT's slope at each pixel's level, measured over +-`span` levels (both in native
    units). Equalization gives rare levels a shallow slope, so errors at those pixels (often the
    hottest objects) grow. `lut`: [levels] native values; `levels`: [H, W] int."""
    top = len(lut) - 1
    slope = (lut[np.clip(levels + span, 0, top)] - lut[np.clip(levels - span, 0, top)]) / (
        np.clip(levels + span, 0, top) - np.clip(levels - span, 0, top)
    )
    return 1.0 / np.maximum(slope, 1e-12)


def _hottest(values: np.ndarray, frame: np.ndarray, share: float) -> np.ndarray:
    """`values` at the frame's hottest `share` of pixels."""
    return values[frame >= np.quantile(frame, 1.0 - share)]


def error_amplification(
    processed: Sequence[np.ndarray],
    raw: Sequence[np.ndarray],
    to_original,
    sigma: float = 0.005,
    hottest: float = 0.05,
    seed: int = 0,
) -> Dict[str, float]:
    """What a rendering error becomes in the original space: Gaussian noise of std `sigma` (training
    space, normalised) is added to each processed frame, mapped back (`to_original(values, t)`) and
    compared with the raw frame. Ratios of the RMS error to sigma over all pixels and each frame's
    hottest `hottest` share, and the 99th percentile of |error| / sigma. Unlike the local slope
    (`inverse_lut_gain`) this also counts an error that carries a pixel across an empty stretch of
    levels (between a hot object and its cold background), which equalization squeezes."""
    rs = np.random.default_rng(seed)
    errors, hot = [], []
    for t, (p, r) in enumerate(zip(processed, raw)):
        error = to_original(p + sigma * rs.standard_normal(p.shape).astype(np.float32), t) - r
        errors.append(error.ravel())
        hot.append(_hottest(error, r, hottest))
    every, hot_all = np.concatenate(errors), np.concatenate(hot)
    rms = lambda e: float(np.sqrt(np.mean(np.square(e))))  # noqa: E731
    return {
        "sigma": sigma,
        "rms": rms(every) / sigma,
        "rms_hottest": rms(hot_all) / sigma,
        "p99": float(np.quantile(np.abs(every), 0.99)) / sigma,
    }


def gain_summary(gains: Sequence[np.ndarray], frames: Sequence[np.ndarray], hottest: float = 0.05) -> Dict[str, float]:
    """Median inverse-LUT gain over all pixels and over each frame's hottest `hottest` share, and the
    share of those hottest pixels whose errors grow more than 4x."""
    hot = [_hottest(g, f, hottest) for g, f in zip(gains, frames)]
    everything, hot_all = np.concatenate([g.ravel() for g in gains]), np.concatenate(hot)
    return {
        "median": float(np.median(everything)),
        "median_hottest": float(np.median(hot_all)),
        "hottest_over_4x": float((hot_all > 4.0).mean()),
    }
