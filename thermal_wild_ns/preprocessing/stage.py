"""The preprocessing stage: run the photometric LUTs over a capture once, cache the result.

Frames are processed in capture order (train and held-out frames alike: they are one sensor
stream). The cache folder, keyed by the frames' files, the radiometric range and the parameters,
holds `luts.npy` ([T, levels] float64, memory-mapped when read back), the processed frames
(normalised float32 `.npy`, no 8-bit re-quantisation) and a `meta.json`; it is written to a
temporary folder and renamed into place, so it is never half-written and is rebuilt when the
data or parameters change.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import tempfile
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Union

import numpy as np
from tqdm import tqdm

from thermal_wild_ns.data.capture import ThermalFrame
from thermal_wild_ns.data.thermal_io import RadiometricRange, load_npy, publish_cache_folder, read_raw_frame
from thermal_wild_ns.preprocessing.photometric import LevelGrid, PhotometricConfig, apply_lut, frame_luts, invert_lut

CACHE_VERSION = 1


@dataclass
class PreprocessedSequence:
    """LUTs and processed frames of one capture (index = capture-order frame index)."""

    folder: Path
    grid: LevelGrid
    radiometric_range: RadiometricRange
    config: PhotometricConfig
    _median_luts: Dict[tuple, np.ndarray] = field(default_factory=dict, repr=False, compare=False)

    @property
    def luts(self) -> np.ndarray:
        """[T, levels] float64 native values (memory-mapped)."""
        return load_npy(self.folder / "luts.npy", mmap_mode="r")

    def frame_path(self, index: int, ground_truth: bool = False) -> Path:
        return self.folder / ("ground_truth" if ground_truth else "frames") / f"{index:05d}.npy"

    def read_frame(self, index: int, ground_truth: bool = False) -> np.ndarray:
        """Processed frame `index` ([H, W] float32, normalised; thread-safe)."""
        return load_npy(self.frame_path(index, ground_truth))

    def lut(self, index: Union[int, Sequence[int]]) -> np.ndarray:
        """Frame `index`'s LUT, or the level-wise median of several frames' LUTs: a canonical scale
        for a view no frame was captured at. The median of strictly increasing LUTs is strictly
        increasing, and one photometric outlier frame cannot move it; on the outlier stress scene the
        mean alone capped a novel view at 36.5 dB, the median gives 46.6 (tests/test_preprocessing.py).
        Computed once per set."""
        if isinstance(index, int):
            return np.asarray(self.luts[index])
        key = tuple(index)
        if key not in self._median_luts:
            self._median_luts[key] = np.median(np.asarray(self.luts[list(key)]), axis=0)
        return self._median_luts[key]

    def to_native(self, normalised: np.ndarray, index: Union[int, Sequence[int]]) -> np.ndarray:
        """Processed values in the normalised scale -> original native values, through `lut(index)`'s inverse."""
        return invert_lut(self.lut(index), self.radiometric_range.to_native(normalised), self.grid)

    def to_original_normalised(self, normalised: np.ndarray, index: Union[int, Sequence[int]]) -> np.ndarray:
        """Processed values -> the dataset-normalised ORIGINAL scale (where raw frames live)."""
        return self.radiometric_range.normalize(self.to_native(normalised, index))


def _key(frames: Sequence[ThermalFrame], rng: RadiometricRange, config: PhotometricConfig) -> str:
    h = hashlib.sha256(json.dumps({"v": CACHE_VERSION, "range": asdict(rng), "config": asdict(config)}, sort_keys=True).encode())
    for f in frames:
        for path in (f.image, f.ground_truth):
            if path is not None:
                stat = path.stat()
                h.update(f"{path.resolve()}:{stat.st_size}:{stat.st_mtime_ns}".encode())
    return h.hexdigest()[:16]


def _checked(path: Path, palette: Optional[str]) -> np.ndarray:
    frame = read_raw_frame(path, palette)
    if np.issubdtype(frame.dtype, np.floating) and not np.all(np.isfinite(frame)):
        raise ValueError(f"{path}: non-finite pixel values; preprocessing needs finite frames")
    return frame


def preprocess(frames: List[ThermalFrame], rng: RadiometricRange, config: PhotometricConfig, cache_root: Path) -> PreprocessedSequence:
    """LUTs + processed frames for `frames` (capture order), from the cache when up to date."""
    grid = LevelGrid.for_dtype(rng.dtype, rng.low, rng.high)
    folder = Path(cache_root) / f"preprocessed-{_key(frames, rng, config)}"
    sequence = PreprocessedSequence(folder, grid, rng, config)
    if (folder / "meta.json").is_file():
        return sequence
    Path(cache_root).mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=".preprocessing-", dir=cache_root))
    try:
        (work / "frames").mkdir()
        (work / "ground_truth").mkdir()
        luts = np.lib.format.open_memmap(work / "luts.npy", mode="w+", dtype=np.float64, shape=(len(frames), grid.num_levels))
        current: List[np.ndarray] = []  # the frame frame_luts is on: each file is read once

        def raw_frames():
            for f in frames:
                current[:] = [_checked(f.image, rng.palette)]
                yield current[0]

        stream = frame_luts(raw_frames(), grid, rng.low, rng.high, config)
        for t, (frame, lut) in enumerate(tqdm(zip(frames, stream), total=len(frames), desc=f"Preprocessing ({config.variant})")):
            luts[t] = lut
            np.save(work / "frames" / f"{t:05d}.npy", rng.normalize(apply_lut(lut, current[0], grid)))
            if frame.ground_truth is not None:
                gt = apply_lut(lut, _checked(frame.ground_truth, rng.palette), grid)
                np.save(work / "ground_truth" / f"{t:05d}.npy", rng.normalize(gt))
        luts.flush()
        del luts
        (work / "meta.json").write_text(json.dumps({"config": asdict(config), "range": asdict(rng), "frames": [str(f.image) for f in frames]}, indent=1))
        publish_cache_folder(work, folder, "meta.json")
    except BaseException:
        shutil.rmtree(work, ignore_errors=True)
        raise
    return sequence
