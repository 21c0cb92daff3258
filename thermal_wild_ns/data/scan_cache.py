"""A capture's frame scan (`thermal_io.scan_frames`: every frame read once, the radiometric range measured), kept
for the commands after training: `ns-eval`, the exports, `ns-render` and the viewer each set up the dataparser,
and a survey of thousands of frames would be read again by each. Kept per set of inputs (each frame file's path,
size and modification time, and the scan's settings): a frame changed, added or removed is a new key, scanned
again. The scan's warnings are kept with it and said again on every use."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import warnings
from pathlib import Path
from typing import Callable, Optional, Sequence

from thermal_wild_ns.data.thermal_io import FrameScan, RadiometricRange

SCAN_CACHE_VERSION = 1
"""Bumped when what a scan measures changes: earlier entries are then never read."""


def scan_key(paths: Sequence[Path], settings: dict) -> str:
    """A digest of the frame files (path, size, modification time) and the scan's `settings` (a value JSON has no
    form for, such as a declared range, by its repr)."""
    files = []
    for path in paths:
        stat = os.stat(path)
        files.append([str(Path(path).resolve()), stat.st_size, stat.st_mtime_ns])
    entry = {"version": SCAN_CACHE_VERSION, "files": files, "settings": settings}
    text = json.dumps(entry, sort_keys=True, default=repr)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def cached_scan(folder: Path, key: str, scan: Callable[[], FrameScan]) -> FrameScan:
    """The scan of `key` from `folder` (its warnings said again), or `scan()` run, said and kept there. A range that
    holds a camera calibration is not kept (it is scanned each time); a folder that cannot be written keeps
    nothing."""
    path = Path(folder) / f"scan-{key}.json"
    if path.is_file():
        kept = json.loads(path.read_text())
        for message in kept["warnings"]:
            warnings.warn(message, UserWarning, stacklevel=2)
        return FrameScan(RadiometricRange(**kept["range"]), kept["degenerate"])
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        result = scan()
    for warning in said:  # said as they would have been without the record
        warnings.warn_explicit(warning.message, warning.category, warning.filename, warning.lineno)
    if result.range.planck is None and result.range.frame_celsius is None:
        _keep(
            path,
            {
                "range": dataclasses.asdict(result.range),
                "degenerate": result.degenerate,
                "warnings": [str(w.message) for w in said if issubclass(w.category, UserWarning)],
            },
        )
    return result


def _keep(path: Path, entry: dict) -> Optional[Path]:
    """`entry` written to `path` whole (a temporary file renamed), or nothing where the folder cannot be written
    (no partial file left)."""
    partial = path.with_suffix(f".{os.getpid()}.partial")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        partial.write_text(json.dumps(entry))
        os.replace(partial, path)
        return path
    except OSError:
        partial.unlink(missing_ok=True)
        return None
