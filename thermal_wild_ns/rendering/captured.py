"""Fixed-shape pieces of a render outside training, replayed on a GPU as CUDA graphs.

A render a user waits for (the viewer, `wild-thermal-render`, the export commands) is bound by the
host: dozens of small kernels, each launched from Python. The pieces around gsplat's rasterization
(the camera's view matrix and background before it; compositing, depth and colormap after it) have
the same shapes for every frame of one camera size, so each is recorded once as a CUDA graph and
replayed: one launch instead of its kernels, with the same kernels' results. gsplat's rasterization
itself sizes its buffers from the data (a host read) and stays outside. On a CPU, or under
autograd, the function simply runs.
"""

from __future__ import annotations

import threading
from typing import Callable, Dict, Hashable, Tuple

import torch
from nerfstudio.utils.rich_utils import CONSOLE
from torch import Tensor

from thermal_wild_ns._upstream import end_failed_capture

KEPT_GRAPHS = 4
"""Graphs kept per `CapturedCalls` and thread (a viewer switching between a few sizes replays them;
each holds its own memory)."""


UNRECORDABLE = ()
"""The entry of a key whose graph could not be recorded."""


class CapturedCalls:
    """`fn(*inputs)` for tensors `inputs` of fixed shapes, replayed as a CUDA graph per `key`.

    `fn` reads tensors only from `inputs` (copied into the graph's own at each replay) and constants
    that live as long as the process; the key names every value besides `inputs` that `fn` depends
    on (sizes, intrinsics, a colormap): a graph replays the kernels and buffers it recorded. The
    outputs of a replay are the graph's own buffers, overwritten by its next replay: a caller keeps
    a copy (`copy_outputs`).
    """

    def __init__(self) -> None:
        self.per_thread: Dict[int, Dict[Hashable, tuple]] = {}
        """thread -> key -> (graph, static inputs, static outputs, (tensor, version) last copied into
        each static input) or UNRECORDABLE, the most recent last. Each thread (the viewer's, the
        trainer's evaluation) has graphs of its own: one thread's replay cannot overwrite buffers
        another is still reading, nor free them."""
        self.output_ids: set = set()
        """ids of the outputs handed out as the graphs' own buffers"""

    def __call__(
        self, key: Hashable, fn: Callable[..., Tuple[Tensor, ...]], *inputs: Tensor, copy_outputs: bool = False
    ) -> Tuple[Tensor, ...]:
        """`fn(*inputs)`; on a GPU outside autograd the replay of its graph for `key` (recorded at the
        key's first call). `copy_outputs`: copies of a replay's outputs rather than its buffers."""
        if not self.records(inputs):
            return fn(*inputs)
        graphs = self.graphs
        entry = graphs.pop(key, None)
        if entry is None:
            alive = {thread.ident for thread in threading.enumerate()}
            for ident in [ident for ident in self.per_thread if ident not in alive]:  # a viewer client gone
                del self.per_thread[ident]
            try:
                entry = self._capture(fn, inputs)
            except RuntimeError as error:  # a kernel this GPU's driver cannot record: run as is from now on
                end_failed_capture()
                entry = UNRECORDABLE
                CONSOLE.log(f"[yellow]Renders run kernel by kernel: a CUDA graph could not record them ({error})")
        graphs[key] = entry
        if entry is UNRECORDABLE:
            return fn(*inputs)
        while len(graphs) > KEPT_GRAPHS:
            graphs.pop(next(iter(graphs)))
        graph, static_inputs, outputs, copied = entry
        for i, (static, value) in enumerate(zip(static_inputs, inputs)):
            last, version = copied[i]
            # unchanged since its last copy (a baked map): no copy. A graph's output changes at each of its
            # replays without a new version: always copied
            if last is not value or version != value._version or id(value) in self.output_ids:
                static.copy_(value)
                copied[i] = (value, value._version)
        graph.replay()
        if copy_outputs:
            return tuple(output.clone() for output in outputs)
        self.output_ids.update(id(output) for output in outputs)  # (an id reused later: one copy too many)
        return outputs

    @staticmethod
    def records(inputs: Tuple[Tensor, ...]) -> bool:
        """Whether a call with `inputs` goes through a graph: CUDA tensors, outside autograd."""
        return inputs[0].device.type == "cuda" and not torch.is_grad_enabled()

    @property
    def graphs(self) -> Dict[Hashable, tuple]:
        """This thread's graphs."""
        return self.per_thread.setdefault(threading.get_ident(), {})

    @staticmethod
    def _capture(fn, inputs) -> tuple:
        static_inputs = tuple(value.clone() for value in inputs)
        side = torch.cuda.Stream()
        side.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(side):  # first calls outside the graph: lazy initialisations, cached values
            fn(*static_inputs)
        torch.cuda.current_stream().wait_stream(side)
        graph = torch.cuda.CUDAGraph()
        # thread_local: a viewer thread's capture does not fail another thread's CUDA calls
        with torch.cuda.graph(graph, capture_error_mode="thread_local"):
            outputs = fn(*static_inputs)
        return graph, static_inputs, outputs, [(value, value._version) for value in inputs]
