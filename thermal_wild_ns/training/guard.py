"""Training that never silently diverges.

`GuardedTrainer` is nerfstudio's Trainer with a check between backward and the optimizer step:
a step whose loss or gradients are not finite, or whose loss spikes far above the recent
median, is skipped (no parameter update, no densification statistics) and logged. Where the
model says its schedule moves the loss (`schedule_moves_loss(step)`: opacity resets, resolution
changes), the recent losses are forgotten instead. Every
`check_every` steps it also checks the model itself and keeps a copy of it when healthy. When
the parameters hold NaN/inf, all Gaussians are gone or transparent, or too many steps in a row
had to be skipped, training rolls back to that copy and goes on; after `max_rollbacks` it stops
with `TrainingDiverged` (a clear message, and a non-zero exit code from `ns-train`).

It also stops a run once the scene stops improving (`auto_stop.py`), says why, and writes the
record of that decision to `auto_stop.json` beside the run's config.
"""

from __future__ import annotations

import collections
import copy
import dataclasses
import functools
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Deque, Dict, List, Optional, Type

import torch
import tyro
import yaml
from nerfstudio.engine.trainer import TrainerConfig
from nerfstudio.utils.decorators import check_main_thread
from nerfstudio.utils.rich_utils import CONSOLE
from torch.profiler import record_function

from thermal_wild_ns._upstream import (
    TrainerAfterLoad,
    fused_adam_ready,
    fused_adam_step,
    guard_optimizer_steps,
    repoint_optimizers,
    trainer_checkpoint_state,
)
from thermal_wild_ns.errors import IncompleteConfig, InputError
from thermal_wild_ns.pipeline.run_check import (
    PARTIAL_FOLDER,
    CheckpointNotSaved,
    check_checkpoint,
    checkpoints_in,
    write_atomically,
    write_text_atomically,
)
from thermal_wild_ns.training.auto_stop import AutoStopConfig, PlateauRule, held_back_images, held_back_score
from thermal_wild_ns.training.model_interface import GuardedModel


class TrainingDiverged(RuntimeError):
    """Training cannot go on: the model is broken (NaN/inf, collapsed) or every step fails."""


@dataclass
class DivergenceGuardConfig:
    enabled: bool = True
    loss_spike_factor: float = 20.0
    """Skip a step whose loss exceeds this many times the median loss of the last accepted steps."""
    spike_window: int = 100
    """Accepted steps the median is taken over (no spike test before the window is full)."""
    persistent_frame_factor: float = 2.0
    """A spike is sudden: a frame whose loss on its previous visit was already within this factor
    of the spike is a hard frame (a flat-field jump, an outlier frame), and its step is accepted.
    Skipping it at every visit would silently drop that frame from training."""
    max_consecutive_skips: int = 50
    """Stop when this many steps in a row had to be skipped."""
    check_every: int = 100
    """Steps between checks of the model itself (finite parameters, Gaussians left, opacity)."""
    max_rollbacks: int = 3
    """When the model breaks (NaN/inf parameters, collapse, every step skipped), training goes back
    to the last healthy state (kept at every model check) up to this many times, then stops."""
    min_mean_opacity: float = 1e-3
    """Stop when the mean Gaussian opacity falls below this (everything turned transparent)."""


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

    def save_config(self) -> None:
        """nerfstudio's `save_config` (config.yml beside the run), written atomically."""
        # the loading commands check for checkpoints before reading data (ThermalPipeline)
        if hasattr(self.pipeline, "checkpoint_dir"):
            self.pipeline.checkpoint_dir = self.get_checkpoint_dir()
        base = self.get_base_dir()
        CONSOLE.log(f"Saving config to: {base / 'config.yml'}")
        write_text_atomically(base / "config.yml", yaml.dump(self), base / PARTIAL_FOLDER)


class DivergenceGuard:
    """The checks, independent of the trainer (`check_step` before the optimizer step,
    `check_model` now and then)."""

    def __init__(self, config: DivergenceGuardConfig):
        self.config = config
        self.recent: Deque[float] = collections.deque(maxlen=config.spike_window)
        self.frame_loss: Dict[int, float] = {}  # each training frame's loss at its last visit
        self.skipped = 0
        self.consecutive = 0
        self.rollbacks = 0

    def check_step(
        self, loss: Optional[torch.Tensor], parameters: dict, groups: List[str], frame: Optional[int] = None
    ) -> Optional[str]:
        """Why this step must be skipped, or None. One host sync: the loss and the sum of all
        gradient norms (one fused kernel; NaN/inf anywhere makes it non-finite) travel together.
        `frame`: the training image of this step, for telling spikes from hard frames."""
        grads = [(g, p.grad) for g in groups for p in parameters[g] if p.grad is not None]
        checks = [loss.detach().float().reshape(1)] if loss is not None else []
        if grads:
            checks.append(torch.stack(torch._foreach_norm([grad for _, grad in grads])).sum().float().reshape(1))
        if not checks:
            return None
        values = torch.cat([c.to(checks[0].device) for c in checks]).tolist()
        if loss is not None:
            value = values.pop(0)
            if not math.isfinite(value):
                return f"non-finite loss ({value})"
            previous = self.frame_loss.get(frame) if frame is not None else None
            if frame is not None:
                self.frame_loss[frame] = value
            if len(self.recent) == self.recent.maxlen:
                median = sorted(self.recent)[len(self.recent) // 2]
                hard_frame = previous is not None and value <= self.config.persistent_frame_factor * previous
                if value > self.config.loss_spike_factor * median and not hard_frame:
                    return f"loss spike ({value:.4g} > {self.config.loss_spike_factor:g} x recent median {median:.4g})"
        if grads and not math.isfinite(values[0]):  # rare: find the culprits one by one
            bad = sorted({g for g, grad in grads if not bool(torch.isfinite(grad).all())}) or ["(norm overflow)"]
            return f"non-finite gradients in {', '.join(bad)}"
        if loss is not None:
            self.recent.append(value)
        return None

    def rebaseline(self) -> None:
        """Forget the recent losses: the schedule itself just moved the loss (an opacity reset, a
        finer training resolution). Without this, every frame's first visit after such a step
        looks like a spike and is skipped, right when the model must recover."""
        self.recent.clear()
        self.frame_loss.clear()

    def record(self, step: int, reason: Optional[str]) -> None:
        if reason is None:
            self.consecutive = 0
            return
        self.skipped += 1
        self.consecutive += 1
        CONSOLE.log(f"[yellow]step {step}: {reason}; step skipped ({self.skipped} so far)")
        if self.consecutive >= self.config.max_consecutive_skips:
            raise TrainingDiverged(
                f"step {step}: {self.consecutive} steps in a row were skipped (last: {reason}). Training has diverged; "
                "lower the learning rates or check the data (diagnose it with wild-thermal-diagnose)."
            )

    def check_model(self, model, step: int) -> None:
        named = [(name, param) for name, param in model.named_parameters() if param.numel() > 0]
        finite = torch.stack([torch.isfinite(param).all() for _, param in named]).tolist()  # one host sync
        for (name, _), ok in zip(named, finite):
            if not ok:
                raise TrainingDiverged(f"step {step}: parameter '{name}' holds NaN/inf values; training has diverged")
        if hasattr(model, "num_points"):
            if model.num_points == 0:
                raise TrainingDiverged(f"step {step}: every Gaussian was pruned; the model collapsed to an empty scene")
            opacity = float(torch.sigmoid(model.opacities.detach()).mean())
            if opacity < self.config.min_mean_opacity:
                raise TrainingDiverged(
                    f"step {step}: mean Gaussian opacity {opacity:.2e} < {self.config.min_mean_opacity:g}; the "
                    f"scene has turned "
                    "transparent (the background explains every pixel)"
                )


SAVES_PER_RUN = 10
"""A run saves a checkpoint at least this many times (every 10 % of its steps), as well as every
`--steps-per-save`: a short run killed part-way leaves something to resume from."""


class GuardedTrainer(TrainerAfterLoad):
    """nerfstudio's Trainer with `DivergenceGuard` between backward and the optimizer step, where
    `--max-num-iterations` is the run's total step count, resumed or not."""

    config: GuardedTrainerConfig

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
        self.guard = DivergenceGuard(self.config.guard)
        # once, not per step: a runtime protocol check is slow, and the model's class does not change
        self.guarded_model = isinstance(self.pipeline.model, GuardedModel)
        self._step = 0
        unsupported = self._lean_step_unsupported() if self.config.lean_step else None
        self.lean = self.config.lean_step and unsupported is None
        if unsupported is not None:
            CONSOLE.log(f"nerfstudio's training step (not the lean one): {unsupported}")
        if self.config.guard.enabled and not self.lean:  # the lean step calls the guard itself
            guard_optimizer_steps(self.optimizers, self._accept_step)
        self._setup_auto_stop()

    def _lean_step_unsupported(self) -> Optional[str]:
        """Why `_lean_iteration` cannot stand in for nerfstudio's step with this config, or None."""
        config = self.config
        if config.mixed_precision:
            return "mixed precision"
        if any(n != 1 for n in config.gradient_accumulation_steps.values()) or config.log_gradients:
            return "gradient accumulation or gradient logging"
        for name, optimizer in self.optimizers.optimizers.items():
            if not fused_adam_ready(optimizer) or self.optimizers.config[name]["optimizer"].max_norm is not None:
                return f"optimizer '{name}' is not a fused Adam without gradient clipping"
        return None

    def _lean_iteration(self, step: int):
        """nerfstudio's `Trainer.train_iteration` where `_lean_step_unsupported` is None, with its
        result: gradients cleared, loss (the loss dict summed in the same order), backward, the
        divergence guard, every optimizer stepped (`fused_adam_step`), the schedulers stepped."""
        optimizers = list(self.optimizers.optimizers.values())
        for optimizer in optimizers:
            for group in optimizer.param_groups:
                for param in group["params"]:
                    param.grad = None
        _, loss_dict, metrics_dict = self.pipeline.get_train_loss_dict(step=step)
        loss = functools.reduce(torch.add, loss_dict.values())
        loss.backward()
        if not self.config.guard.enabled or self._accept_step(list(self.optimizers.parameters)):
            fused_adam_step(optimizers)
        self.optimizers.scheduler_step_all(step)
        return loss, loss_dict, metrics_dict

    def _iteration(self, step: int):
        return self._lean_iteration(step) if self.lean else super().train_iteration(step)

    def _setup_auto_stop(self) -> None:
        """Hold the scoring frames back from the datamanager's training order (before any step)."""
        config, datamanager = self.config.auto_stop, self.pipeline.datamanager
        self.progress: Optional[PlateauRule] = None
        self.stop_reason: Optional[str] = None
        if not config.enabled or not hasattr(datamanager, "hold_back"):
            return
        images = held_back_images(len(datamanager.train_dataset), config.held_back_frames)
        if not images:
            CONSOLE.log(
                f"automatic stop off: {len(datamanager.train_dataset)} training images are too few to hold "
                f"{config.held_back_frames} back"
            )
            return
        datamanager.hold_back(images)
        self.progress = PlateauRule(config.patience, config.min_improvement)
        self._best: Optional[dict] = None
        frames = [datamanager.train_dataset.frame_index(k) for k in images]
        CONSOLE.log(f"automatic stop: capture frames {frames} are held back from training to score it")
        if self.config.load_dir is not None:
            self._resume_auto_stop(Path(self.config.load_dir).parent)

    def _partial_dir(self) -> Path:
        """Where this run's files are written before their rename into place (`run_check`)."""
        return self.config.get_base_dir() / PARTIAL_FOLDER

    def _state_path(self, kind: str, step: int, run: Optional[Path] = None) -> Path:
        """Where a state of step `step` is kept beside the run's config (this run's, or `run`'s):
        'best', the best-scoring model so far, which a resumed run can still go back to; 'trained',
        the state trained last when the final checkpoint holds the best one instead."""
        return (run or self.config.get_base_dir()) / "auto_stop" / f"{kind}-{step:09d}.pt"

    def _resume_auto_stop(self, run: Path) -> None:
        """Continue the automatic stop of the run being resumed: its checks before the checkpoint,
        replayed, and its best model so far. Where that run ended by keeping its best model, the
        training goes on from the state it had trained, not from the kept one."""
        record_path = run / "auto_stop.json"
        if not record_path.is_file():
            return
        record = json.loads(record_path.read_text())
        ended_on_kept = record.get("kept_step") not in (None, record["last_step"])
        if ended_on_kept and record["last_step"] == self._start_step - 1:
            trained = self._state_path("trained", record["last_step"], run)
            if trained.is_file():
                self._restore(torch.load(trained, map_location=self.pipeline.device, weights_only=True))
                self.pipeline.model.step = self._start_step
            else:
                CONSOLE.log(f"[yellow]automatic stop: {trained} is gone: training goes on from the kept model")
        for check in record["checks"]:
            if check["step"] < self._start_step:
                self.progress.update(check["step"], check["psnr"])
        best = self.progress.best_step
        if best is not None and self.config.auto_stop.keep_best:
            path = self._state_path("best", best, run)
            if path.is_file():
                self._best = torch.load(path, map_location=self.pipeline.device, weights_only=True)
            else:
                CONSOLE.log(f"[yellow]automatic stop: {path} is gone: the model of step {best} can no longer be kept")

    def _accept_step(self, param_groups) -> bool:
        """Whether this step's update may happen (the guard's checks on its loss and gradients)."""
        model = self.pipeline.model
        guarded = self.guarded_model
        loss, frame = model.last_training_loss() if guarded else (None, None)
        with record_function("thermal/guard_check"):  # named sections for python -m experiments.profile_step
            reason = self.guard.check_step(loss, self.optimizers.parameters, param_groups, frame)
        if reason is not None and guarded:
            model.discard_step_statistics()  # the strategy must not record this step's gradients either
        self.guard.record(self._step, reason)
        return reason is None

    def train(self) -> None:
        # nerfstudio trains max_num_iterations steps after the step it resumed from; here it is the
        # total, so a resumed run ends where the uninterrupted one would
        total, every = self.config.max_num_iterations, self.config.steps_per_save
        self.total_steps = total
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

    def after_checkpoint_load(self) -> None:
        # splatfacto's load_state_dict replaced the Gaussian parameters after the optimizers were built
        repoint_optimizers(self.optimizers, self.pipeline.get_param_groups())

    def train_iteration(self, step: int):
        self._step = step
        result = self._guarded_iteration(step)
        if self.progress is not None and (step + 1) % self.config.auto_stop.check_every == 0:
            self._check_progress(step)
        return result

    def _check_progress(self, step: int) -> None:
        """Score the held-back frames; stop training at a plateau. No score before the schedule's
        start-up is over (the model's `settled_step`: full resolution, first opacity reset)."""
        if self.guarded_model and step < self.pipeline.model.settled_step:
            return
        score = held_back_score(self.pipeline, self.pipeline.datamanager.held_back)
        if self.progress.update(step, score) and self.config.auto_stop.keep_best:
            self._best = self._snapshot(step)
            best = self._best
            write_atomically(self._state_path("best", step), lambda tmp: torch.save(best, tmp), self._partial_dir())
        if self.progress.plateaued and self.stop_reason is None:
            self.stop_reason = self.progress.reason(self.config.auto_stop.check_every)
            self.stop_training = True  # nerfstudio's loop ends before the next step
            CONSOLE.log(f"[bold]step {step}: training stops: {self.stop_reason}")
        self._write_auto_stop_record(kept=None)

    @check_main_thread
    def save_checkpoint(self, step: int) -> None:
        """nerfstudio's checkpoint (`trainer_checkpoint_state`), written atomically: a run killed or
        out of disk space while saving keeps its previous checkpoint whole, and no partial file is
        ever in `nerfstudio_models/`."""
        path = self.checkpoint_dir / f"step-{step:09d}.ckpt"
        state = trainer_checkpoint_state(self, step)
        try:
            write_atomically(path, lambda tmp: torch.save(state, tmp), self._partial_dir())
        except CheckpointNotSaved as err:
            kept = checkpoints_in(self.checkpoint_dir)
            resume = (
                f"the last checkpoint, {kept[-1]}, is whole: resume from it with --load-dir {self.checkpoint_dir}"
                if kept
                else "no earlier checkpoint was saved"
            )
            raise CheckpointNotSaved(f"step {step}: {err}. Training stops; {resume}") from err.__cause__
        if self.config.save_only_latest_checkpoint:  # only once the new one is in place
            for old in checkpoints_in(self.checkpoint_dir):
                if old != path:
                    old.unlink()
        # a resume from this checkpoint (or a later one) needs no best model older than the best so far
        best = self.progress.best_step if self.progress is not None else None
        if best is not None:
            for path in self._state_path("best", best).parent.glob("best-*.pt"):
                if int(path.stem.split("-")[1]) < best:
                    path.unlink()

    def before_final_checkpoint(self) -> None:
        if self.progress is None:
            return
        self.step = self._step  # the last step trained (nerfstudio's loop counted one past it at a stop)
        history = self.progress.history
        checked = bool(history) and history[-1][0] == self._step
        final = history[-1][1] if checked else held_back_score(self.pipeline, self.pipeline.datamanager.held_back)
        kept = self._step
        if self._best is not None and self.progress.best > final + self.progress.min_improvement:
            # the state trained last, for a resume that goes on training (the final checkpoint holds the kept one)
            trained = self._snapshot(self._step)
            write_atomically(
                self._state_path("trained", self._step), lambda tmp: torch.save(trained, tmp), self._partial_dir()
            )
            self._restore(self._best)
            self.pipeline.model.step = self._step  # splatfacto's load_state_dict sets it to 30000
            kept = self._best["step"]
            CONSOLE.log(
                f"[bold]kept the model of step {kept} ({self.progress.best:.2f} dB on the held-back frames, "
                f"{final:.2f} at the end)"
            )
        self._write_auto_stop_record(kept, final)

    def _write_auto_stop_record(self, kept: Optional[int], final: Optional[float] = None) -> None:
        """auto_stop.json beside the run's config: the checks so far (a resumed run replays them)
        and, at the end, the model kept and why the run ended."""
        datamanager = self.pipeline.datamanager
        record = {
            "held_back_frames": [datamanager.train_dataset.frame_index(k) for k in datamanager.held_back],
            "steps_asked": self.total_steps,
            "last_step": self._step,
            "stopped_early": self.stop_reason is not None,
            "reason": self.stop_reason,
            "kept_step": kept,
            "final_psnr": final,
            "checks": [{"step": s, "psnr": v} for s, v in self.progress.history],
        }
        write_text_atomically(
            self.config.get_base_dir() / "auto_stop.json", json.dumps(record, indent=1), self._partial_dir()
        )

    def _guarded_iteration(self, step: int):
        if not self.config.guard.enabled:
            return self._iteration(step)
        if self.guarded_model and self.pipeline.model.schedule_moves_loss(step):
            self.guard.rebaseline()
        try:
            result = self._iteration(step)
            if step % self.config.guard.check_every == 0:
                self.guard.check_model(self.pipeline.model, step)
                self._healthy = self._snapshot(step)
        except TrainingDiverged as err:
            healthy = getattr(self, "_healthy", None)
            if healthy is None or self.guard.rollbacks >= self.config.guard.max_rollbacks:
                raise
            self._restore(healthy)
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

    def _snapshot(self, step: int) -> dict:
        """A copy of everything a rollback restores: parameters (Gaussians, embeddings, MLPs),
        densification statistics and RNG (the model's extra state), optimizer moments."""
        return {
            "step": step,
            "model": copy.deepcopy(self.pipeline.model.state_dict()),
            "optimizers": {name: copy.deepcopy(opt.state_dict()) for name, opt in self.optimizers.optimizers.items()},
        }

    def _restore(self, healthy: dict) -> None:
        self.pipeline.model.load_state_dict(copy.deepcopy(healthy["model"]))
        repoint_optimizers(
            self.optimizers, self.pipeline.get_param_groups()
        )  # the load replaced the Gaussian parameters
        for name, optimizer in self.optimizers.optimizers.items():
            optimizer.load_state_dict(copy.deepcopy(healthy["optimizers"][name]))
