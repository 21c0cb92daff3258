"""A run's states on disk and in memory: nerfstudio's checkpoint written atomically (a run killed or
out of disk space while saving keeps its previous checkpoint whole, and no partial file is ever in
`nerfstudio_models/`), and the snapshot a rollback or the automatic stop goes back to."""

from __future__ import annotations

import copy
from pathlib import Path

import torch

from thermal_wild_ns._upstream import replace_gaussians, repoint_optimizers
from thermal_wild_ns.pipeline.run_check import CheckpointNotSaved, checkpoints_in, write_atomically

SAVES_PER_RUN = 10
"""A run saves a checkpoint at least this many times (every 10 % of its steps), as well as every
`--steps-per-save`: a short run killed part-way leaves something to resume from."""


def save_checkpoint(state: dict, checkpoint_dir: Path, step: int, partial_dir: Path, only_latest: bool) -> None:
    """Write `state` (`_upstream.trainer_checkpoint_state`) as `step-{step}.ckpt` in `checkpoint_dir`,
    through `partial_dir`; with `only_latest`, remove the older ones once it is in place. A failed
    write raises `CheckpointNotSaved` saying what the run can be resumed from."""
    path = checkpoint_dir / f"step-{step:09d}.ckpt"
    try:
        write_atomically(path, lambda tmp: torch.save(state, tmp), partial_dir)
    except CheckpointNotSaved as err:
        kept = checkpoints_in(checkpoint_dir)
        resume = (
            f"the last checkpoint, {kept[-1]}, is whole: resume from it with --load-dir {checkpoint_dir}"
            if kept
            else "no earlier checkpoint was saved"
        )
        raise CheckpointNotSaved(f"step {step}: {err}. Training stops; {resume}") from err.__cause__
    if only_latest:  # only once the new one is in place
        for old in checkpoints_in(checkpoint_dir):
            if old != path:
                old.unlink()


SNAPSHOT_GPU_SHARE = 0.25
"""A snapshot stays on the GPU while it takes at most this share of the memory the GPU has left, else
it goes to host memory: a large survey's parameters and Adam moments would otherwise be held twice or
three times on the GPU (the guard's healthy state, the automatic stop's best)."""


def snapshot_device(nbytes: int, device: torch.device) -> torch.device:
    """Where a snapshot of `nbytes` of the state on `device` is kept (`SNAPSHOT_GPU_SHARE`)."""
    if device.type != "cuda":
        return device
    free, _ = torch.cuda.mem_get_info(device)
    spare = free + torch.cuda.memory_reserved(device) - torch.cuda.memory_allocated(device)
    return device if nbytes <= SNAPSHOT_GPU_SHARE * spare else torch.device("cpu")


def _tensors(obj) -> list:
    if isinstance(obj, torch.Tensor):
        return [obj]
    if isinstance(obj, dict):
        return [t for value in obj.values() for t in _tensors(value)]
    if isinstance(obj, (list, tuple)):
        return [t for value in obj for t in _tensors(value)]
    return []


def _copied(obj, device: torch.device):
    """A deep copy of `obj` whose GPU tensors are on `device` (host tensors, the RNG state, stay)."""
    if isinstance(obj, torch.Tensor):
        return obj.detach().to(device if obj.is_cuda else obj.device, copy=True)
    if isinstance(obj, dict):
        return {key: _copied(value, device) for key, value in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(_copied(value, device) for value in obj)
    return copy.deepcopy(obj)


def snapshot(pipeline, optimizers, step: int) -> dict:
    """A copy of everything a rollback restores: parameters (Gaussians, embeddings, MLPs),
    densification statistics and RNG (the model's extra state), optimizer moments; on the GPU or, when
    large for the memory left, on the host (`snapshot_device`)."""
    state = {
        "model": pipeline.model.state_dict(),
        "optimizers": {name: opt.state_dict() for name, opt in optimizers.optimizers.items()},
    }
    nbytes = sum(t.numel() * t.element_size() for t in _tensors(state) if t.is_cuda)
    return {"step": step, **_copied(state, snapshot_device(nbytes, pipeline.model.device))}


def restore(pipeline, optimizers, state: dict) -> None:
    """Put back a `snapshot` (the model's step stays the caller's to set). The current Gaussians and
    their Adam moments go first: a rollback happens where memory ran out, where the old and the restored
    copies side by side may not fit."""
    gaussians = getattr(pipeline.model, "gauss_params", None)
    if gaussians is not None:
        replace_gaussians(pipeline, optimizers, {name: p.detach()[:0].clone() for name, p in gaussians.items()})
    pipeline.model.load_state_dict(copy.deepcopy(state["model"]))
    repoint_optimizers(optimizers, pipeline.get_param_groups())  # the load replaced the Gaussian parameters
    for name, optimizer in optimizers.optimizers.items():
        optimizer.load_state_dict(copy.deepcopy(state["optimizers"][name]))
