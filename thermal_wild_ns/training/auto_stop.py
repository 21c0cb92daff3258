"""Training that stops when the scene stops improving.

A few training frames are held back from the gradient (evenly spread, never the first or last, so
their photometric state can be interpolated from their neighbours). Every `check_every` steps, once
the schedule's start-up is over (full resolution, past the first opacity reset), the model renders
them at that interpolated state and is scored against them as captured (PSNR, original space), after
a least-squares gain + offset fit per frame: the `time` render, scored as the `aligned` protocol
scores, on frames that are not the test views. The fit keeps a frame's global level, which nothing
before it predicts when the camera jumped (an AGC step, one bright frame), from swamping the
score's changes: they are the scene's (docs/results/scene_table_defaults_h100: a held-back bright frame
ended runs at their first checks without it).
When the score has not risen by `min_improvement` dB in `patience` checks in a row, training stops,
and the best-scoring model is kept. Quality on new views can fall after an early peak; the
held-back frames see that fall, which no measure of the frames being fitted can.

`stop_rules.py` holds the decisions alone (`PlateauRule`, `HeldBackBudget`); `held_back.py` picks the frames
and scores them; `AutoStopRun` is all of it for one run, as the trainer drives it.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional

import torch
from nerfstudio.utils.rich_utils import CONSOLE

from thermal_wild_ns.pipeline.datamanager import ThermalDatamanager
from thermal_wild_ns.pipeline.ranks import RankGroup
from thermal_wild_ns.pipeline.run_check import PARTIAL_FOLDER, write_atomically, write_text_atomically
from thermal_wild_ns.training.checkpoints import restore, snapshot
from thermal_wild_ns.training.held_back import held_back_images, held_back_score, scene_renders, share_images
from thermal_wild_ns.training.model_interface import GuardedModel
from thermal_wild_ns.training.stop_rules import HeldBackBudget, PlateauRule
from thermal_wild_ns.training.view_probe import ViewTermVerdict, judge_view_term, verdict_check


@dataclass
class AutoStopConfig:
    enabled: bool = True
    """Stop once the held-back frames' score stops improving (off: train every step asked for)."""
    held_back_frames: int = 2
    """Training frames held back from the gradient to score the model on."""
    check_every: int = 500
    """Steps between two scores of the held-back frames."""
    patience: int = 4
    """Checks in a row without an improvement after which training stops."""
    patience_floor_steps: int = 650
    """Fewest steps `patience` checks span where the checks are fitted to a shorter schedule (`scale_to`:
    the demo's and the bench's; `ns-train` keeps the full schedule's checks): there the checks come more
    often, and the patience grows to span this many steps. The held-back score fits a
    gain and offset per frame, so it flattens before the per-frame states have settled; where the wait was
    4 checks of a 5,000-step schedule (332 steps), a wait of twice that lifted `time` on most generated
    scenes, and doubling the full schedule's wait changed neither real capture clearly
    (docs/results/patience_h200x2); on both real captures' shortened schedule it is level or higher
    within the seeds' spread (docs/results/floor_real_h200). 0: the patience in checks alone."""
    min_improvement: float = 0.05
    """Rise of the score (PSNR, dB) over the best so far that counts as an improvement."""
    keep_best: bool = True
    """At a stop, and at the end of a run, go back to the model of the best-scoring check when the
    last check scored lower."""
    grow_budget: bool = True
    """Let the held-back frames set the Gaussian budget: the run starts at `budget_start` (in place of the
    model's fixed `max_gaussians`); where their score has plateaued with the model at its budget, the
    budget doubles and training goes on instead of stopping; a later plateau doubles it again only if the
    last raise brought a new best, else the run stops and keeps its best model. The model grows only while
    frames it never trained on gain from it (`HeldBackBudget`). On by default: from a small start it
    matched or beat the fixed budget's `time` and `aligned` on both real captures and every generated
    scene with several times fewer Gaussians (docs/results/grow_default_h200). Off, or with the stop off:
    the fixed `max_gaussians`."""
    budget_start: int = 12_500
    """The Gaussian budget (over every GPU) a run starts from where the held-back frames set it
    (`grow_budget`), or the seed points' count where that is larger; each raise doubles it."""
    budget_limit: int = 1_000_000
    """The most Gaussians `grow_budget` may reach (over every GPU)."""
    decide_view_term: bool = False
    """With a view term in the model (`--pipeline.model.view-sh-degree` 1 or 2): let the held-back frames
    decide whether it stays. Until scored check `view_trial_checks`, training renders alternate with and
    without the term; there the held-back frames are scored both ways (a radial fall-off fitted to each, so
    that mimicking the camera's vignetting earns nothing), and the term stays where it scores higher
    by `min_improvement` and little of what it adds is radial (`view_max_radial_share`), else it is zeroed
    for good (`view_probe.py`); one GPU only. Off: the term trains from the start. Off by default: right
    on every generated scene whose answer is known, it drops the term on both real captures (what the term
    adds there is more radial than on a scene made to need it), so by default it would only add its cost
    (docs/results/view_share_h200).
    For captures whose view effect is not radial: oblique views of façades, reflections of the sky."""
    view_max_radial_share: float = 0.09
    """With `decide_view_term`: the largest share of what the term adds to training views that one radial
    fall-off about the image centre may explain, and the term stay. Above it the term does what the camera
    model does (a camera's vignetting is the same radial pattern in every view; radiance that changes with
    the view follows surfaces, not the sensor) and is zeroed, whatever the held-back frames score. Set
    between the shares the trial saw on CPU at its first check: the generated vignetting scene above it,
    the generated scene made to need the term and the tests' small one below (docs/results/view_verdict_cpu,
    "The term's radial share")."""
    view_trial_checks: int = 1
    """With `decide_view_term`: the scored check at which the held-back frames decide (1: the first). A
    later verdict lets the term and the frame states train side by side for longer before they are judged
    (docs/results/view_verdict_cpu)."""

    def scale_to(self, schedule: int, full_schedule: int = 30_000) -> None:
        """Check as often, relative to the schedule, in a run whose schedule is `schedule` steps
        long instead of `full_schedule` (the one `check_every` is given for), and wait at least
        `patience_floor_steps` (in checks, within the schedule) before stopping."""
        self.check_every = max(self.check_every * min(schedule, full_schedule) // full_schedule, 10)
        floor_steps = min(self.patience_floor_steps, schedule)
        self.patience = max(self.patience, math.ceil(floor_steps / self.check_every))


class AutoStopRun:
    """The automatic stop of one training run, as the trainer drives it: `start` holds the scoring
    frames back from the datamanager's training order (before any step); `check(step)` every
    `check_every` steps scores them and keeps the best model; `finish(step)` before the final
    checkpoint keeps the best model where it beat the last, and `auto_stop.json` beside the run's
    config records every check and the decision (a resumed run replays it: `resume`)."""

    def __init__(self, config: AutoStopConfig, pipeline, optimizers, run_dir: Path, steps_asked: int):
        self.config, self.pipeline, self.optimizers = config, pipeline, optimizers
        self.run_dir, self.steps_asked = run_dir, steps_asked
        self.partial_dir = run_dir / PARTIAL_FOLDER  # where its files are written before their rename
        self.progress = PlateauRule(config.patience, config.min_improvement)
        self.stop_reason: Optional[str] = None
        self.kept_step: Optional[int] = None
        """The step whose model the run ended with (set by `finish`)."""
        self.last_step = 0
        self._best: Optional[dict] = None
        self.check_counts: Dict[int, int] = {}
        """step -> Gaussians (this GPU's) at each check: the held-back score against the model's size."""
        self._scores_settled_model = isinstance(pipeline.model, GuardedModel)  # it says when scores settle
        # across GPUs every rank scores (renders are collective) and keeps its own Gaussians' best state;
        # rank 0's score decides for all, and rank 0 writes the record
        self.ranks = RankGroup.current()
        grows = config.grow_budget and self._scores_settled_model  # the model says its count and budget
        self.budget = None
        if grows:  # the held-back frames' budget replaces the model's fixed one from the first step
            # never below the seed points: a budget under the model's size would hold back every raise
            # that does not pass it (growth needs room), whatever the held-back frames say
            asked = config.budget_start // self.ranks.world  # this GPU's share
            start = max(asked, pipeline.model.num_points)
            self.budget = HeldBackBudget(start, max(start, config.budget_limit // self.ranks.world))
            pipeline.model.start_budget(start)
            if start > asked and self.ranks.rank == 0:
                CONSOLE.log(f"Gaussian budget: starts at the model's {start:,} seed points (over budget_start)")
        # the held-back frames decide the view term (one GPU: the probe's training renders are not collective)
        self.decides_view_term = (
            config.decide_view_term
            and self._scores_settled_model
            and pipeline.model.has_view_term()
            and not self.ranks.split
        )
        self.view_verdict: Optional[ViewTermVerdict] = None

    @classmethod
    def start(cls, config: AutoStopConfig, pipeline, optimizers, run_dir: Path, steps_asked: int):
        """Hold the scoring frames back and return the run's stop; None where it is off or the
        capture has too few frames (said on the console)."""
        datamanager = pipeline.datamanager
        if not config.enabled or not isinstance(datamanager, ThermalDatamanager):  # it holds frames back
            return None
        images = held_back_images(len(datamanager.train_dataset), config.held_back_frames)
        if not images:
            CONSOLE.log(
                f"automatic stop off: {len(datamanager.train_dataset)} training images are too few to hold "
                f"{config.held_back_frames} back"
            )
            return None
        datamanager.hold_back(images)
        run = cls(config, pipeline, optimizers, run_dir, steps_asked)
        CONSOLE.log(f"automatic stop: capture frames {run.held_back_frames} are held back from training to score it")
        if run.decides_view_term:
            pipeline.model.try_view_term()
            CONSOLE.log(
                "view term: on trial (every other training step) until the held-back frames decide it "
                f"at {verdict_check(config.view_trial_checks)}"
            )
        elif config.decide_view_term:
            CONSOLE.log(
                "[yellow]--auto-stop.decide-view-term: nothing to decide (the model has no view term: "
                "--pipeline.model.view-sh-degree 0, or training across GPUs)"
            )
        return run

    @property
    def held_back_frames(self) -> List[int]:
        """The capture positions of the frames held back to score the run."""
        datamanager = self.pipeline.datamanager
        return [datamanager.train_dataset.frame_index(k) for k in datamanager.held_back]

    def state_path(self, kind: str, step: int, run: Optional[Path] = None) -> Path:
        """Where a state of step `step` is kept beside the run's config (this run's, or `run`'s):
        'best', the best-scoring model so far, which a resumed run can still go back to; 'trained',
        the state trained last when the final checkpoint holds the best one instead."""
        rank = f"-rank{self.ranks.rank}" if self.ranks.split else ""  # each rank's share of the Gaussians
        return (run or self.run_dir) / "auto_stop" / f"{kind}-{step:09d}{rank}.pt"

    def resume(self, run: Path, start_step: int) -> None:
        """Continue the automatic stop of the run being resumed: its checks before the checkpoint,
        replayed, and its best model so far. Where that run ended by keeping its best model, the
        training goes on from the state it had trained, not from the kept one."""
        record_path = run / "auto_stop.json"
        if not record_path.is_file():
            return
        record = json.loads(record_path.read_text())
        ended_on_kept = record.get("kept_step") not in (None, record["last_step"])
        if ended_on_kept and record["last_step"] == start_step - 1:
            trained = self.state_path("trained", record["last_step"], run)
            if trained.is_file():
                state = torch.load(trained, map_location=self.pipeline.device, weights_only=True)
                restore(self.pipeline, self.optimizers, state)
                self.pipeline.model.step = start_step
            else:
                CONSOLE.log(f"[yellow]automatic stop: {trained} is gone: training goes on from the kept model")
        raised_at = {r["step"] for r in record.get("budget_raises", [])}
        for check in record["checks"]:
            if check["step"] < start_step:
                self.progress.update(check["step"], check["psnr"])
                if "gaussians" in check:
                    self.check_counts[check["step"]] = check["gaussians"]
                if check["step"] in raised_at:
                    self.progress.restart()
        verdict = record.get("view_term")
        if self.decides_view_term and verdict is not None and verdict["step"] < start_step:  # decided before
            self.view_verdict = ViewTermVerdict(**verdict)
            self.pipeline.model.use_view_term(self.view_verdict.kept)
        raises = [(r["step"], r["budget"]) for r in record.get("budget_raises", []) if r["step"] < start_step]
        if self.budget is not None and "budget_start" in record:  # the run's own start, not the checkpoint's size
            self.budget.start = record["budget_start"]
            self.pipeline.model.start_budget(self.budget.start)
        if self.budget is not None and raises:  # the budget the run had reached
            self.budget.raises = raises
            self.pipeline.model.raise_budget(raises[-1][1])
        best = self.progress.best_step
        if best is not None and self.config.keep_best:
            path = self.state_path("best", best, run)
            if path.is_file():
                self._best = torch.load(path, map_location=self.pipeline.device, weights_only=True)
            else:
                CONSOLE.log(f"[yellow]automatic stop: {path} is gone: the model of step {best} can no longer be kept")

    def check(self, step: int) -> bool:
        """Score the held-back frames after `step`; True the first time the scores have plateaued
        (training must stop). No score before the schedule's start-up is over (the model's
        `settled_step`: full resolution, first opacity reset)."""
        self.last_step = step
        if self._scores_settled_model and step < self.pipeline.model.settled_step:
            return False
        this_check = len(self.progress.history) + 1  # scored checks so far, a resumed run's replayed ones too
        if self.decides_view_term and self.view_verdict is None and this_check >= self.config.view_trial_checks:
            score = self._decide_view_term(step)
        else:
            score = self.ranks.from_rank_0(held_back_score(self.pipeline, self.pipeline.datamanager.held_back))
        improved = self.progress.update(step, score)
        self.check_counts[step] = self.pipeline.model.num_points  # the held-back score's model size (this GPU's)
        if self.budget is not None and self.progress.plateaued and self._grow_budget(step):
            self.progress.restart()  # a larger model to score: the plateau rule starts over
        if improved and self.config.keep_best:
            self._best = None  # the older copy goes before the new one is made
            best = self._best = snapshot(self.pipeline, self.optimizers, step)
            write_atomically(self.state_path("best", step), lambda tmp: torch.save(best, tmp), self.partial_dir)
        stops = self.progress.plateaued and self.stop_reason is None
        if stops:
            self.stop_reason = self.progress.reason(self.config.check_every)
            CONSOLE.log(f"[bold]step {step}: training stops: {self.stop_reason}")
        self.write_record(kept=None)
        return stops

    def _decide_view_term(self, step: int) -> float:
        """The held-back frames' verdict on the view term on trial (`judge_view_term`), applied to the
        model; the held-back score (`held_back_score`) of the model it leaves."""
        pipeline, held_back = self.pipeline, self.pipeline.datamanager.held_back
        # scored with a radial fall-off fitted to each frame: a term that only mimics the camera's
        # vignetting (the same in every frame, so in the held-back ones too) gains nothing there
        verdict = judge_view_term(
            pipeline.model,
            lambda: held_back_score(pipeline, held_back, radial=True),
            lambda: scene_renders(pipeline, share_images(len(pipeline.datamanager.train_dataset), held_back)),
            self.config.min_improvement,
            self.config.view_max_radial_share,
            step,
        )
        self.view_verdict = verdict
        CONSOLE.log(f"step {step}: view term {'kept' if verdict.kept else 'off'}: {verdict.why()}")
        return held_back_score(pipeline, held_back)  # the plain score, as every check's

    def _grow_budget(self, step: int) -> bool:
        """Apply `HeldBackBudget` to this plateaued check (each rank to its share of the Gaussians);
        True where the budget grew."""
        model = self.pipeline.model
        count, budget = model.gaussian_budget()
        raised = self.budget.next_budget(self.progress.best_step, count, budget, model.densifies(step))
        # one decision for every rank (each counts its own share): rank 0's, as the score is
        raised = int(self.ranks.from_rank_0(float(raised or 0)))
        if raised == 0:
            return False
        self.budget.raised(step, raised)
        model.raise_budget(raised)
        if self.ranks.rank == 0:
            share = f" per GPU ({self.ranks.world})" if self.ranks.split else ""
            CONSOLE.log(
                f"step {step}: the held-back score plateaued with the model at its budget ({count:,} "
                f"Gaussians{share}): the budget grows to {raised:,}"
            )
        return True

    def forget_older_best(self) -> None:
        """After a checkpoint: a resume from it (or a later one) needs no best model older than the best so far."""
        best = self.progress.best_step
        if best is not None:
            for path in self.state_path("best", best).parent.glob("best-*.pt"):
                if int(path.stem.split("-")[1]) < best:
                    path.unlink(missing_ok=True)  # across GPUs another rank may have removed it

    def finish(self, step: int) -> None:
        """Before the final checkpoint of a run whose last trained step is `step`: keep the best
        model where it beat the last by `min_improvement`, and write the record."""
        self.last_step = step
        if self.decides_view_term and self.view_verdict is None:  # no scored check: the term is off, as reported
            self.pipeline.model.use_view_term(False)
        history = self.progress.history
        checked = bool(history) and history[-1][0] == step
        final = (
            history[-1][1]
            if checked
            else self.ranks.from_rank_0(held_back_score(self.pipeline, self.pipeline.datamanager.held_back))
        )
        kept = step
        if self._best is not None and self.progress.best > final + self.progress.min_improvement:
            # the state trained last, for a resume that goes on training (the final checkpoint holds the kept one)
            trained = snapshot(self.pipeline, self.optimizers, step)
            write_atomically(self.state_path("trained", step), lambda tmp: torch.save(trained, tmp), self.partial_dir)
            restore(self.pipeline, self.optimizers, self._best)
            self.pipeline.model.step = step  # splatfacto's load_state_dict sets it to 30000
            kept = self._best["step"]
            if self.budget is not None:  # the budget the kept model trained under: what the model reports and
                # follows (a view term that came in with a later raise trained nothing in it: it renders none)
                self.pipeline.model.start_budget(self.budget.budget_at(kept))
            CONSOLE.log(
                f"[bold]kept the model of step {kept} ({self.progress.best:.2f} dB on the held-back frames, "
                f"{final:.2f} at the end)"
            )
        self.kept_step = kept
        self.write_record(kept, final)

    def write_record(self, kept: Optional[int], final: Optional[float] = None) -> None:
        """auto_stop.json beside the run's config: the checks so far (a resumed run replays them)
        and, at the end, the model kept and why the run ended."""
        record = {
            "held_back_frames": self.held_back_frames,
            "steps_asked": self.steps_asked,
            "last_step": self.last_step,
            "stopped_early": self.stop_reason is not None,
            "reason": self.stop_reason,
            "kept_step": kept,
            "final_psnr": final,
            "checks": [dict(step=s, psnr=v, gaussians=self.check_counts.get(s)) for s, v in self.progress.history],
        }
        if self.view_verdict is not None:
            record["view_term"] = self.view_verdict.as_record()
        if self.budget is not None:  # per GPU across GPUs
            record["budget_start"] = self.budget.start
            record["budget_raises"] = [{"step": s, "budget": b} for s, b in self.budget.raises]
        if self.ranks.rank == 0:
            write_text_atomically(self.run_dir / "auto_stop.json", json.dumps(record, indent=1), self.partial_dir)
