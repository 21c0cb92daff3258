"""Benchmarks: accuracy vs speed, training-step profiles, render speed, Gaussian budget."""


def device_name() -> str:
    """What the numbers were measured on (written beside every benchmark result)."""
    import torch

    return torch.cuda.get_device_name() if torch.cuda.is_available() else "cpu"


def synchronize() -> None:
    """Wait for the GPU's queued work (a no-op on CPU): timings must end where the work does."""
    import torch

    if torch.cuda.is_available():
        torch.cuda.synchronize()
