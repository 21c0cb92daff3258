"""How large the model may grow and what comes with size: the Gaussian budget (which the automatic stop starts,
raises and GPU memory caps), the view-dependent term that waits for a large budget or a trial of the held-back
frames, and the prune of Gaussians few frames see. A policy whose state is passed in, as gsplat's strategies:
`GrowthPolicy` holds the config's rules, `GrowthState` what the run has decided so far; the densification
itself is the strategy's (`strategy.BudgetedDefaultStrategy`, whose `max_gaussians` is the budget)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import List, Literal, Optional

import torch
from nerfstudio.utils.rich_utils import CONSOLE
from torch import Tensor

from thermal_wild_ns.decisions import Decision
from thermal_wild_ns.errors import InputError
from thermal_wild_ns.model.in_view import few_view_mask
from thermal_wild_ns.model.strategy import BudgetedDefaultStrategy
from thermal_wild_ns.rendering import world_to_camera


@dataclass
class GrowthState:
    """What a run's growth has come to (`GrowthPolicy` reads and writes it)."""

    view_term: Literal["on", "off", "trial"]
    """Whether the view term takes part in renders (`use_view_term`, `try_view_term`)."""
    view_term_waits: bool = False
    """It waits for the Gaussian budget to pass `view_term_above_budget` (`follow_budget`)."""
    view_term_by_trial: bool = False
    """The held-back frames' trial decides it instead of the budget (`try_view_term`)."""
    few_view_pruned: int = 0
    """Gaussians the few-view prune removed so far (checkpointed: a resume counts the whole run's)."""
    growth_ceiling: Optional[int] = None
    """Where a training step ran out of GPU memory (`limit_growth`): no budget passes it."""


@dataclass
class GrowthPolicy:
    """The growth rules of a model config (`GrowthPolicy.of`), for a model split over `world` GPUs."""

    max_gaussians: int
    view_term_above_budget: Optional[int]
    view_term_from_step: int
    few_view_prune_frames: int
    few_view_prune_nearer: float
    few_view_prune_above_budget: Optional[int]
    has_view_term: bool
    """Whether the model was built with a view-dependent term (`view_sh_degree` > 0)."""
    world: int = 1
    rank: int = 0

    @classmethod
    def of(cls, config, world: int, rank: int) -> "GrowthPolicy":
        if config.few_view_prune_frames < 0 or config.few_view_prune_nearer < 0:
            raise InputError(
                f"few_view_prune_frames {config.few_view_prune_frames}, few_view_prune_nearer "
                f"{config.few_view_prune_nearer:g}: each must be 0 (off; at any distance) or more"
            )
        if config.few_view_prune_above_budget is not None and config.few_view_prune_above_budget < 0:
            raise InputError(
                f"few_view_prune_above_budget {config.few_view_prune_above_budget}: must be 0 or more (None: no rule)"
            )
        return cls(
            config.max_gaussians,
            config.view_term_above_budget,
            config.view_term_from_step,
            config.few_view_prune_frames,
            config.few_view_prune_nearer,
            config.few_view_prune_above_budget,
            config.view_sh_degree > 0,
            world,
            rank,
        )

    def initialize_state(self, strategy: BudgetedDefaultStrategy) -> GrowthState:
        state = GrowthState("on" if self.has_view_term else "off")
        self.follow_budget(state, strategy, step=0)  # the fixed budget's: a budget set later says so then
        return state

    # ------------------------------------------------------------------ the budget
    def budget_over_gpus(self, strategy: BudgetedDefaultStrategy) -> int:
        """The Gaussian budget densification applies now, over every GPU (each holds its share of it)."""
        return strategy.max_gaussians * self.world

    def start_budget(self, state: GrowthState, strategy: BudgetedDefaultStrategy, count: int, step: int) -> None:
        """Densification grows to `count` Gaussians (this GPU's) at most from now on, in place of `max_gaussians`."""
        strategy.max_gaussians = count
        self.follow_budget(state, strategy, step)

    def raise_budget(self, state: GrowthState, strategy: BudgetedDefaultStrategy, count: int, step: int) -> None:
        """Densification may grow to `count` Gaussians from now on, never past the growth ceiling."""
        ceiling = state.growth_ceiling
        strategy.max_gaussians = max(strategy.max_gaussians, count if ceiling is None else min(count, ceiling))
        self.follow_budget(state, strategy, step)

    @staticmethod
    def limit_growth(state: GrowthState, strategy: BudgetedDefaultStrategy, count: int) -> None:
        """Densification never grows past `count` Gaussians from now on (a step ran out of GPU memory there)."""
        strategy.max_gaussians = min(strategy.max_gaussians, count)
        state.growth_ceiling = count if state.growth_ceiling is None else min(state.growth_ceiling, count)

    # ------------------------------------------------------------------ the view term
    def renders_view_term(self, state: GrowthState, training: bool, step: int) -> bool:
        """Whether a render now adds the view term (in training not before `view_term_from_step`; in no render
        while the budget is below `view_term_above_budget`; on trial in odd training steps only)."""
        if state.view_term_waits or (training and step < self.view_term_from_step):
            return False
        if state.view_term == "trial":
            return training and step % 2 == 1
        return state.view_term == "on"

    @staticmethod
    def use_view_term(state: GrowthState, view_sh: Optional[Tensor], on: bool) -> None:
        """Whether the view term (coefficients `view_sh` [N, K]) takes part in renders from now on. Off: its
        coefficients are zeroed and get no gradient, so the model renders as one built without it."""
        if view_sh is None:
            raise ValueError("this model has no view term (view_sh_degree 0)")
        if not on:
            with torch.no_grad():
                view_sh.zero_()
        state.view_term = "on" if on else "off"

    @staticmethod
    def try_view_term(state: GrowthState, view_sh: Optional[Tensor]) -> None:
        """Put the view term on trial until `use_view_term` decides (the automatic stop's rule,
        `training/view_probe.py`): training renders alternate between with it (odd steps) and without it, so the
        Gaussians learn to render both ways; every render outside training leaves it out."""
        if view_sh is None:
            raise ValueError("this model has no view term (view_sh_degree 0)")
        state.view_term, state.view_term_waits, state.view_term_by_trial = "trial", False, True

    def view_term_follows_budget(self, state: GrowthState) -> bool:
        """Whether the Gaussian budget decides the view term (`view_term_above_budget`, no trial)."""
        return self.view_term_above_budget is not None and self.has_view_term and not state.view_term_by_trial

    def follow_budget(self, state: GrowthState, strategy: BudgetedDefaultStrategy, step: int) -> None:
        """The view term waits while the Gaussian budget (over every GPU) is at or below `view_term_above_budget`,
        and takes part once it passes it (said on the console during a run)."""
        if not self.view_term_follows_budget(state):
            return
        threshold = self.view_term_above_budget
        waits = self.budget_over_gpus(strategy) <= threshold
        if state.view_term_waits and not waits and step > 0 and self.rank == 0:
            CONSOLE.log(
                f"step {step}: the Gaussian budget passed {threshold:,}: the view-dependent emission "
                "term takes part from now on (view_term_above_budget)"
            )
        state.view_term_waits = waits

    def loaded(self, state: GrowthState, view_sh: Optional[Tensor]) -> None:
        """After a checkpoint loads: a term that waits but was trained (its run's budget passed the threshold)
        renders; a resumed run's automatic stop sets the budget it had reached, and the rule again, right after."""
        if state.view_term_waits and view_sh is not None and bool(view_sh.any()):
            state.view_term_waits = False

    # ------------------------------------------------------------------ the few-view prune
    def few_view_prune_runs(self, strategy: BudgetedDefaultStrategy) -> bool:
        """Whether the few-view prune takes part at densification rounds now (`few_view_prune_frames`, on one GPU,
        with a Gaussian budget above `few_view_prune_above_budget` where that is set)."""
        if self.few_view_prune_frames <= 0 or self.world > 1:
            return False
        threshold = self.few_view_prune_above_budget
        return threshold is None or self.budget_over_gpus(strategy) > threshold

    def prune_few_view(self, state: GrowthState, strategy, params, optimizers, strategy_state, step, views) -> None:
        """Remove the few-view Gaussians (`few_view_mask`) of the training frames rendered so far (`views`: each
        frame's view at the scale it last rendered at; the test is in the view's own pixels)."""
        if len(views) <= self.few_view_prune_frames:
            return  # too few frames rendered yet to tell a few-view Gaussian from any other
        poses = torch.cat([v.camera_to_world for v in views])  # [F, 3, 4]
        viewmats = torch.cat([world_to_camera(v.camera_to_world) if v.viewmat is None else v.viewmat for v in views])
        Ks = torch.cat([v.K for v in views])  # [F, 3, 3]
        sizes = [(v.width, v.height) for v in views]
        mask = few_view_mask(
            params["means"].detach(),
            params["scales"].detach(),
            viewmats,
            Ks,
            sizes,
            poses[:, :, 3],
            self.few_view_prune_frames,
            self.few_view_prune_nearer,
        )
        state.few_view_pruned += strategy.prune_where(params, optimizers, strategy_state, mask, step)

    # ------------------------------------------------------------------ what it decided
    def budget_decisions(self, strategy: BudgetedDefaultStrategy, count: int) -> List[Decision]:
        """The model's size for this run, and why (`training/decisions.py`)."""
        share = f" (this GPU's share of {self.world})" if self.world > 1 else ""
        budget = strategy.max_gaussians  # this GPU's, as densification applies it now (raises: the stop's entry)
        entries: List[Decision] = [
            Decision(
                "Gaussians",
                f"{count:,} now{share}, at most {budget:,}",
                f"max_gaussians {self.max_gaussians:,}",
                "config",
            )
        ]
        if strategy.memory_stopped_at is not None:
            why = f"GPU memory: growth stopped at {strategy.memory_stopped_at:,}{share}"
            entries.append(Decision("Gaussians", "capped by GPU memory", why, "data"))
        return entries

    def part_decisions(self, state: GrowthState, strategy: BudgetedDefaultStrategy, view_degree: int):
        """Whether the few-view prune and the view term take part, and why (`training/decisions.py`)."""
        entries: List[Decision] = []
        over_gpus = self.budget_over_gpus(strategy)
        if self.few_view_prune_frames > 0:
            nearer = (
                f", nearer than {self.few_view_prune_nearer:g} x the median" if self.few_view_prune_nearer > 0 else ""
            )
            why = f"few_view_prune_frames {self.few_view_prune_frames}{nearer}"
            if self.few_view_prune_above_budget is not None:
                why += f"; few_view_prune_above_budget {self.few_view_prune_above_budget:,}, the budget {over_gpus:,}"
            if self.few_view_prune_runs(strategy):
                choice = f"on: {state.few_view_pruned:,} removed so far"
            else:
                choice = "off across GPUs" if self.world > 1 else "waits for a larger Gaussian budget"
                choice += f" ({state.few_view_pruned:,} removed so far)" if state.few_view_pruned else ""
            entries.append(Decision("few-view prune", choice, why, "config"))
        view = f"view_sh_degree {view_degree}"
        if self.view_term_follows_budget(state):
            view += f"; view_term_above_budget {self.view_term_above_budget:,}, the Gaussian budget {over_gpus:,}"
        on = view_degree > 0 and not state.view_term_waits
        entries.append(Decision("view-dependent emission", "on" if on else "off", view, "config"))
        return entries
