"""Fixed-shape pieces of a training step, their forward and backward replayed on a GPU as CUDA graphs.

A training step is bound by the host: each small kernel of the loss or of a small MLP is launched
from Python, forward and backward. Pieces whose inputs keep their shapes from step to step (the loss
terms of a frame size; the background MLP over a frame size's grid) are recorded once per shape by
`torch.cuda.make_graphed_callables` and replayed: the same kernels, on copies of the inputs, one launch
each way. Recording happens inside a training step, under the trainer's lock, which the viewer's
renders also take: torch records in its global mode, where another thread's CUDA calls would fail it.
On a CPU, or where a graph cannot be recorded, the piece simply runs (CUDA's random generators
released from the failed capture: `_upstream.end_failed_capture`). (Renders outside training:
`rendering/captured.py`.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Dict, Hashable, Optional, Tuple

import torch
from nerfstudio.utils.rich_utils import CONSOLE
from torch import Tensor, nn

from thermal_wild_ns._upstream import end_failed_capture


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
    other value `fn` depends on (a size). (A piece whose shapes move on with the Gaussian count:
    `PaddedRowCalls`.)

    A recording's outputs and the activations its backward reads are static buffers: a second call
    before the backward would overwrite the first call's. Calls of one step that all reach one
    backward (several cameras per step) therefore each name their `slot`, their place in the step,
    and each slot replays recordings of its own."""

    def __init__(self, name: str) -> None:
        self.name = name  # how a message names the piece
        self.graphs: Dict[Hashable, Optional[Callable]] = {}
        """slot, key, input shapes and grad flags -> the graphed `fn` (None: it could not be recorded)"""

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
            # leaf copies with the inputs' grad flags: torch warms up and records on these
            samples = tuple(t.detach().clone().requires_grad_(t.requires_grad) for t in inputs)
            try:
                self.graphs[full_key] = self._record(fn, samples)
            except RuntimeError as error:
                end_failed_capture()
                self.graphs[full_key] = None
                CONSOLE.log(
                    f"[yellow]The {self.name} runs kernel by kernel: a CUDA graph could not record it ({error})"
                )
        graphed = self.graphs[full_key]
        return fn(*inputs) if graphed is None else graphed(*inputs)


def row_capacity(rows: int) -> int:
    """The rows a recording of `PaddedRowCalls` holds for `rows` rows: the least 1024 * sqrt(2)^k at or
    above `rows`, a multiple of 256. Densification moves the Gaussian count by a few percent every hundred
    steps: within a capacity the same recording replays, and the padded rows stay under half of it."""
    k = 0
    while (capacity := _capacity(k)) < rows:
        k += 1
    return capacity


def _capacity(k: int) -> int:
    """1024 * sqrt(2)^k rounded up to a multiple of 256 (even k: a power of two, exactly)."""
    scale = 1.0 if k % 2 == 0 else math.sqrt(2.0)
    return -(-math.ceil(1024 * 2 ** (k // 2) * scale) // 256) * 256


@dataclass(eq=False)
class RowsRecording:
    """One recording of a function of rows (`PaddedRowCalls`): its static inputs, output and gradients,
    `capacity` rows each, and its two replays."""

    shapes: Hashable  # the inputs' shapes past the rows, dtypes and grad flags it was recorded for
    capacity: int
    row_inputs: Tuple[Tensor, ...]  # [capacity, ...] each
    shared_inputs: Tuple[Tensor, ...]
    parameters: Tuple[Tensor, ...]  # the module's, whose gradients the backward replay gives (`grads`' last)
    output: Tensor  # [capacity, ...]
    grad_output: Tensor  # [capacity, ...]
    grads: Tuple[Optional[Tensor], ...]  # of the row inputs, the shared inputs and the parameters, in that order
    forward: Callable[[], None]
    backward: Callable[[], None]
    rows: int = -1  # the rows in use: past them the row inputs and the output's gradient hold zeros

    def load(self, rows: int, row_values: Tuple[Tensor, ...], shared_values: Tuple[Tensor, ...]) -> None:
        """The call's inputs into the static ones: `rows` rows each, the rest zero (a zero gradient past
        them adds nothing to the parameters' gradients)."""
        if rows != self.rows:
            for buffer in (*self.row_inputs, self.grad_output):
                buffer[rows:].zero_()
            self.rows = rows
        for buffer, value in zip(self.row_inputs, row_values):
            buffer[:rows].copy_(value)
        for buffer, value in zip(self.shared_inputs, shared_values):
            buffer.copy_(value)


class _ReplayedRows(torch.autograd.Function):
    """A `RowsRecording` replayed for `rows` rows: forward, and its gradients into the inputs and parameters."""

    @staticmethod
    def forward(ctx, recording: RowsRecording, rows: int, *tensors: Tensor) -> Tensor:
        n_rows, n_shared = len(recording.row_inputs), len(recording.shared_inputs)
        recording.load(rows, tensors[:n_rows], tensors[n_rows : n_rows + n_shared])
        recording.forward()
        ctx.recording, ctx.rows = recording, rows
        return recording.output[:rows].detach()  # a static buffer: the next replay writes it, as torch's graphs

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_output: Tensor):
        recording, rows = ctx.recording, ctx.rows
        recording.grad_output[:rows].copy_(grad_output)
        recording.backward()
        n_rows = len(recording.row_inputs)
        grads = tuple(
            None if g is None else (g[:rows] if i < n_rows else g).detach() for i, g in enumerate(recording.grads)
        )
        return (None, None, *grads)


class PaddedRowCalls:
    """`fn(*row_inputs, *shared_inputs)` for a module `fn` of rows (each output row depends on its own
    input rows, the shared inputs and the module's parameters alone: a per-Gaussian MLP), replayed forward
    and backward as CUDA graphs recorded for a capacity of rows (`row_capacity`). `GraphedCalls` records
    each new shape, and a count that densification moves every hundred steps would be recorded again each
    time (a recording costs more than a hundred replays save: docs/results/emission_graphs_h100); here the
    inputs fill the first rows of the recording's, zeros the rest, and one recording serves every count from
    half its capacity to all of it. Only the latest recording of each `slot` (a camera's place among a
    step's cameras, as `GraphedCalls`) is kept: it holds the activations of every row. On a CPU, or where a
    graph cannot be recorded, `fn` simply runs. The padded rows change how cuBLAS splits its sums: the
    values are the unpadded ones up to float rounding, not bit for bit."""

    def __init__(self, name: str) -> None:
        self.name = name  # how a message names the piece
        self.recordings: Dict[int, Optional[RowsRecording]] = {}
        """slot -> its latest recording (None: the last one asked for could not be recorded)"""
        self.failed: set = set()  # (slot, shapes, capacity) that could not be recorded

    @staticmethod
    def records(inputs: Tuple[Tensor, ...]) -> bool:
        """Whether these inputs' calls are recorded (on a GPU) rather than simply run."""
        return inputs[0].is_cuda

    def __call__(self, fn: nn.Module, row_inputs: Tuple[Tensor, ...], shared_inputs: Tuple[Tensor, ...], slot: int = 0):
        if not self.records(row_inputs):
            return fn(*row_inputs, *shared_inputs)
        rows = row_inputs[0].shape[0]
        shapes = (
            tuple((tuple(t.shape[1:]), t.dtype, t.requires_grad) for t in row_inputs),
            tuple((tuple(t.shape), t.dtype, t.requires_grad) for t in shared_inputs),
        )
        recording = self.recordings.get(slot)
        if recording is None or recording.shapes != shapes or not recording.capacity // 2 < rows <= recording.capacity:
            recording = self._recording(fn, row_inputs, shared_inputs, shapes, row_capacity(rows), slot)
        if recording is None:
            return fn(*row_inputs, *shared_inputs)
        return _ReplayedRows.apply(recording, rows, *row_inputs, *shared_inputs, *recording.parameters)

    def _recording(self, fn, row_inputs, shared_inputs, shapes, capacity: int, slot: int) -> Optional[RowsRecording]:
        """The slot's recording for `capacity` rows of these shapes (its older one's memory let go first);
        None where torch could not record it (said once)."""
        self.recordings.pop(slot, None)
        if (slot, shapes, capacity) in self.failed:
            return None
        rows = tuple(
            torch.zeros((capacity, *t.shape[1:]), dtype=t.dtype, device=t.device).requires_grad_(t.requires_grad)
            for t in row_inputs
        )
        shared = tuple(t.detach().clone().requires_grad_(t.requires_grad) for t in shared_inputs)
        names, parameters = zip(*fn.named_parameters()) if any(True for _ in fn.parameters()) else ((), ())
        # recorded on leaves that share the parameters' memory (an update in place reaches the replays), never on
        # the parameters themselves: their gradient nodes, made on the step's stream and kept alive by the last
        # step's loss, would make the recorded backward wait on that stream, which fails a capture
        aliases = tuple(p.detach().requires_grad_(p.requires_grad) for p in parameters)
        recorded = lambda *inputs: torch.func.functional_call(fn, dict(zip(names, aliases)), inputs)
        try:
            recording = self._record(recorded, shapes, capacity, rows, shared, parameters, aliases)
        except RuntimeError as error:
            end_failed_capture()
            self.failed.add((slot, shapes, capacity))
            CONSOLE.log(f"[yellow]The {self.name} runs kernel by kernel: a CUDA graph could not record it ({error})")
            return None
        self.recordings[slot] = recording
        return recording

    @staticmethod
    def _record(fn, shapes, capacity: int, rows, shared, parameters, aliases) -> RowsRecording:
        """`fn` on these static inputs and the parameters' `aliases` (leaves sharing their memory), forward and
        backward, recorded as torch's `make_graphed_callables` records (torch 2.11-2.13: warmed up on a side
        stream, then both passes captured in one memory pool); the gradients of the aliases are the
        parameters'."""
        inputs = rows + shared
        surface = inputs + aliases
        wanted = tuple(t for t in surface if t.requires_grad)
        torch.cuda.synchronize()
        with torch.cuda.stream(torch.cuda.Stream()):  # lazy initialisation outside the captures
            for _ in range(3):
                out = fn(*inputs)
                torch.autograd.grad(out, wanted, torch.zeros_like(out), allow_unused=True)
        torch.cuda.synchronize()
        pool = torch.cuda.graph_pool_handle()
        forward_graph, backward_graph = torch.cuda.CUDAGraph(), torch.cuda.CUDAGraph()
        with torch.cuda.graph(forward_graph, pool=pool):
            output = fn(*inputs)
        grad_output = torch.zeros_like(output)
        with torch.cuda.graph(backward_graph, pool=pool):
            found = iter(torch.autograd.grad(output, wanted, grad_output, allow_unused=True))
            grads = tuple(next(found) if t.requires_grad else None for t in surface)
        return RowsRecording(
            shapes,
            capacity,
            rows,
            shared,
            parameters,
            output.detach(),
            grad_output,
            grads,
            forward_graph.replay,
            backward_graph.replay,
        )
