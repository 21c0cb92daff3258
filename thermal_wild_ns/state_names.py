"""The names of photometric states, the one grammar every command reads (`--photometric-state` of
`wild-thermal-render`, `ns-eval`'s protocols, the viewer, the exports):

- `canonical`: one fixed state for novel views (the model's canonical embedding, the median training LUT);
- `frame:N`: training frame N's own state (N its capture index);
- `time:T`: the state at capture position T (a float; between training frames, interpolated).

What a name stands for in a trained run (an embedding and a LUT) is the pipeline's to resolve
(`pipeline/photometric_state.py`); the model answers for the embedding (`model/frame_states.py`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, Optional

from thermal_wild_ns.errors import InputError

StateKind = Literal["canonical", "frame", "time"]


@dataclass(frozen=True)
class StateName:
    kind: StateKind
    position: Optional[float] = None
    """The capture position of `frame` (a whole number) and `time`; None for `canonical`."""

    def __str__(self) -> str:
        if self.kind == "canonical":
            return "canonical"
        if self.kind == "frame":
            return f"frame:{int(self.position)}"
        return f"time:{self.position:g}"

    @classmethod
    def parse(cls, spec: str) -> "StateName":
        """'canonical', 'frame:N' or 'time:T'; an `InputError` saying what is expected otherwise."""
        kind, _, value = spec.partition(":")
        try:
            if kind == "canonical" and not value:
                return CANONICAL
            if kind == "frame":
                return cls("frame", float(int(value)))
            if kind == "time" and math.isfinite(position := float(value)):
                return cls("time", position)
        except ValueError:
            pass
        raise InputError(
            f"photometric state '{spec}': expected canonical, frame:N (a training frame's index) or time:T (a "
            "capture position)"
        )


CANONICAL = StateName("canonical")


def at_time(t: float) -> StateName:
    """The state at capture position `t`."""
    return StateName("time", float(t))
