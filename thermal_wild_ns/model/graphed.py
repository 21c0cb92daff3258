"""Fixed-shape pieces of a training step, their forward and backward replayed on a GPU as CUDA graphs.

A training step is bound by the host: each small kernel of the loss or of a small MLP is launched
from Python, forward and backward. Pieces whose inputs keep their shapes from step to step (the loss
terms of a frame size; the background MLP over a frame size's grid) are recorded once per shape by
`torch.cuda.make_graphed_callables` and replayed: the same kernels, on copies of the inputs, one launch
each way. Recording happens inside a training step, under the trainer's lock, which the viewer's
renders also take: torch records in its global mode, where another thread's CUDA calls would fail it.
On a CPU, or where a graph cannot be recorded, the piece simply runs. (Renders outside training:
`rendering/captured.py`.)
"""

from __future__ import annotations

from typing import Callable, Dict, Hashable, Optional, Tuple

import torch
from nerfstudio.utils.rich_utils import CONSOLE
from torch import Tensor


class GraphedCalls:
    """`fn(*inputs)` for tensors `inputs`, replayed forward and backward as CUDA graphs per `key` and
    input shapes. `fn` (a function, or a module whose parameters take gradients) reads tensors only
    from `inputs` and its own parameters, and the same `fn` comes with each key; the key names every
    other value `fn` depends on (a size)."""

    def __init__(self, name: str) -> None:
        self.name = name  # how a message names the piece
        self.graphs: Dict[Hashable, Optional[Callable]] = {}
        """key, input shapes and grad flags -> the graphed `fn` (None: it could not be recorded)"""

    def __call__(self, key: Hashable, fn: Callable[..., Tuple[Tensor, ...]], *inputs: Tensor):
        if not inputs[0].is_cuda:
            return fn(*inputs)
        full_key = (key, tuple((tuple(t.shape), t.requires_grad) for t in inputs))
        if full_key not in self.graphs:
            # leaf copies with the inputs' grad flags: torch warms up and records on these
            samples = tuple(t.detach().clone().requires_grad_(t.requires_grad) for t in inputs)
            try:
                self.graphs[full_key] = torch.cuda.make_graphed_callables(fn, samples, allow_unused_input=True)
            except RuntimeError as error:
                self.graphs[full_key] = None
                CONSOLE.log(
                    f"[yellow]The {self.name} runs kernel by kernel: a CUDA graph could not record it ({error})"
                )
        graphed = self.graphs[full_key]
        return fn(*inputs) if graphed is None else graphed(*inputs)
