"""`wild-thermal-diagnose --data PATH`: how wild is this thermal sequence, before and after
preprocessing (the paper's Fig. 2/3 diagnostics).

Reads any supported layout, runs the chosen preprocessing variant over the capture (capture
order) and writes to `--output-dir`:
- `diagnostics.json`: per-frame dI_t, tracked SIFT features per consecutive pair, the mean radial
  power spectrum, the histogram, and a summary, each before and after; the largest error (in
  native levels) of mapping the processed frames back through their inverse LUTs; and how much
  that inverse magnifies a rendering error, over all pixels and at each frame's hottest 5 %;
- `diagnostics.png`: the four panels (dI_t per frame, tracked features per frame pair, mean radial
  power spectrum, histogram), before vs after;
- `frames.png`: a few frames before and after, on the dataset's one radiometric range.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Dict, List

import cv2
import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import tyro

from thermal_wild_ns.analysis.diagnostics import (
    error_amplification,
    gain_summary,
    high_frequency_ratio,
    inverse_lut_gain,
    radial_power_spectrum,
    relative_mean_change,
    tracked_features,
    used_dynamic_range,
)
from thermal_wild_ns.data.dataparsers import LayoutName, ThermalDataParserConfig
from thermal_wild_ns.data.palettes import false_colour
from thermal_wild_ns.errors import report_input_errors_briefly
from thermal_wild_ns.preprocessing.photometric import PREPROCESSING_FLAG, PhotometricConfig
from thermal_wild_ns.preprocessing.stage import PreprocessedSequence, preprocess
from thermal_wild_ns.progress import track


@dataclass
class DiagnoseArgs:
    data: Path
    """Dataset folder (any supported layout)."""
    layout: LayoutName = "auto"
    """Dataset layout ('auto' detects it)."""
    preprocessing: PhotometricConfig = field(default_factory=PhotometricConfig)
    """The preprocessing whose effect is shown ('after')."""
    output_dir: Path = Path("outputs/diagnostics")
    spectrum_frames: int = 16
    """Frames (evenly spaced) averaged into the power spectrum."""
    cache_dir: Path = Path("outputs/.thermal_cache")
    """Where the processed frames and LUTs are cached (shared with training's preprocessing stage)."""


def _frames_stats(frames: List[np.ndarray], native_means: List[float], spectrum_frames: int) -> Dict:
    picks = np.unique(np.linspace(0, len(frames) - 1, min(spectrum_frames, len(frames))).astype(int))
    spectra = [radial_power_spectrum(frames[i]) for i in picks]
    freqs, power = spectra[0][0], np.mean([p for _, p in spectra], axis=0)
    delta = relative_mean_change(native_means)
    tracks = tracked_features(frames) if len(frames) > 1 else []
    dynamic = used_dynamic_range(frames)
    return {
        "delta_i": delta.tolist(),
        "std_delta_i": float(np.std(delta)),
        "tracked_features": tracks,
        "median_tracked_features": float(np.median(tracks)) if tracks else 0.0,
        "spectrum_freqs": freqs.tolist(),
        "spectrum_power": power.tolist(),
        "high_frequency_ratio": high_frequency_ratio(freqs, power),
        "dynamic_range": dynamic,
    }


def summary_line(name: str, before: Dict, after: Dict) -> str:
    def pair(key, fmt):
        return f"{format(before[key], fmt)} -> {format(after[key], fmt)}"

    return (
        f"{name}: std dI_t {pair('std_delta_i', '.4f')}, high-frequency energy {pair('high_frequency_ratio', '.4f')}, "
        f"used dynamic range {before['dynamic_range']['used_range']:.3f} -> "
        f"{after['dynamic_range']['used_range']:.3f}, "
        f"median tracked SIFT features {pair('median_tracked_features', '.0f')}"
    )


def preprocessing_advice(sequence: PreprocessedSequence) -> str:
    """What training does with this capture's frames: `wild-thermal` trains on the raw frames by default
    (said first: with its camera model and per-frame state, preprocessing cost both real captures, even
    where the contrast rule would apply it, docs/results/preprocessing_camera_h200), then what the contrast
    rule (`PreprocessedSequence.decision`, `PhotometricConfig.skip_when_stable`) decides where
    preprocessing is asked for, and why. Never a recommendation to preprocess that the evidence contradicts."""
    decision = sequence.decision()
    what = "preprocess this capture" if decision.pays else "still train on its raw frames"
    return (
        "`wild-thermal` trains on the raw frames (its default: its camera model and per-frame state follow "
        f"the frames' changes); asked for ({PREPROCESSING_FLAG} stab+bbhe), the contrast rule would {what}: "
        f"{decision.reason}"
    )


def _plot(result: Dict, path: Path, title: str) -> None:
    matplotlib.use("Agg")

    before, after = result["before"], result["after"]
    label_b, label_a = "raw", f"after {result['preprocessing']['variant']}"
    fig, ax = plt.subplots(2, 2, figsize=(11, 7.5))
    ax[0, 0].plot(before["delta_i"], "o-", ms=3, label=f"{label_b} (std {before['std_delta_i']:.4f})")
    ax[0, 0].plot(after["delta_i"], "o-", ms=3, label=f"{label_a} (std {after['std_delta_i']:.4f})")
    ax[0, 0].axhline(0, color="grey", lw=0.5)
    ax[0, 0].set(
        title="relative mean change per frame, dI_t", xlabel="frame (capture order)", ylabel="(mu_t - mu) / mu"
    )
    ax[0, 1].plot(before["tracked_features"], label=f"{label_b} (median {before['median_tracked_features']:.0f})")
    ax[0, 1].plot(after["tracked_features"], label=f"{label_a} (median {after['median_tracked_features']:.0f})")
    ax[0, 1].set(title="SIFT features tracked to the next frame", xlabel="frame pair (t, t+1)", ylabel="RANSAC inliers")
    for stats, label in ((before, label_b), (after, label_a)):
        ax[1, 0].loglog(
            stats["spectrum_freqs"], stats["spectrum_power"], label=f"{label} (HF {stats['high_frequency_ratio']:.3f})"
        )
        hist = np.asarray(stats["dynamic_range"]["histogram"])
        ax[1, 1].plot(
            np.linspace(0, 1, len(hist)),
            hist / hist.sum(),
            label=f"{label} (p1-p99 {stats['dynamic_range']['used_range']:.2f})",
        )
    ax[1, 0].set(
        title="radially averaged power spectrum (mean over frames)", xlabel="frequency / Nyquist", ylabel="power"
    )
    ax[1, 1].set(
        title="intensity histogram, all frames", xlabel="normalised intensity (dataset range)", ylabel="share of pixels"
    )
    for a in ax.ravel():
        a.legend(fontsize=8)
        a.grid(alpha=0.3)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _frames_png(
    raw: List[np.ndarray], processed: List[np.ndarray], path: Path, count: int = 4, tile_width: int = 256
) -> None:
    """Top row raw, bottom row processed, `count` evenly spaced frames, inferno on [0, 1]."""

    picks = np.unique(np.linspace(0, len(raw) - 1, min(count, len(raw))).astype(int))

    def tile(frames):
        tiles = []
        for i in picks:
            h, w = frames[i].shape
            small = cv2.resize(frames[i], (tile_width, max(1, round(h * tile_width / w))), interpolation=cv2.INTER_AREA)
            tiles.append(false_colour(small))
        return np.concatenate(tiles, 1)

    cv2.imwrite(str(path), np.concatenate([tile(raw), tile(processed)], 0))


def diagnose(args: DiagnoseArgs) -> Dict:
    parser = ThermalDataParserConfig(data=args.data, layout=args.layout).setup()
    capture, rng = parser.capture(), parser.radiometric_range()
    args.output_dir.mkdir(parents=True, exist_ok=True)
    sequence = preprocess(capture.frames, rng, args.preprocessing, args.cache_dir)
    raw = [rng.read(f.image) for f in track(capture.frames, "Reading frames")]
    processed = [sequence.read_frame(t) for t in range(len(capture.frames))]
    native = lambda frames: [float(rng.to_native(f.mean())) for f in frames]  # noqa: E731
    result = {
        "data": str(args.data),
        "layout": capture.layout,
        "frames": len(capture.frames),
        "degenerate_frames": parser.degenerate_frames,  # no contrast: left out of training and of these statistics
        "radiometric_range": {"low": rng.low, "high": rng.high, "dtype": rng.dtype},
        "preprocessing": asdict(args.preprocessing),
        # the stored processed frames mapped back through their inverse LUTs, against the raw frames
        "lut_round_trip_max_levels": max(
            float(np.abs(sequence.to_original_normalised(p, sequence.lut(t)) - r).max())
            * (rng.high - rng.low)
            / sequence.grid.step
            for t, (p, r) in enumerate(zip(processed, raw))
        ),
        # a render's error at a pixel grows by this much when mapped back (hot, rare levels most)
        "inverse_lut_gain": gain_summary(
            [
                inverse_lut_gain(np.asarray(sequence.lut(t)), sequence.grid.levels(rng.to_native(r)))
                for t, r in enumerate(raw)
            ],
            raw,
        ),
        "error_amplification": error_amplification(
            processed, raw, lambda values, t: sequence.to_original_normalised(values, sequence.lut(t))
        ),
        "before": _frames_stats(raw, native(raw), args.spectrum_frames),
        "after": _frames_stats(processed, native(processed), args.spectrum_frames),
    }
    name = Path(args.data).resolve().name
    gain = result["inverse_lut_gain"]
    result["summary"] = summary_line(name, result["before"], result["after"]) + (
        f"; inverse-LUT error gain: median {gain['median']:.2f}, hottest 5 % {gain['median_hottest']:.2f}"
        f" ({100 * gain['hottest_over_4x']:.0f} % of them above 4x)"
        f"; a training-space error of {result['error_amplification']['sigma']} becomes "
        f"x{result['error_amplification']['rms']:.2f} RMS"
        f" (hottest 5 %: x{result['error_amplification']['rms_hottest']:.2f})"
    )
    result["advice"] = preprocessing_advice(sequence)
    (args.output_dir / "diagnostics.json").write_text(json.dumps(result, indent=1))
    _plot(
        result,
        args.output_dir / "diagnostics.png",
        f"{name} ({capture.layout}, {len(raw)} frames): raw vs {args.preprocessing.variant}",
    )
    _frames_png(raw, processed, args.output_dir / "frames.png")
    print(result["summary"])
    if parser.degenerate_frames:
        print(f"frames with no contrast (left out): {', '.join(parser.degenerate_frames)}")
    print(f"preprocessing: {result['advice']}")
    print(
        f"written: {args.output_dir / 'diagnostics.json'}, {args.output_dir / 'diagnostics.png'}, "
        f"{args.output_dir / 'frames.png'}"
    )
    return result


def entrypoint():
    report_input_errors_briefly()
    diagnose(tyro.cli(DiagnoseArgs))


if __name__ == "__main__":
    entrypoint()
