"""A capture's frame files: which files of a folder are frames, in which order, and their size."""

from __future__ import annotations

import re
from pathlib import Path
from typing import List, Tuple

from thermal_wild_ns.data.thermal_io import IMAGE_SUFFIXES, read_raw_frame


def natural_key(name: str) -> list:
    """Sort key that orders 'frame2' before 'frame10'."""
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


def image_files(folder: Path, suffixes=IMAGE_SUFFIXES) -> List[Path]:
    return sorted((p for p in folder.iterdir() if p.suffix.lower() in suffixes), key=lambda p: natural_key(p.name))


# --------------------------------------------------------------------------- nerfstudio transforms.json
def frame_size(path: Path) -> Tuple[int, int]:
    """(width, height) of a frame file."""

    h, w = read_raw_frame(path).shape
    return w, h
