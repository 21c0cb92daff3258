"""One choice a run made and why (`Decision`): the parts of the package that choose (the datamanager's
preprocessing, the model's budget and parts, the trainer's automatic stop) each say theirs in this
form, and the trainer reports them together (`training/decisions.py`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal


@dataclass(frozen=True)
class Decision:
    part: str
    choice: str
    why: str
    decided_by: Literal["data", "config"]
    """'data': a rule measured on this capture chose; 'config': a default or the user's option did."""
