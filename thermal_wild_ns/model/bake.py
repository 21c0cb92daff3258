"""Values a render outside training reuses until what they depend on changes: the emission MLP over
every Gaussian, the background MLP over every direction (under one frame embedding)."""

from __future__ import annotations

from typing import Callable, Dict, Tuple

import torch
from torch import Tensor, nn


class BakedValues:
    """Named values computed without autograd from some tensors, each kept until one of those
    tensors changes: a training step (`step`; fused Adam updates in place without bumping tensor
    versions), an in-place edit or load (versions) or densification (identities). The check runs on
    the host: no GPU round trip per frame. A value holds its tensors themselves, so their
    identities cannot be recycled."""

    def __init__(self) -> None:
        self.slots: Dict[str, tuple] = {}
        """name -> (tensors, (step, versions...), value)"""
        self._parameter_lists: Dict[int, tuple] = {}

    def get(self, name: str, tensors: Tuple[Tensor, ...], step: int, compute: Callable[[], Tensor]) -> Tensor:
        versions = (step, *(t._version for t in tensors))
        cached = self.slots.get(name)
        if cached is not None and cached[1] == versions and all(a is b for a, b in zip(cached[0], tensors)):
            return cached[2]
        with torch.no_grad():
            value = compute()
        self.slots[name] = (tensors, versions, value)
        return value

    def parameters_of(self, module: nn.Module) -> Tuple[Tensor, ...]:
        """A module's parameters, listed once: they stay the same objects for the module's life
        (loads copy into them, `.to()` moves their data), and a render checks them every frame."""
        cached = self._parameter_lists.get(id(module))
        if cached is None or cached[0] is not module:
            cached = self._parameter_lists[id(module)] = (module, tuple(module.parameters()))
        return cached[1]
