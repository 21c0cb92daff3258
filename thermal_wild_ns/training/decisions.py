"""What a run chose and why, in one place: printed when training starts and again when it ends, and
written to `decisions.json` beside the run's config (ns-train and the multi-GPU launcher alike).

Each entry is a part of the method (preprocessing, the Gaussian budget, the model's parts, the
automatic stop), the choice the run made, why, and whether the capture's own evidence decided it
('data': a rule measured on this capture) or the method's configuration did ('config': a default or
an option the user set). A user reads at a glance which parts this capture switched on or off, and a
reviewer sees which defaults no measurement of the scene backs.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from typing import List, Optional

from nerfstudio.utils.rich_utils import CONSOLE

from thermal_wild_ns.decisions import Decision
from thermal_wild_ns.pipeline.datamanager import ThermalDatamanager
from thermal_wild_ns.pipeline.run_check import PARTIAL_FOLDER, write_text_atomically
from thermal_wild_ns.training.model_interface import GuardedModel
from thermal_wild_ns.training.schedule import cameras_per_step
from thermal_wild_ns.training.view_probe import verdict_check

DECISIONS_FILE = "decisions.json"


def stop_decision(auto_stop, steps_asked: int, last_step: Optional[int] = None) -> Decision:
    """The automatic stop at the start (on or off, the frames it holds back) or, given the last step
    trained, how the run ended."""
    if auto_stop is None:
        return Decision(
            "training length", f"{steps_asked:,} steps", "--max-num-iterations (no automatic stop)", "config"
        )
    if last_step is None:
        frames, config = auto_stop.held_back_frames, auto_stop.config
        why = (
            f"automatic stop: capture frames {frames} held back to score it every {config.check_every:,} steps; it"
            f" stops after {config.patience} checks ({config.patience * config.check_every:,} steps) without a"
            f" {config.min_improvement:g} dB rise; at most {steps_asked:,} steps"
        )
        return Decision("training length", "until the held-back frames stop improving", why, "data")
    kept = auto_stop.kept_step
    model = "" if kept in (None, last_step) else f"; kept the model of step {kept:,}, the best on the held-back frames"
    if auto_stop.stop_reason is not None:
        return Decision("training length", f"stopped after step {last_step:,}", auto_stop.stop_reason + model, "data")
    return Decision(
        "training length", f"{last_step + 1:,} steps", "--max-num-iterations reached first" + model, "config"
    )


def cameras_decision(config) -> Optional[Decision]:
    """Several training frames per step (`config` the trainer's, its schedule in steps): how the schedule
    was laid out for them; None for one frame per step."""
    count = cameras_per_step(config)
    if count <= 1:
        return None
    model = config.pipeline.model
    why = (
        f"--pipeline.cameras-per-step: the schedule counts training frames, {count} a step: at most"
        f" {config.max_num_iterations:,} steps, densification every {model.refine_every:,} steps until"
        f" step {model.stop_split_at:,}; the optimizers' settings as given"
    )
    return Decision("training frames per step", str(count), why, "config")


def budget_decision(budget, count: int, now: int, history, kept: Optional[int] = None) -> Decision:
    """The Gaussian budget the held-back frames set (`stop_rules.HeldBackBudget`), `now` this GPU's (`count`
    Gaussians in it), with the best held-back score under each budget so far (`history`: the checks' (step,
    score)); where the run kept the model of step `kept` from before its last raise, the budget it trained under."""
    curve = "; ".join(f"{b:,}: {psnr:.2f} dB" for b, psnr in budget.best_per_budget(history))
    scores = f"; best held-back PSNR per budget: {curve}" if curve else ""
    if budget.raises:
        steps = ", ".join(f"{b:,} at step {s:,}" for s, b in budget.raises)
        why = f"raised where the held-back frames plateaued at the budget: {steps}"
        trained_under = None if kept is None else budget.budget_at(kept)
        if trained_under is not None and trained_under != budget.raises[-1][1]:
            why += f"; the model kept (step {kept:,}) trained under {trained_under:,}"
    else:
        why = (
            f"the held-back frames set it: not raised from its start ({budget.start:,}) so far "
            "(no plateau of their score at the budget)"
        )
    return Decision("Gaussian budget", f"{now:,} ({count:,} Gaussians now)", why + scores, "data")


def view_term_decision(auto_stop, last_step: Optional[int] = None) -> Decision:
    """The view term where the held-back frames decide it (`view_probe.py`): pending (at the start),
    on or off; off where the run ended (`last_step`) before a scored check."""
    verdict = auto_stop.view_verdict
    if verdict is None and last_step is not None:
        why = f"the run ended at step {last_step:,}, before the held-back frames' verdict: zeroed"
        return Decision("view-dependent emission", "off", why, "data")
    if verdict is None:
        checks = auto_stop.config.view_trial_checks
        why = f"on trial (every other training step) until the held-back frames decide at {verdict_check(checks)}"
        return Decision("view-dependent emission", "to be decided", why, "data")
    return Decision("view-dependent emission", "on" if verdict.kept else "off", verdict.why(), "data")


class RunDecisions:
    """The decisions of one run: `start(trainer)` after set-up, `finish(trainer, last_step)` before
    the final checkpoint; each prints them and writes `decisions.json` (rank 0 only across GPUs)."""

    def __init__(self, run_dir: Path, rank: int = 0) -> None:
        self.run_dir, self.rank = run_dir, rank
        self.entries: List[Decision] = []

    def collect(self, trainer, last_step: Optional[int] = None) -> List[Decision]:
        pipeline = trainer.pipeline
        model = pipeline.model
        entries: List[Decision] = []
        if isinstance(pipeline.datamanager, ThermalDatamanager):  # stock nerfstudio's makes no choice
            entries += pipeline.datamanager.decisions()
        if isinstance(model, GuardedModel):  # stock splatfacto says none
            entries += model.decisions()
        stop = trainer.auto_stop
        if stop is not None and stop.decides_view_term:  # the data's entry replaces the config's
            entries = [d for d in entries if d.part != "view-dependent emission"]
            entries.append(view_term_decision(stop, last_step))
        cameras = cameras_decision(trainer.config)
        if cameras is not None:
            entries.append(cameras)
        entries.append(stop_decision(trainer.auto_stop, trainer.config.max_num_iterations, last_step))
        budget = None if trainer.auto_stop is None else trainer.auto_stop.budget
        if budget is not None:  # the data's budget replaces the config's fixed one
            entries = [d for d in entries if not (d.part == "Gaussians" and d.decided_by == "config")]
            entries.append(budget_decision(budget, *model.gaussian_budget(), stop.progress.history, stop.kept_step))
        return entries

    def start(self, trainer) -> None:
        self.entries = self.collect(trainer)
        self._report("this run's choices")

    def finish(self, trainer, last_step: int) -> None:
        self.entries = self.collect(trainer, last_step)
        self._report("what this run decided")

    def _report(self, title: str) -> None:
        if self.rank != 0:
            return
        lines = [f"  {d.part}: {d.choice} ({d.decided_by}: {d.why})" for d in self.entries]
        CONSOLE.log(f"[bold]{title}[/bold] (decisions.json beside the config)\n" + "\n".join(lines))
        text = json.dumps([asdict(d) for d in self.entries], indent=1)
        write_text_atomically(self.run_dir / DECISIONS_FILE, text, self.run_dir / PARTIAL_FOLDER)
