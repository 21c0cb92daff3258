"""A capture's frame files: which files of a folder are frames, in which order, and what each file is. What a
file is comes from its first bytes, never its name: datasets ship PNGs named `.jpg` and JPEGs named `.png`, and a
radiometric JPEG must be read as one whatever it is called."""

from __future__ import annotations

import re
import warnings
from pathlib import Path
from typing import List, Literal, Set, Tuple

IMAGE_SUFFIXES = {".png", ".tif", ".tiff", ".jpg", ".jpeg"}
"""Names of image files a capture's frames may have (what each is, is read from its bytes: `file_kind`)."""

FileKind = Literal["jpeg", "png", "tiff", "npy", "unknown"]

_SIGNATURES: Tuple[Tuple[bytes, FileKind], ...] = (
    (b"\xff\xd8\xff", "jpeg"),
    (b"\x89PNG\r\n\x1a\n", "png"),
    (b"II*\x00", "tiff"),
    (b"MM\x00*", "tiff"),
    (b"II+\x00", "tiff"),  # BigTIFF
    (b"MM\x00+", "tiff"),
    (b"\x93NUMPY", "npy"),
)
_BY_SUFFIX = {".jpg": "jpeg", ".jpeg": "jpeg", ".png": "png", ".tif": "tiff", ".tiff": "tiff", ".npy": "npy"}
_said: Set[Tuple[str, str]] = set()  # (suffix, kind) pairs already said in this run's log


def natural_key(name: str) -> list:
    """Sort key that orders 'frame2' before 'frame10'."""
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


def image_files(folder: Path, suffixes=IMAGE_SUFFIXES) -> List[Path]:
    return sorted((p for p in folder.iterdir() if p.suffix.lower() in suffixes), key=lambda p: natural_key(p.name))


def kind_of_bytes(head: bytes) -> FileKind:
    """What a file is from its first bytes (at least 8)."""
    return next((kind for signature, kind in _SIGNATURES if head.startswith(signature)), "unknown")


def file_kind(path: Path) -> FileKind:
    """What the file at `path` is, read from its first bytes; said once in the run's log where its name says
    otherwise (`note_misnamed`). 'unknown' for an unreadable or empty file (its reader then says why)."""
    try:
        with open(path, "rb") as handle:
            kind = kind_of_bytes(handle.read(8))
    except OSError:
        return "unknown"
    note_misnamed(Path(path), kind)
    return kind


def note_misnamed(path: Path, kind: FileKind) -> None:
    """Say, once per run and per pair of name and content, that a file named as one format is another."""
    named = _BY_SUFFIX.get(path.suffix.lower())
    if kind == "unknown" or named is None or named == kind:
        return
    if (path.suffix.lower(), kind) in _said:
        return
    _said.add((path.suffix.lower(), kind))
    warnings.warn(
        f"{path}: named {path.suffix} but its content is {kind.upper()}: read as {kind.upper()} (so is every other "
        f"{path.suffix} file that is one)",
        stacklevel=3,
    )
