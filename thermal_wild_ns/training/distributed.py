"""The trainer of one scene split across GPUs (`multi_gpu.py` launches it, one process per GPU).

Each rank holds its share of the Gaussians (`pipeline/ranks.py`) and trains one image per step; gsplat's
distributed rasterization sends every camera's splats to the rank that renders it and the gradients
back to their owners. Everything else (frame embeddings, emission and background MLPs) has one copy per
rank: after backward their gradients are summed over the ranks (`RankGroup.sum_gradients`), so the
copies take the same Adam step and stay equal; the photometric state is one on every rank.

A checkpoint is one file that loads on one GPU (ns-viewer, ns-render, ns-eval, wild-thermal-export):
every rank's Gaussians gathered in rank order, the networks' optimizer state (the same on every
rank), without the Gaussians' Adam moments and densification statistics, which are per rank. Resuming
one (`--load-dir`, on one GPU through ns-train or on several through the launcher, each rank taking its
share) continues with fresh moments for the Gaussians.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import List, Type

import torch
from torch.nn import Parameter

from thermal_wild_ns._upstream import replace_gaussians, trainer_checkpoint_state
from thermal_wild_ns.pipeline.ranks import RankGroup
from thermal_wild_ns.pipeline.run_check import PARTIAL_FOLDER
from thermal_wild_ns.training.checkpoints import save_checkpoint
from thermal_wild_ns.training.divergence import TrainingDiverged
from thermal_wild_ns.training.lean_step import lean_iteration
from thermal_wild_ns.training.trainer import GuardedTrainer, GuardedTrainerConfig

GAUSSIANS = "_model.gauss_params."
"""Prefix of the per-Gaussian tensors in a pipeline's state dict."""


def gathered_checkpoint_state(trainer, step: int, ranks: RankGroup, gaussian_names: List[str]) -> dict:
    """The run's checkpoint as one GPU would have written it (`trainer_checkpoint_state`), with every
    rank's Gaussians (`gaussian_names`: the per-Gaussian parameters) gathered. Every rank must call
    it (it is a collective); rank 0's result is the one to write (the Gaussians gathered in host memory,
    a share at a time: a model split because it does not fit one GPU is never whole on one)."""
    state = trainer_checkpoint_state(trainer, step)
    pipeline = state["pipeline"]
    for key in sorted(pipeline):
        if key.startswith(GAUSSIANS):
            pipeline[key] = ranks.gather_rows_on_host(pipeline[key])
        elif key.endswith("_extra_state"):  # per-rank densification statistics: not kept
            pipeline[key] = {**pipeline[key], "strategy_state": {}}
    state["optimizers"] = {k: v for k, v in state["optimizers"].items() if k not in gaussian_names}
    return state


@dataclass
class DistributedTrainerConfig(GuardedTrainerConfig):
    """`GuardedTrainerConfig` for one scene across the GPUs of a host (set by `multi_gpu.py`)."""

    _target: Type = field(default_factory=lambda: DistributedTrainer)


class DistributedTrainer(GuardedTrainer):
    """`GuardedTrainer` whose step sums the shared parameters' gradients over the ranks and whose
    checkpoints gather the Gaussians (one file, written by rank 0). The automatic stop scores on every
    rank together and decides by rank 0's score; the divergence guard's verdicts (skip a step, roll back)
    are one for all ranks. A step out of GPU memory stops the run (the other ranks wait in collectives)."""

    config: DistributedTrainerConfig

    def setup(self, test_mode="val"):
        super().setup(test_mode=test_mode)
        if not self.lean:
            raise SystemExit("training across GPUs needs the lean training step (fused Adam, no mixed precision)")
        self.ranks = RankGroup.current()
        model = self.pipeline.model
        self.gaussian_names = list(model.gauss_params.keys())
        # one copy per rank; the Gaussians are replaced at each densification, these never are
        self.shared: List[Parameter] = [p for n, p in model.named_parameters() if not n.startswith("gauss_params.")]

    def after_checkpoint_load(self) -> None:
        """A resumed run (`--load-dir`): the checkpoint holds every rank's Gaussians; each rank keeps
        its share (the checkpoint has no Adam moments or statistics for them: they start afresh)."""
        super().after_checkpoint_load()
        gaussians = {name: p.detach() for name, p in self.pipeline.model.gauss_params.items()}
        replace_gaussians(self.pipeline, self.optimizers, RankGroup.current().own_rows(gaussians))

    def _iteration(self, step: int):
        accept = self._accept_step if self.config.guard.enabled else None
        return lean_iteration(
            self.pipeline,
            self.optimizers,
            step,
            accept,
            after_backward=lambda: self.ranks.sum_gradients(self.shared),
            metrics=self._metrics_logged(step),
        )

    def _agree(self, accepted):
        """The guard's verdict on this step, one for all ranks: a step any rank must skip, every rank skips
        (the shared copies stay equal, and the guard's counters, which decide a rollback, agree)."""
        return self.ranks.all_agree(accepted)

    def _check_model(self, step: int) -> None:
        """The guard's model check, one for all ranks: where any rank's share is broken, every rank rolls
        back (to its own healthy state)."""
        try:
            super()._check_model(step)
            broken = None
        except TrainingDiverged as err:
            broken = str(err)
        if self.ranks.any(broken is not None, self.pipeline.model.device):
            raise TrainingDiverged(broken or f"step {step}: the model diverged on another GPU")

    def _after_out_of_memory(self, step: int, message: str):
        # the other ranks wait inside this step's collectives: no rollback can be agreed on; torchrun stops them
        raise SystemExit(
            f"step {step}, GPU {self.ranks.rank}: out of GPU memory ({message}). Lower "
            "--pipeline.model.max-gaussians or the resolution, or use more GPUs"
        )

    def save_checkpoint(self, step: int) -> None:  # every rank: the gather is collective
        gap = self.ranks.differing(self.shared)
        if gap != 0.0:  # a bug, not bad input: the copies must take identical steps
            raise RuntimeError(f"step {step}: the ranks' copies of the shared parameters differ by up to {gap:g}")
        state = gathered_checkpoint_state(self, step, self.ranks, self.gaussian_names)
        if self.ranks.rank == 0:
            only_latest = self.config.save_only_latest_checkpoint
            base = self.config.get_base_dir()
            save_checkpoint(state, self.checkpoint_dir, step, base / PARTIAL_FOLDER, only_latest)
        torch.distributed.barrier()  # no rank runs ahead of a checkpoint being written
        if self.auto_stop is not None:
            self.auto_stop.forget_older_best()
