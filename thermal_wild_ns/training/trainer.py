"""`GuardedTrainer`: nerfstudio's Trainer, made of small parts, each its own module and tests.

- the lean step (`lean_step.py`): nerfstudio's training step without its per-step Python;
- the divergence guard (`divergence.py`) between backward and the optimizer step: a step whose loss
  or gradients are not finite, or whose loss spikes far above the recent median, is skipped (no
  update, no densification statistics); where the model says its schedule moves the loss
  (`schedule_moves_loss(step)`), the recent losses are forgotten instead. Every `check_every` steps
  it checks the model itself and keeps a healthy copy (`checkpoints.snapshot`); a broken model rolls
  back to it, up to `max_rollbacks` times, then `TrainingDiverged` stops the run (a clear message,
  a non-zero exit code from `ns-train`);
- the automatic stop (`auto_stop.AutoStopRun`): stops once the scene stops improving, says why,
  keeps the best model and records the decision in `auto_stop.json` beside the run's config;
- the run's decisions (`decisions.RunDecisions`): what the run chose and why (preprocessing, the
  model's size and parts, its length), printed at the start and the end and kept in `decisions.json`;
- checkpoints (`checkpoints.py`) written atomically, at least `SAVES_PER_RUN` times a run, and
  `--max-num-iterations` as the run's total length, resumed or not;
- the schedule in training frames (`schedule.in_steps`): with several cameras per step the trainer runs
  the config's lengths divided by their count, the config itself (config.yml) as the user gave it.

What the trainer asks of the model is one declared interface (`model_interface.GuardedModel`); a
model without it (stock splatfacto) trains without those checks.
"""

from __future__ import annotations

import dataclasses
import os
import random
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Type

import numpy as np
import torch
import tyro
import yaml
from nerfstudio.engine.trainer import TrainerConfig
from nerfstudio.utils.decorators import check_main_thread
from nerfstudio.utils.misc import step_check
from nerfstudio.utils.rich_utils import CONSOLE

from thermal_wild_ns._upstream import (
    TrainerAfterLoad,
    guard_optimizer_steps,
    lighter_event_writes,
    profiled_section,
    repoint_optimizers,
    trainer_checkpoint_state,
)
from thermal_wild_ns.errors import IncompleteConfig, InputError
from thermal_wild_ns.pipeline.ranks import RankGroup
from thermal_wild_ns.pipeline.run_check import PARTIAL_FOLDER, check_checkpoint, write_text_atomically
from thermal_wild_ns.pipeline.thermal_pipeline import ThermalPipeline, ThermalPipelineConfig
from thermal_wild_ns.training.auto_stop import AutoStopConfig, AutoStopRun
from thermal_wild_ns.training.checkpoints import SAVES_PER_RUN, restore, save_checkpoint, snapshot
from thermal_wild_ns.training.decisions import RunDecisions
from thermal_wild_ns.training.divergence import DivergenceGuard, DivergenceGuardConfig, TrainingDiverged
from thermal_wild_ns.training.lean_step import lean_iteration, lean_step_unsupported, total_loss
from thermal_wild_ns.training.model_interface import GuardedModel
from thermal_wild_ns.training.schedule import in_steps


@dataclass
class GuardedTrainerConfig(TrainerConfig):
    _target: Type = field(default_factory=lambda: GuardedTrainer)
    prompt: tyro.conf.Suppress[Optional[str]] = None
    """nerfstudio's alias of the model's text prompt: thermal models take none."""
    guard: DivergenceGuardConfig = field(default_factory=DivergenceGuardConfig)
    """Divergence and collapse detection."""
    auto_stop: AutoStopConfig = field(default_factory=AutoStopConfig)
    """Stop when the scene stops improving, scored on a few training frames held back from the gradient."""
    lean_step: bool = True
    """Run each training step's body in this plugin's trainer rather than through nerfstudio's
    `Trainer.train_iteration`: the same forward, loss, backward, checks and Adam update, without the
    per-step Python around them (gradient-accumulation and grad-scaler bookkeeping, one wrapped
    `step()` per optimizer). It needs fused Adam optimizers without gradient clipping, no mixed
    precision and no gradient accumulation, and falls back to nerfstudio's step (and says why)
    otherwise. False: always nerfstudio's step, the reference the lean one is tested against."""

    def __setstate__(self, state: dict) -> None:
        """How config.yml is read back (PyYAML sets a saved object's fields through this): a file cut
        short lacks the fields saved last, which would otherwise fall back to defaults silently."""
        missing = [f.name for f in dataclasses.fields(self) if f.name not in state]
        if missing:
            raise IncompleteConfig(
                f"{len(missing)} settings are missing, the last saved first: {', '.join(missing[-3:])}"
            )
        self.__dict__.update(state)

    def set_experiment_name(self) -> None:
        """A run is named after its data folder (`outputs/NAME/METHOD/TIMESTAMP`). nerfstudio names it after
        `--data` given before the dataparser (`ns-train M --data X`) and calls it 'unnamed' otherwise, which
        is this plugin's usual form (`ns-train M thermal --data X`): every survey's runs would share one
        folder. Here the dataparser's folder names it where nerfstudio's alias was not given."""
        data = getattr(self.pipeline.datamanager.dataparser, "data", None)
        if self.experiment_name is None and self.pipeline.datamanager.data is None and data is not None:
            folder = Path(os.path.abspath(data))  # '.' and '..' named, a link by its own name
            self.experiment_name = (folder.parent if folder.is_file() else folder).name or None
        super().set_experiment_name()

    def save_config(self) -> None:
        """nerfstudio's `save_config` (config.yml beside the run), written atomically."""
        # the loading commands check for checkpoints before reading data (ThermalPipeline)
        if isinstance(self.pipeline, ThermalPipelineConfig):
            self.pipeline.checkpoint_dir = self.get_checkpoint_dir()
        base = self.get_base_dir()
        CONSOLE.log(f"Saving config to: {base / 'config.yml'}")
        write_text_atomically(base / "config.yml", yaml.dump(self), base / PARTIAL_FOLDER)


class GuardedTrainer(TrainerAfterLoad):
    """nerfstudio's Trainer with the lean step, the divergence guard, the automatic stop and atomic
    checkpoints, where `--max-num-iterations` is the run's total length in training frames, resumed or not."""

    config: GuardedTrainerConfig

    def __init__(self, config: GuardedTrainerConfig, local_rank: int = 0, world_size: int = 1) -> None:
        # the trainer counts steps; the config counts frames (the same where a step trains one)
        super().__init__(in_steps(config), local_rank, world_size)

    def setup(self, test_mode="val"):
        load_dir = self.config.load_dir
        if load_dir is not None:
            # a user's typo or a damaged file, not a bug: one line, no traceback (before the data is read)
            if not Path(load_dir).is_dir():
                raise SystemExit(
                    f"--load-dir {load_dir}: no such folder (a run's checkpoints are in RUN/nerfstudio_models)"
                )
            try:
                check_checkpoint(Path(load_dir), self.config.load_step)
            except InputError as err:
                raise SystemExit(f"--load-dir: {err}") from None
        super().setup(test_mode=test_mode)
        lighter_event_writes()  # host work at every step otherwise
        self.guard = DivergenceGuard(self.config.guard)
        # once, not per step: a runtime protocol check is slow, and the model's class does not change
        self.guarded_model = isinstance(self.pipeline.model, GuardedModel)
        self._step = 0
        self._healthy: Optional[dict] = None  # the last healthy state, for a rollback
        unsupported = lean_step_unsupported(self.config, self.optimizers) if self.config.lean_step else None
        self.lean = self.config.lean_step and unsupported is None
        if unsupported is not None:
            CONSOLE.log(f"nerfstudio's training step (not the lean one): {unsupported}")
        if self.config.guard.enabled and not self.lean:  # the lean step calls the guard itself
            guard_optimizer_steps(self.optimizers, self._accept_step_now)
        self.auto_stop = AutoStopRun.start(
            self.config.auto_stop,
            self.pipeline,
            self.optimizers,
            self.config.get_base_dir(),
            self.config.max_num_iterations,
        )
        if self.auto_stop is not None and load_dir is not None:
            self.auto_stop.resume(Path(load_dir).parent, self._start_step)
        self.decisions = RunDecisions(self.config.get_base_dir(), RankGroup.current().rank)
        self.decisions.start(self)

    def _step_verdict(self, param_groups, loss: Optional[torch.Tensor] = None) -> Optional[torch.Tensor]:
        """Whether this step's update may happen: the guard's checks on its loss and gradients, decided
        on the device ([] bool; None: nothing to check), recorded by the guard a step later. `loss`: the
        step's total where the step summed it (the lean step), else the model's losses are summed here;
        a model without the trainer's interface has no loss checked."""
        losses, frame = self.pipeline.model.last_training_losses() if self.guarded_model else (None, None)
        if losses is None:
            loss = None
        elif loss is None:
            loss = total_loss(losses)
        with profiled_section("thermal/guard_check"):  # named sections for python -m experiments.profile_step
            return self.guard.verdict(
                loss, self.optimizers.parameters, param_groups, frame, step=self._step, agree=self._agree
            )

    def _agree(self, accepted: torch.Tensor) -> torch.Tensor:
        """One verdict for every GPU of the run (here one GPU: its own)."""
        return accepted

    def _check_model(self, step: int) -> None:
        """The guard's check of the model itself (`TrainingDiverged` when broken)."""
        self.guard.check_model(self.pipeline.model, step)

    def _accept_step(self, param_groups, loss: Optional[torch.Tensor] = None) -> Optional[torch.Tensor]:
        """The lean step's verdict (`_step_verdict`) on the step's total `loss`, on the device: the optimizers
        take it as `found_inf`, the model keeps a rejected step's gradients out of its densification statistics."""
        accepted = self._step_verdict(param_groups, loss)
        if accepted is not None and self.guarded_model:
            self.pipeline.model.weigh_step_statistics(accepted)
        return accepted

    def _accept_step_now(self, param_groups) -> bool:
        """nerfstudio's step asks before its optimizers step: the verdict, read back at once."""
        accepted = self._accept_step(param_groups)
        self.guard.settle()
        return accepted is None or bool(accepted)

    def train(self) -> None:
        # nerfstudio trains max_num_iterations steps after the step it resumed from; here it is the
        # total, so a resumed run ends where the uninterrupted one would
        total, every = self.config.max_num_iterations, self.config.steps_per_save
        remaining = max(0, total - self._start_step)
        if remaining == 0:
            CONSOLE.log(f"the checkpoint is at step {self._start_step - 1}: --max-num-iterations {total} is reached")
            return
        self.config.max_num_iterations = remaining
        self.config.steps_per_save = min(every, max(1, total // SAVES_PER_RUN))
        try:
            super().train()
        finally:
            self.config.max_num_iterations, self.config.steps_per_save = total, every

    def optimizer_states_loaded(self, states: dict) -> dict:
        model = self.pipeline.model  # loaded inside nerfstudio's setup, before `guarded_model` is set
        return model.optimizer_states_of(states) if isinstance(model, GuardedModel) else states

    def after_checkpoint_load(self) -> None:
        # splatfacto's load_state_dict replaced the Gaussian parameters after the optimizers were built
        repoint_optimizers(self.optimizers, self.pipeline.get_param_groups())

    def train_iteration(self, step: int):
        self._step = step
        result = self._guarded_iteration(step)
        if self.auto_stop is not None and (step + 1) % self.config.auto_stop.check_every == 0:
            if self.auto_stop.check(step):
                self.stop_training = True  # nerfstudio's loop ends before the next step
        return result

    @check_main_thread
    def save_checkpoint(self, step: int) -> None:
        """nerfstudio's checkpoint (`trainer_checkpoint_state`), written atomically (`checkpoints.py`)."""
        state = trainer_checkpoint_state(self, step)
        only_latest = self.config.save_only_latest_checkpoint
        save_checkpoint(state, self.checkpoint_dir, step, self.config.get_base_dir() / PARTIAL_FOLDER, only_latest)
        if self.auto_stop is not None:
            self.auto_stop.forget_older_best()

    def before_final_checkpoint(self) -> None:
        self.guard.settle()  # the last step's skip, if it was one, is counted
        if self.auto_stop is not None:
            self.step = self._step  # the last step trained (nerfstudio's loop counted one past it at a stop)
            self.auto_stop.finish(self._step)
        self.decisions.finish(self, self._step)

    def _iteration(self, step: int):
        if self.lean:
            accept = self._accept_step if self.config.guard.enabled else None
            return lean_iteration(self.pipeline, self.optimizers, step, accept, metrics=self._metrics_logged(step))
        return super().train_iteration(step)

    def _metrics_logged(self, step: int) -> bool:
        """Whether nerfstudio's loop logs this step's metrics (its log steps), or the pipeline computes them
        at every step anyway (one not the plugin's): the plugin's pipeline leaves them out elsewhere, a few
        operations less per step."""
        logged = step_check(step, self.config.logging.steps_per_log, run_at_zero=True)
        return logged or not isinstance(self.pipeline, ThermalPipeline)

    def _guarded_iteration(self, step: int):
        if not self.config.guard.enabled:
            return self._iteration(step)
        out_of_memory = None
        try:
            return self._checked_iteration(step)
        except torch.OutOfMemoryError as err:  # handled below, once the failed step's tensors are released
            out_of_memory = str(err).splitlines()[0]
        return self._after_out_of_memory(step, out_of_memory)

    def _after_out_of_memory(self, step: int, message: str):
        """A step ran out of GPU memory: back to the last healthy state, whose Gaussian count is then
        the most densification may reach (`limit_growth`), as a rollback (it counts as one)."""
        healthy = self._healthy
        count = None if healthy is None else int(healthy["model"]["gauss_params.means"].shape[0])
        if count is None or not self.guarded_model or self.guard.rollbacks >= self.config.guard.max_rollbacks:
            raise SystemExit(
                f"step {step}: out of GPU memory ({message}). Lower --pipeline.model.max-gaussians or the "
                "resolution, or train across GPUs (torchrun -m thermal_wild_ns.multi_gpu)"
            )
        torch.cuda.empty_cache()
        restore(self.pipeline, self.optimizers, healthy)
        model = self.pipeline.model
        model.step = step
        model.discard_step_statistics()
        model.limit_growth(count)
        self.guard.rollbacks += 1
        CONSOLE.log(
            f"[yellow]step {step}: out of GPU memory -> rolled back to step {healthy['step']} ({count:,} Gaussians), "
            f"which densification will not grow past ({self.guard.rollbacks} of at most "
            f"{self.config.guard.max_rollbacks} rollbacks)"
        )
        zero = torch.zeros((), device=self.pipeline.device)
        return zero, {"rolled_back": zero}, {}

    def _checked_iteration(self, step: int):
        try:
            if self.guarded_model and self.pipeline.model.schedule_moves_loss(step):
                self.guard.rebaseline()  # reads the last verdict back first: it may stop the run
            result = self._iteration(step)
            if step % self.config.guard.check_every == 0:
                self.guard.settle()  # this step's skip counted before the model is judged
                self._check_model(step)
                self._healthy = None  # the older copy goes before the new one is made
                self._healthy = snapshot(self.pipeline, self.optimizers, step)
        except TrainingDiverged as err:
            healthy = self._healthy
            if healthy is None or self.guard.rollbacks >= self.config.guard.max_rollbacks:
                raise
            restore(self.pipeline, self.optimizers, healthy)
            model = self.pipeline.model
            model.step = step  # splatfacto's load_state_dict sets it to 30000 (for its viewer)
            if self.guarded_model:
                model.discard_step_statistics()  # this step's statistics belong to the discarded state
            self.guard.rollbacks += 1
            self.guard.consecutive = 0
            CONSOLE.log(
                f"[yellow]{err} -> rolled back to the healthy state of step {healthy['step']} "
                f"({self.guard.rollbacks} of at most {self.config.guard.max_rollbacks} rollbacks)"
            )
            zero = torch.zeros((), device=self.pipeline.device)
            return zero, {"rolled_back": zero}, {}
        return result


def seeded_trainer(config: TrainerConfig, local_rank: int = 0):
    """The trainer of `config`, set up as `ns-train` sets it up (nerfstudio's `train_loop`): Python's,
    numpy's and torch's random generators seeded with `config.machine.seed` first, so the initial
    Gaussians and networks, and every draw after them, are the same in every run of one config. For
    code that trains without `ns-train` (the demo, the benchmarks, each GPU's process of `multi_gpu.py`,
    on GPU `local_rank`)."""
    seed = config.machine.seed
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)
    trainer = config.setup(local_rank=local_rank, world_size=1)
    trainer.setup()
    return trainer
