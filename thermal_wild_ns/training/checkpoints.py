"""A run's states on disk and in memory: nerfstudio's checkpoint written atomically (a run killed or
out of disk space while saving keeps its previous checkpoint whole, and no partial file is ever in
`nerfstudio_models/`), and the snapshot a rollback or the automatic stop goes back to."""

from __future__ import annotations

import copy
from pathlib import Path

import torch

from thermal_wild_ns._upstream import repoint_optimizers
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


def snapshot(pipeline, optimizers, step: int) -> dict:
    """A copy of everything a rollback restores: parameters (Gaussians, embeddings, MLPs),
    densification statistics and RNG (the model's extra state), optimizer moments."""
    return {
        "step": step,
        "model": copy.deepcopy(pipeline.model.state_dict()),
        "optimizers": {name: copy.deepcopy(opt.state_dict()) for name, opt in optimizers.optimizers.items()},
    }


def restore(pipeline, optimizers, state: dict) -> None:
    """Put back a `snapshot` (the model's step stays the caller's to set)."""
    pipeline.model.load_state_dict(copy.deepcopy(state["model"]))
    repoint_optimizers(optimizers, pipeline.get_param_groups())  # the load replaced the Gaussian parameters
    for name, optimizer in optimizers.optimizers.items():
        optimizer.load_state_dict(copy.deepcopy(state["optimizers"][name]))
