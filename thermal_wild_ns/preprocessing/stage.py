"""The preprocessing stage: run the photometric LUTs over a capture once, cache the result.

Frames are processed in capture order. Only training frames update the stabilization reference
and only their processed frames are stored: a held-out frame never shapes what the model trains
on. Each held-out frame still gets a LUT from its own histogram, kept apart as an oracle
(`oracle_lut`): it is built from that frame's pixels, so a leak-free score never uses it. A
held-out or novel view's leak-free LUT is `lut_at(t)`, interpolated from the training frames.

The cache folder, keyed by the frames' files, the split, the radiometric range and the parameters,
holds `luts.npy` ([T, levels] float64, memory-mapped when read back), the processed training
frames (normalised float32 `.npy`, no 8-bit re-quantisation) and a `meta.json`; it is written to
a temporary folder and renamed into place, so it is never half-written and is rebuilt when the
data, split or parameters change.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from dataclasses import asdict, dataclass, field
from functools import cached_property
from pathlib import Path
from typing import List, NamedTuple, Optional, Sequence, Tuple

import numpy as np
from nerfstudio.utils.rich_utils import CONSOLE

from thermal_wild_ns.data.capture import ThermalFrame
from thermal_wild_ns.data.thermal_io import (
    RadiometricRange,
    discard_cache_folder,
    load_npy,
    make_work_folder,
    publish_cache_folder,
    read_raw_frame,
)
from thermal_wild_ns.errors import InputError
from thermal_wild_ns.preprocessing.photometric import (
    LevelGrid,
    PhotometricConfig,
    apply_lut,
    blend_luts,
    frame_luts,
    invert_lut,
    time_weights,
)
from thermal_wild_ns.progress import track

CACHE_VERSION = 4


def frame_mean_spread(means: Sequence[float]) -> float:
    """How much a sequence's mean level wanders: the median absolute deviation of the frames' means
    (scaled to a standard deviation), in the dataset-normalised scale so raw and processed frames
    compare whatever the units. Robust: one outlier frame does not make a stable capture look
    unsteady (on such a capture, preprocessing costs accuracy: docs/results/stress_protocols_3seeds)."""
    means = np.asarray(means, dtype=np.float64)
    return float(1.4826 * np.median(np.abs(means - np.median(means))))


CONTRAST_QUANTILES = np.linspace(0.02, 0.98, 49)
"""Where each training frame's quantile function is sampled for `frame_contrast_spread`."""
CONTRAST_SPREAD = 0.15
"""`frame_contrast_spread` from which preprocessing pays (`preprocessing_pays`): between a real drone
capture's and those of scenes whose frames differ by level offsets, gains within a few percent
(chosen by docs/results/preprocessing_rule, which lists each scene's)."""


def frame_quantiles(frame: np.ndarray, max_samples: int = 65536) -> np.ndarray:
    """A frame's quantile function at `CONTRAST_QUANTILES` [P] (of a strided subsample on large frames)."""
    flat = np.asarray(frame, dtype=np.float64).reshape(-1)
    return np.quantile(flat[:: flat.size // max_samples + 1], CONTRAST_QUANTILES)


def frame_contrast_spread(quantiles: Sequence[Sequence[float]]) -> float:
    """How much the frames' contrast varies: each frame's quantile function [P] fitted, least
    squares, as gain x the median frame's + offset; the spread of the log gains (median absolute
    deviation scaled to a standard deviation, robust to an outlier frame). A sensor's automatic
    gain control moves it; level offsets (warm-up drift, flat-field corrections) do not."""
    q = np.asarray(quantiles, dtype=np.float64)  # [T, P]
    reference = np.median(q, axis=0)  # [P]
    centred = reference - reference.mean()
    if not np.any(centred):
        return 0.0
    gains = (q - q.mean(axis=1, keepdims=True)) @ centred / (centred @ centred)  # [T]
    log_gains = np.log(np.clip(gains, 1e-6, None))
    return float(1.4826 * np.median(np.abs(log_gains - np.median(log_gains))))


def preprocessing_pays(raw_spread: float, processed_spread: float, contrast_spread: float) -> bool:
    """The rule of `PhotometricConfig.skip_when_stable`. Preprocessing exists to make consecutive
    frames consistent: where it leaves their mean levels no steadier, the capture was already
    stable and preprocessing only costs accuracy (docs/results/stress_protocols_3seeds). Where the
    frames differ by level offsets alone, the frame embeddings follow them, and preprocessing costs
    `aligned` accuracy; where their contrast varies (`frame_contrast_spread` >= `CONTRAST_SPREAD`),
    it pays (docs/results/preprocessing_rule)."""
    return processed_spread < raw_spread and contrast_spread >= CONTRAST_SPREAD


class PreprocessingDecision(NamedTuple):
    """`PreprocessedSequence.decision`: whether preprocessing pays, why in words, and the measurements."""

    pays: bool
    reason: str
    raw_spread: float  # `frame_mean_spread` of the raw training frames
    processed_spread: float  # ... of the preprocessed ones
    contrast_spread: float  # `frame_contrast_spread` of the raw training frames


@dataclass
class PreprocessedSequence:
    """LUTs and processed training frames of one capture (index = capture-order frame index)."""

    folder: Path
    grid: LevelGrid
    radiometric_range: RadiometricRange
    config: PhotometricConfig
    _median: Optional[np.ndarray] = field(default=None, repr=False, compare=False)

    @cached_property
    def meta(self) -> dict:
        """The cache folder's meta.json (read once)."""
        return json.loads((self.folder / "meta.json").read_text())

    @property
    def train_indices(self) -> List[int]:
        """Capture indices of the training frames (increasing): the frames whose LUTs are a state."""
        return self.meta["train_indices"]

    @property
    def luts(self) -> np.ndarray:
        """[T, levels] float64 native values (memory-mapped); held-out rows are oracle LUTs."""
        return load_npy(self.folder / "luts.npy", mmap_mode="r")

    def frame_mean_spreads(self) -> Tuple[float, float]:
        """`frame_mean_spread` of the training frames, raw and processed (what `preprocessing_pays`
        decides from)."""
        means = self.meta["training_frame_means"]
        return frame_mean_spread(means["raw"]), frame_mean_spread(means["processed"])

    def frame_contrast_spread(self) -> float:
        """`frame_contrast_spread` of the raw training frames."""
        return frame_contrast_spread(self.meta["training_frame_quantiles"])

    def decision(self) -> PreprocessingDecision:
        """Whether preprocessing pays for this capture (`preprocessing_pays`), with the measurements
        that say so, in words too (logged at setup, recorded by the bench, advised by wild-thermal-diagnose)."""
        raw, processed = self.frame_mean_spreads()
        contrast = self.frame_contrast_spread()
        measured = f"frame-mean spread {raw:.4f} -> {processed:.4f} preprocessed, contrast spread {contrast:.3f}"
        pays = preprocessing_pays(raw, processed, contrast)
        if pays:
            reason = f"the frames' levels and contrast vary ({measured})"
        elif processed >= raw:
            reason = f"the capture is stable ({measured})"
        else:
            offsets = "the frames differ by level offsets, which the frame embeddings follow"
            reason = f"{offsets} ({measured}, under {CONTRAST_SPREAD})"
        return PreprocessingDecision(pays, reason, raw, processed, contrast)

    def problem(self, frame_count: int) -> Optional[str]:
        """What is wrong with the cache folder (a file missing, cut short or unreadable), or None.
        Reads the files' headers and sizes only, not their pixels."""
        try:
            train = self.train_indices
            luts = self.luts
            if luts.shape != (frame_count, self.grid.num_levels):
                return f"luts.npy holds {luts.shape}, not ({frame_count}, {self.grid.num_levels})"
            for index in train:
                load_npy(self.frame_path(index), mmap_mode="r")  # a file cut short fails its mapping
        except (OSError, ValueError, KeyError) as err:
            return str(err)
        return None

    def frame_path(self, index: int) -> Path:
        return self.folder / "frames" / f"{index:05d}.npy"

    def read_frame(self, index: int) -> np.ndarray:
        """Processed training frame `index` ([H, W] float32, normalised; thread-safe)."""
        if index not in set(self.train_indices):
            raise KeyError(f"frame {index} is held out: only training frames are preprocessed")
        return load_npy(self.frame_path(index))

    def lut(self, index: int) -> np.ndarray:
        """Training frame `index`'s LUT."""
        if index not in set(self.train_indices):
            raise KeyError(
                f"frame {index} is held out: its own LUT is built from its pixels (oracle_lut); "
                "a leak-free LUT for it is lut_at(index)"
            )
        return np.asarray(self.luts[index])

    def oracle_lut(self, index: int) -> np.ndarray:
        """A held-out frame's LUT from its own histogram: an upper bound that uses the frame's
        pixels, never part of a leak-free score."""
        return np.asarray(self.luts[index])

    def lut_at(self, t: float, without: Sequence[int] = ()) -> np.ndarray:
        """The LUT at capture position `t`: between the neighbouring training frames' LUTs, through
        their inverses (`blend_luts`; exactly a training frame's own at its index), strictly increasing.
        `without`: training frames (capture indices) not to interpolate from (held back from
        training: their own LUT is made from their pixels)."""
        left_out = set(without)
        frames = [index for index in self.train_indices if index not in left_out]
        i, j, w = time_weights(frames, t)
        luts = self.luts
        return blend_luts(np.asarray(luts[frames[i]]), np.asarray(luts[frames[j]]), w)

    def median_lut(self) -> np.ndarray:
        """Level-wise median of the training frames' LUTs: a canonical scale for a view no frame was
        captured at. The median of strictly increasing LUTs is strictly increasing, and one
        photometric outlier frame cannot move it (tests/test_preprocessing.py). Computed once."""
        if self._median is None:
            # a band of levels at a time, through a mapping opened per band: memory stays flat in
            # the frame count (all training LUTs at once are 0.5 MB per frame on a 16-bit grid)
            rows, levels = self.train_indices, self.grid.num_levels
            median = np.empty(levels)
            for start in range(0, levels, _LEVEL_BAND):
                band = np.array(self.luts[rows, start : start + _LEVEL_BAND])
                median[start : start + _LEVEL_BAND] = np.median(band, axis=0)
            self._median = median
        return self._median

    def to_original_normalised(self, normalised: np.ndarray, lut: np.ndarray) -> np.ndarray:
        """Processed values (normalised training space) -> the dataset-normalised ORIGINAL scale
        (where raw frames live), through `lut`'s inverse."""
        rng = self.radiometric_range
        return rng.normalize(invert_lut(lut, rng.to_native(normalised), self.grid))

    def to_processed_normalised(self, normalised: np.ndarray, lut: np.ndarray) -> np.ndarray:
        """Original values (dataset-normalised) -> the training space, through `lut` (linear
        between levels): what a frame at that state would have been preprocessed to."""
        rng, grid = self.radiometric_range, self.grid
        levels = (rng.to_native(np.asarray(normalised, dtype=np.float64)) - grid.offset) / grid.step
        return rng.normalize(np.interp(levels, np.arange(grid.num_levels, dtype=np.float64), lut))


def _key(
    frames: Sequence[ThermalFrame], train: Sequence[bool], rng: RadiometricRange, config: PhotometricConfig
) -> str:
    h = hashlib.sha256(
        json.dumps(
            {"v": CACHE_VERSION, "range": asdict(rng), "config": _processing(config), "train": list(train)},
            sort_keys=True,
        ).encode()
    )
    for f in frames:
        stat = f.image.stat()
        h.update(f"{f.image.resolve()}:{stat.st_size}:{stat.st_mtime_ns}".encode())
    return h.hexdigest()[:16]


def _processing(config: PhotometricConfig) -> dict:
    """The settings that shape the processed frames (the cache key: `skip_when_stable` only decides
    whether they are used)."""
    return {k: v for k, v in asdict(config).items() if k != "skip_when_stable"}


def _checked(path: Path, palette: Optional[str]) -> np.ndarray:
    frame = read_raw_frame(path, palette)
    if np.issubdtype(frame.dtype, np.floating) and not np.all(np.isfinite(frame)):
        raise InputError(f"{path}: non-finite pixel values; preprocessing needs finite frames")
    return frame


_LEVEL_BAND = 4096
"""Levels per band when the median LUT is computed."""


def preprocess(
    frames: List[ThermalFrame],
    rng: RadiometricRange,
    config: PhotometricConfig,
    cache_root: Path,
    train: Optional[Sequence[bool]] = None,
) -> PreprocessedSequence:
    """LUTs for `frames` (capture order) and the processed training frames, from the cache when up
    to date. `train[t]`: whether frame t is a training frame (default: all are, as for diagnostics
    of a whole capture); the others never touch the stabilization reference."""
    train = [True] * len(frames) if train is None else [bool(x) for x in train]
    if len(train) != len(frames):
        raise InputError(f"{len(train)} training flags for {len(frames)} frames")
    if not any(train):
        raise InputError("no training frames to preprocess")
    grid = LevelGrid.for_dtype(rng.dtype, rng.low, rng.high)
    folder = Path(cache_root) / f"preprocessed-{_key(frames, train, rng, config)}"
    sequence = PreprocessedSequence(folder, grid, rng, config)
    if (folder / "meta.json").is_file():
        problem = sequence.problem(len(frames))
        if problem is None:
            return sequence
        CONSOLE.log(f"[yellow]{folder}: the preprocessing cache is damaged ({problem}): preprocessing again")
        discard_cache_folder(folder)
        sequence = PreprocessedSequence(folder, grid, rng, config)
    work = make_work_folder(Path(cache_root), ".preprocessing-")
    try:
        (work / "frames").mkdir()
        # written row by row through the file, not a writable mapping: a mapping's dirty pages would
        # all count as this process's memory until the end (0.5 MB per frame on a 16-bit grid)
        luts = open(work / "luts.npy", "wb")
        header = {"descr": "<f8", "fortran_order": False, "shape": (len(frames), grid.num_levels)}
        np.lib.format.write_array_header_1_0(luts, header)
        current: List[np.ndarray] = []  # the frame frame_luts is on: each file is read once
        means: dict = {"raw": [], "processed": []}  # training frames, normalised
        quantiles: List[List[float]] = []  # training frames, raw, normalised

        def raw_frames():
            for f in frames:
                current[:] = [_checked(f.image, rng.palette)]
                yield current[0]

        stream = frame_luts(raw_frames(), grid, rng.low, rng.high, config, in_reference=train)
        for t, lut in enumerate(track(stream, f"Preprocessing ({config.variant})", total=len(frames))):
            luts.write(np.ascontiguousarray(lut, dtype="<f8").tobytes())
            if train[t]:
                processed = rng.normalize(apply_lut(lut, current[0], grid))
                np.save(work / "frames" / f"{t:05d}.npy", processed)
                raw = rng.normalize(current[0])
                means["raw"].append(float(raw.mean()))
                means["processed"].append(float(processed.mean()))
                quantiles.append(frame_quantiles(raw).tolist())
        luts.close()
        meta = {
            "config": _processing(config),
            "range": asdict(rng),
            "frames": [str(f.image) for f in frames],
            "train_indices": [t for t, is_train in enumerate(train) if is_train],
            "training_frame_means": means,
            "training_frame_quantiles": quantiles,
        }
        (work / "meta.json").write_text(json.dumps(meta, indent=1))
        publish_cache_folder(work, folder, "meta.json")
    except BaseException:
        shutil.rmtree(work, ignore_errors=True)
        raise
    return sequence
