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
from torch import Tensor, nn


class RecordedCall(nn.Module):
    """`fn` as the module torch records: `make_graphed_callables` replaces a module's `forward` with
    the replay of its one recording, so a module handed to it directly would replay that recording's
    shapes for every later caller (another shape fails: a model's MLP whose row count moves with the
    Gaussian count, or its plain calls outside training). A fresh wrapper per recording leaves `fn`
    itself untouched; a module `fn` is a submodule, so its parameters still take gradients."""

    def __init__(self, fn: Callable):
        super().__init__()
        self.fn = fn

    def forward(self, *inputs: Tensor):
        return self.fn(*inputs)


class GraphedCalls:
    """`fn(*inputs)` for tensors `inputs`, replayed forward and backward as CUDA graphs per `key` and
    input shapes. `fn` (a function, or a module whose parameters take gradients) reads tensors only
    from `inputs` and its own parameters, and the same `fn` comes with each key; the key names every
    other value `fn` depends on (a size). `latest_only`: keep the graph of the latest shapes alone (a
    piece whose shapes move on and do not come back, such as the Gaussian count: each recording holds
    its activations' memory).

    A recording's outputs and the activations its backward reads are static buffers: a second call
    before the backward would overwrite the first call's. Calls of one step that all reach one
    backward (several cameras per step) therefore each name their `slot`, their place in the step,
    and each slot replays recordings of its own."""

    def __init__(self, name: str, latest_only: bool = False) -> None:
        self.name = name  # how a message names the piece
        self.latest_only = latest_only
        self.graphs: Dict[Hashable, Optional[Callable]] = {}
        """slot, key, input shapes and grad flags -> the graphed `fn` (None: it could not be recorded)"""
        self.accumulators: Dict[int, object] = {}
        """id of a parameter of a recorded `fn` -> the autograd node that takes its gradient (`held_accumulators`)"""

    @staticmethod
    def records(inputs: Tuple[Tensor, ...]) -> bool:
        """Whether these inputs' calls are recorded (on a GPU) rather than simply run."""
        return inputs[0].is_cuda

    @staticmethod
    def _record(fn: Callable, samples: Tuple[Tensor, ...]) -> Callable:
        return torch.cuda.make_graphed_callables(RecordedCall(fn), samples, allow_unused_input=True)

    def __call__(self, key: Hashable, fn: Callable[..., Tuple[Tensor, ...]], *inputs: Tensor, slot: int = 0):
        if not self.records(inputs):
            return fn(*inputs)
        full_key = (slot, key, tuple((tuple(t.shape), t.requires_grad) for t in inputs))
        if full_key not in self.graphs:
            if self.latest_only:  # the slot's older recordings' memory goes before the new one takes its own
                self.graphs = {k: v for k, v in self.graphs.items() if k[0] != slot}
            self.accumulators.update(held_accumulators(fn))
            # leaf copies with the inputs' grad flags: torch warms up and records on these
            samples = tuple(t.detach().clone().requires_grad_(t.requires_grad) for t in inputs)
            try:
                self.graphs[full_key] = self._record(fn, samples)
            except RuntimeError as error:
                self.graphs[full_key] = None
                CONSOLE.log(
                    f"[yellow]The {self.name} runs kernel by kernel: a CUDA graph could not record it ({error})"
                )
        graphed = self.graphs[full_key]
        return fn(*inputs) if graphed is None else graphed(*inputs)


def held_accumulators(fn: Callable) -> Dict[int, object]:
    """The autograd nodes that accumulate the gradients of `fn`'s parameters (a module's; a function has
    none), made now, on the step's stream, for the caller to hold. Torch makes a parameter's node when a
    graph first uses the parameter and keeps it while any graph does; `make_graphed_callables` (read in
    torch 2.13's source) warms up and records on streams of its own and keeps the recording's outputs,
    and with them their graph: a node first made there stays on that stream, and every later step's
    backward may then wait across streams for each such parameter (torch 2.11 warns of it once in every
    GPU run: "The AccumulateGrad node's stream does not match the stream of the node that produced the
    incoming gradient"). Made first on the step's stream and held, the recording uses the same node."""
    parameters = fn.parameters() if isinstance(fn, nn.Module) else ()
    with torch.enable_grad():  # a view's grad_fn leads to the parameter's node
        return {id(p): p.view_as(p).grad_fn.next_functions[0][0] for p in parameters if p.requires_grad}
