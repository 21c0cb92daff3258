"""Bilinear resizing as matrix products (`model/bilinear.py`) against torch's own bilinear interpolation."""

import pytest
import torch
import torch.nn.functional as F

from thermal_wild_ns.model import bilinear
from thermal_wild_ns.model.bilinear import bilinear_resize


def torch_bilinear(grid, height, width):
    return F.interpolate(grid[None], size=(height, width), mode="bilinear", align_corners=False)[0]


@pytest.mark.parametrize(
    "shape, size",
    [
        ((2, 8, 8), (512, 640)),  # flat-field cells at a full DUNR frame
        ((1, 128, 160), (512, 640)),  # the background's stride-4 grid
        ((1, 32, 40), (127, 161)),  # sizes that are no multiple of the grid's
        ((2, 16, 20), (8, 5)),  # smaller than the grid: torch's formula too, without antialiasing
        ((1, 7, 9), (7, 9)),  # the same size: the grid itself
    ],
)
def test_bilinear_resize_equals_torchs_bilinear_interpolation_in_values_and_gradients(shape, size):
    generator = torch.Generator().manual_seed(0)
    grid = torch.randn(shape, generator=generator, dtype=torch.float64)
    weight = torch.randn(shape[0], *size, generator=generator, dtype=torch.float64)  # a loss's gradient
    ours, theirs = grid.clone().requires_grad_(True), grid.clone().requires_grad_(True)
    resized = bilinear_resize(ours, *size)
    expected = torch_bilinear(theirs, *size)
    assert resized.shape == expected.shape == (shape[0], *size)
    torch.testing.assert_close(resized, expected, rtol=0, atol=1e-12)
    (resized * weight).sum().backward()
    (expected * weight).sum().backward()
    torch.testing.assert_close(ours.grad, theirs.grad, rtol=0, atol=1e-10)


def test_bilinear_resize_in_float32_is_within_rounding_of_torchs():
    grid = torch.randn(2, 8, 8, generator=torch.Generator().manual_seed(1))
    torch.testing.assert_close(bilinear_resize(grid, 512, 640), torch_bilinear(grid, 512, 640), rtol=0, atol=1e-5)


def test_each_row_of_the_interpolation_weights_sums_to_one_and_the_matrices_are_kept():
    bilinear._weights.clear()
    weights = bilinear.interpolation_weights(8, 100, torch.device("cpu"), torch.float32)  # [100, 8]
    assert weights.shape == (100, 8)
    torch.testing.assert_close(weights.sum(dim=1), torch.ones(100))
    assert ((weights > 0).sum(dim=1) <= 2).all()  # two neighbours at most
    assert bilinear.interpolation_weights(8, 100, torch.device("cpu"), torch.float32) is weights
    for size in range(bilinear.KEPT + 1):  # a bounded number kept: the oldest goes first
        bilinear.interpolation_weights(8, 200 + size, torch.device("cpu"), torch.float32)
    assert len(bilinear._weights) == bilinear.KEPT
    assert (8, 100, torch.device("cpu"), torch.float32) not in bilinear._weights


def test_a_matrix_a_cuda_graph_read_while_recording_is_never_let_go(monkeypatch):
    """A graph replays reads of the matrix's address: freeing it for another size would hand that memory
    to something else under the graph. Recording is simulated (`_recording`); the matrix read then stays
    however many sizes come after, while the others are still let go oldest first."""
    bilinear._weights.clear()
    cpu = torch.device("cpu")
    kept = bilinear.interpolation_weights(8, 512, cpu, torch.float32)  # made before recording (a warm-up run)
    monkeypatch.setattr(bilinear, "_recording", lambda device: True)
    assert bilinear.interpolation_weights(8, 512, cpu, torch.float32) is kept  # read by the recording
    made = bilinear.interpolation_weights(8, 300, cpu, torch.float32)  # made while recording: not kept
    assert (8, 300, cpu, torch.float32) not in bilinear._weights and made.shape == (300, 8)
    monkeypatch.setattr(bilinear, "_recording", lambda device: False)
    for size in range(2 * bilinear.KEPT):
        bilinear.interpolation_weights(8, 600 + size, cpu, torch.float32)
    assert bilinear.interpolation_weights(8, 512, cpu, torch.float32) is kept
    assert len(bilinear._weights) == bilinear.KEPT + 1
    assert (8, 600, cpu, torch.float32) not in bilinear._weights
    bilinear._recorded.discard((8, 512, cpu, torch.float32))
