"""Fixes for running nerfstudio 1.1.5 on current torch, applied when the plugin is loaded.

nerfstudio's loaders (`ns-eval`, `ns-render`, `ns-viewer`, `ns-train --load-dir`) call
`torch.load(path)` without `weights_only`; since torch 2.6 that defaults to True, and a
nerfstudio checkpoint holds numpy scalars, so loading fails with "Unsupported global: numpy...".
Instead of turning the safe loader off, we allow-list exactly the numpy types such checkpoints
contain; everything else still goes through torch's safe unpickler.

`ns-render` refuses to start without an `ffmpeg` on PATH and writes every output (videos and image
sequences alike) through it. Where the system has none, the static ffmpeg that the imageio-ffmpeg
wheel ships is put on this process's PATH (a link named `ffmpeg` in ~/.cache/thermal_wild_ns/bin).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import torch


def allow_nerfstudio_checkpoints() -> None:
    add = getattr(torch.serialization, "add_safe_globals", None)
    if add is None:  # torch < 2.4 loads everything anyway
        return
    from numpy.core.multiarray import _reconstruct, scalar

    dtypes = [type(np.dtype(t)) for t in ("float32", "float64", "int32", "int64", "uint8", "bool")]
    add([scalar, _reconstruct, np.dtype, np.ndarray, *dtypes])


def provide_ffmpeg() -> None:
    if shutil.which("ffmpeg") is not None:
        return
    try:
        import imageio_ffmpeg

        executable = Path(imageio_ffmpeg.get_ffmpeg_exe())
        folder = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "thermal_wild_ns" / "bin"
        folder.mkdir(parents=True, exist_ok=True)
        link = folder / "ffmpeg"
        if not link.exists() or link.resolve() != executable.resolve():
            tmp = folder / f".ffmpeg-{os.getpid()}"
            tmp.unlink(missing_ok=True)
            tmp.symlink_to(executable)
            tmp.replace(link)  # atomic: concurrent processes never see a half-made link
    except (ImportError, OSError, RuntimeError):
        return  # no bundled ffmpeg or no writable cache: nerfstudio says what is missing
    os.environ["PATH"] = f"{folder}{os.pathsep}{os.environ.get('PATH', '')}"


allow_nerfstudio_checkpoints()
provide_ffmpeg()
