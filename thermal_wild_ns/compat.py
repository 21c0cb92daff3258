"""Fixes for running nerfstudio 1.1.5 on current torch, applied when the plugin is loaded.

nerfstudio's loaders (`ns-eval`, `ns-render`, `ns-viewer`, `ns-train --load-dir`) call
`torch.load(path)` without `weights_only`; since torch 2.6 that defaults to True, and a
nerfstudio checkpoint holds numpy scalars, so loading fails with "Unsupported global: numpy...".
Instead of turning the safe loader off, we allow-list exactly the numpy types such checkpoints
contain; everything else still goes through torch's safe unpickler.
"""

from __future__ import annotations

import numpy as np
import torch


def allow_nerfstudio_checkpoints() -> None:
    add = getattr(torch.serialization, "add_safe_globals", None)
    if add is None:  # torch < 2.4 loads everything anyway
        return
    from numpy.core.multiarray import _reconstruct, scalar

    dtypes = [type(np.dtype(t)) for t in ("float32", "float64", "int32", "int64", "uint8", "bool")]
    add([scalar, _reconstruct, np.dtype, np.ndarray, *dtypes])


allow_nerfstudio_checkpoints()
