"""The automatic stop's decisions alone, on the held-back frames' scores (`auto_stop.py` runs them): whether the
scores have stopped improving (`PlateauRule`) and whether a plateau at the Gaussian budget asks for a larger one
(`HeldBackBudget`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple


@dataclass
class PlateauRule:
    """Whether a run's scores have stopped improving. `update` takes one score per check."""

    patience: int
    min_improvement: float
    best: float = -math.inf
    best_step: Optional[int] = None
    since_best: int = 0
    history: List[Tuple[int, float]] = field(default_factory=list)

    def update(self, step: int, score: float) -> bool:
        """Record the score of `step`; True when it is a new best (worth keeping)."""
        self.history.append((step, float(score)))
        if math.isfinite(score) and score > self.best + self.min_improvement:
            self.best, self.best_step, self.since_best = float(score), step, 0
            return True
        self.since_best += 1
        return False

    @property
    def plateaued(self) -> bool:
        return self.since_best >= self.patience

    def restart(self) -> None:
        """Count the checks without an improvement from zero again (the model changed: a raised budget)."""
        self.since_best = 0

    def reason(self, check_every: int) -> str:
        return (
            f"the held-back frames' PSNR has not risen by {self.min_improvement:g} dB in {self.patience} checks "
            f"({self.patience * check_every} steps); best {self.best:.2f} dB at step {self.best_step}"
        )


@dataclass
class HeldBackBudget:
    """The Gaussian budget the held-back frames set (`AutoStopConfig.grow_budget`). At a check whose
    scores have plateaued, `next_budget` doubles it, up to `limit`, where the model is at it (`at_budget`
    of it or more), densification still runs, and the last raise (if any) was followed by a new best
    score; `raised` records the raise the run applied. A rising score is not asked about: in a growing
    model it rises with the steps alone, so only a plateau at the budget says the budget, not the
    training time, holds the model back."""

    start: int
    """The budget the run started from (this GPU's)."""
    limit: int
    at_budget: float = 0.9
    raises: List[Tuple[int, int]] = field(default_factory=list)
    """(step, new budget) of every raise so far."""

    def next_budget(self, best_step: Optional[int], count: int, budget: int, densifies: bool) -> Optional[int]:
        """The budget after a plateaued check (`count` Gaussians, budget `budget`, the best score so far
        at `best_step`), where it grows; else None (the run stops). `raised` records a raise."""
        last_raise_gained = not self.raises or (best_step is not None and best_step > self.raises[-1][0])
        if not densifies or not last_raise_gained or count < self.at_budget * budget or budget >= self.limit:
            return None
        return min(2 * budget, self.limit)

    def raised(self, step: int, budget: int) -> None:
        """Record that the check of `step` raised the budget to `budget`."""
        self.raises.append((step, budget))

    def best_per_budget(self, history: List[Tuple[int, float]]) -> List[Tuple[int, float]]:
        """(budget, the best held-back score of the checks made under it) for each budget the run has had,
        from `history`'s (step, score) checks: a raising check's score belongs to the budget it raised."""
        best: Dict[int, float] = {}
        for step, score in history:
            if math.isfinite(score):
                budget = self.budget_at(step)
                best[budget] = max(best.get(budget, -math.inf), score)
        return sorted(best.items())

    def budget_at(self, step: int) -> int:
        """The budget the model trained under up to the check of `step` (a raise there counts after it)."""
        return next((b for s, b in reversed(self.raises) if s < step), self.start)
