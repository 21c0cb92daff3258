"""Bilinear resizing of small grids as two matrix products: `F.interpolate(mode="bilinear",
align_corners=False)`'s values, with a backward of two more products instead of atomic adds.

The training step upsamples two grids to its frame at every step: the flat-field cells (a few
values per image: the interpolation's backward adds a whole frame of gradients into them, each
addition an atomic on the same few addresses) and the background's stride grid. Bilinear
interpolation along each axis is a fixed linear map, so `rows @ grid @ cols.T` is the same resize;
its gradient is `rows.T @ grad @ cols`, dense and deterministic.
"""

from __future__ import annotations

from typing import Dict, Set, Tuple

import torch
from torch import Tensor

KEPT = 16
"""Weight matrices kept (a training run and a viewer use the same few sizes), besides those a CUDA graph reads."""
_weights: Dict[Tuple, Tensor] = {}
_recorded: Set[Tuple] = set()
"""Keys of matrices a CUDA graph read while it recorded: a graph holds their addresses, not the tensors, so
they are never let go (another size's matrix would take their memory under the graph's replays)."""


def _recording(device: torch.device) -> bool:
    return device.type == "cuda" and torch.cuda.is_current_stream_capturing()


def interpolation_weights(size_in: int, size_out: int, device: torch.device, dtype: torch.dtype) -> Tensor:
    """The [size_out, size_in] map of linear interpolation along one axis, as `F.interpolate`'s
    bilinear mode with `align_corners=False`: output i samples the input at (i + 0.5) * in / out - 0.5,
    clamped to the first and last input; each row weighs its two neighbours, summing to one."""
    key = (size_in, size_out, device, dtype)
    weights = _weights.get(key)
    if weights is not None:
        if _recording(device):
            _recorded.add(key)
        return weights
    source = (torch.arange(size_out, device=device, dtype=dtype) + 0.5) * (size_in / size_out) - 0.5  # [out]
    source = source.clamp(0.0, size_in - 1)
    inputs = torch.arange(size_in, device=device, dtype=dtype)  # [in]
    weights = (1.0 - (source[:, None] - inputs[None]).abs()).clamp_min(0.0)  # [out, in]
    # kept only outside a recording: a tensor made there lives in the graph's memory (and its replays make it again)
    if not _recording(device):
        spare = [k for k in _weights if k not in _recorded]
        if len(spare) >= KEPT:
            del _weights[spare[0]]  # the oldest
        _weights[key] = weights
    return weights


def bilinear_resize(grid: Tensor, height: int, width: int) -> Tensor:
    """`grid` [..., h, w] at height x width [..., height, width], bilinear between sample centres."""
    rows = interpolation_weights(grid.shape[-2], height, grid.device, grid.dtype)  # [height, h]
    cols = interpolation_weights(grid.shape[-1], width, grid.device, grid.dtype)  # [width, w]
    return rows @ grid @ cols.T
