"""The bookkeeping of renders replayed as CUDA graphs (`rendering/captured.py`), on a CPU: a stand-in
graph records `fn`'s outputs into buffers of its own and replays by running `fn` on its own inputs
into them, as a CUDA graph does. (The real graphs: tests/test_gpu_parity.py, on a GPU.)"""

import threading

import torch

from thermal_wild_ns.rendering import captured
from thermal_wild_ns.rendering.captured import CapturedCalls


class StandInGraph:
    def __init__(self, fn, static_inputs):
        self.fn, self.static_inputs = fn, static_inputs
        self.outputs = tuple(out.clone() for out in fn(*static_inputs))
        self.replays = 0

    def replay(self):
        for buffer, value in zip(self.outputs, self.fn(*self.static_inputs)):
            buffer.data.copy_(value)  # as a CUDA graph's replay: new contents, the same tensor version
        self.replays += 1


def stand_in_capture(fn, inputs):
    static_inputs = tuple(value.clone() for value in inputs)
    graph = StandInGraph(fn, static_inputs)
    return graph, static_inputs, graph.outputs, [(value, value._version) for value in inputs]


def recording_calls(monkeypatch) -> CapturedCalls:
    monkeypatch.setattr(CapturedCalls, "_capture", staticmethod(stand_in_capture))
    monkeypatch.setattr(CapturedCalls, "records", staticmethod(lambda inputs: True))
    return CapturedCalls()


def test_a_graphs_output_fed_to_another_graph_is_copied_at_every_replay(monkeypatch):
    """The first graph's output buffer is the same tensor, at the same version, after each replay:
    the second graph must copy it anyway (it once kept the first frame's background)."""
    calls = recording_calls(monkeypatch)
    twice = lambda x: (x * 2,)
    plus_one = lambda y: (y + 1,)
    for value in (1.0, 5.0, -3.0):
        (doubled,) = calls("first", twice, torch.tensor([value]))
        (result,) = calls("second", plus_one, doubled, copy_outputs=True)
        assert float(result) == value * 2 + 1


def test_an_unchanged_input_is_not_copied_again_and_a_changed_one_is(monkeypatch):
    calls = recording_calls(monkeypatch)
    baked = torch.tensor([3.0])  # a baked map: the same tensor until the state changes
    add = lambda x, y: (x + y,)
    copies = []
    original_copy = torch.Tensor.copy_
    monkeypatch.setattr(
        torch.Tensor, "copy_", lambda self, src, *a: copies.append(self) or original_copy(self, src, *a)
    )
    calls("add", add, torch.tensor([1.0]), baked)
    copies.clear()
    (out,) = calls("add", add, torch.tensor([2.0]), baked, copy_outputs=True)
    assert float(out) == 5.0
    camera_input, baked_input = calls.graphs["add"][1]
    assert [c for c in copies if c is camera_input or c is baked_input] == [camera_input]  # the new tensor only
    baked.add_(1.0)  # changed in place: a new version
    (out,) = calls("add", add, torch.tensor([2.0]), baked, copy_outputs=True)
    assert float(out) == 6.0


def test_outputs_are_the_graphs_buffers_unless_copied(monkeypatch):
    calls = recording_calls(monkeypatch)
    negate = lambda x: (-x,)
    (first,) = calls("n", negate, torch.tensor([1.0]))
    (second,) = calls("n", negate, torch.tensor([2.0]))
    assert first is second and float(first) == -2.0  # overwritten by the replay: callers copy
    (kept,) = calls("n", negate, torch.tensor([3.0]), copy_outputs=True)
    calls("n", negate, torch.tensor([4.0]))
    assert float(kept) == -3.0


def test_each_thread_replays_graphs_of_its_own_and_a_few_per_thread(monkeypatch):
    calls = recording_calls(monkeypatch)
    for key in range(captured.KEPT_GRAPHS + 2):
        calls(key, lambda x: (x + 1,), torch.tensor([0.0]))
    assert len(calls.graphs) == captured.KEPT_GRAPHS
    worker = threading.Thread(target=lambda: calls("w", lambda x: (x + 1,), torch.tensor([0.0])))
    worker.start()
    worker.join()
    assert len(calls.per_thread) == 2  # the worker's own
    calls("new", lambda x: (x,), torch.tensor([0.0]))  # a new recording drops the ended thread's graphs
    assert list(calls.per_thread) == [threading.get_ident()]


def test_on_a_cpu_or_under_autograd_the_function_simply_runs():
    calls = CapturedCalls()
    x = torch.tensor([1.0])
    assert float(calls("k", lambda v: (v * 3,), x)[0]) == 3.0 and not calls.per_thread
