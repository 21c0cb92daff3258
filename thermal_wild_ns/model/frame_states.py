"""The photometric states the model knows: the per-frame embeddings of its training frames, along
their capture positions, and the states derived from them (the canonical one, one at any capture
time). The embeddings themselves stay the model's parameter (`frame_embed`, in its checkpoints);
this owns what is computed from them, and the one cache of it."""

from __future__ import annotations

from typing import List, Optional, Sequence

import torch
from torch import Tensor, nn

from thermal_wild_ns.preprocessing.photometric import time_weights


class FrameStates:
    """Frame embeddings [Df] from `embedding` (one row per training image) at capture positions
    `frame_times` (one per row). A named embedding (`named`) is kept outside autograd until the
    embeddings change."""

    def __init__(self, embedding: nn.Embedding, frame_times: Sequence[float]):
        self.embedding = embedding
        self.frame_times: List[float] = [float(t) for t in frame_times]
        self._cache: Optional[tuple] = None  # ((choice, step, version), weight, embedding)

    def at(self, t: float, without: Sequence[int] = ()) -> Tensor:
        """The frame embedding [Df] at capture position `t`: linear between the neighbouring
        training frames' embeddings, exactly a training frame's own at its position. `without`:
        rows not to interpolate from."""
        left_out = set(without)
        rows = [k for k in range(len(self.frame_times)) if k not in left_out]
        i, j, w = time_weights([self.frame_times[k] for k in rows], t)
        weight = self.embedding.weight  # [F, Df]
        return weight[rows[i]] if w == 0.0 else (1.0 - w) * weight[rows[i]] + w * weight[rows[j]]

    def fill_from_neighbours(self, rows: Sequence[int]) -> None:
        """Set the embeddings of `rows` (training images that take no gradient) to the state
        interpolated from the other training frames around them."""
        with torch.no_grad():
            for row in rows:
                self.embedding.weight[row] = self.at(self.frame_times[row], without=rows)

    def named(self, choice: str, step: int) -> Tensor:
        """The frame embedding [Df] `choice` names ('mean', 'zero', a training image's index, or
        'time:T'), kept outside autograd until the embeddings change (`step`: fused Adam does not
        bump tensor versions)."""
        weight = self.embedding.weight  # [F, Df]
        key = (choice, step, weight._version)
        cached = self._cache
        if cached is not None and cached[0] == key and cached[1] is weight:
            return cached[2]
        if choice.startswith("time:"):
            value = self.at(float(choice[5:]))
        elif choice == "mean":
            value = weight.mean(dim=0)
        elif choice == "zero":
            value = torch.zeros_like(weight[0])
        elif choice.isdigit() and int(choice) < weight.shape[0]:
            value = weight[int(choice)]
        else:
            raise ValueError(
                f"inference_embedding must be 'mean', 'zero' or a training-frame index below {weight.shape[0]}, "
                f"got {choice!r}"
            )
        if not torch.is_grad_enabled():
            self._cache = (key, weight, value)
        return value
