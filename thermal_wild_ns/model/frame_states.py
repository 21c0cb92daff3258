"""The photometric states the model knows: the per-frame embeddings of its training frames, along
their capture positions, and the states derived from them (the canonical one, one at any capture
time). The embeddings themselves stay the model's parameter (`frame_embed`, in its checkpoints);
this owns what is computed from them, and the one cache of it."""

from __future__ import annotations

import time
from typing import Callable, Dict, List, Literal, Optional, Sequence

import torch
from torch import Tensor, nn

from thermal_wild_ns.preprocessing.photometric import time_weights
from thermal_wild_ns.state_names import StateName

Emission = Callable[[Tensor], Tensor]
"""A frame embedding [Df] -> the emissions [N] it gives some Gaussians."""
CanonicalEmbedding = Literal["typical", "mean"]
"""How the canonical state's embedding is made from the training frames' (`FrameStates.embedding`)."""


class FrameStates:
    """Frame embeddings [Df] from `embeddings` (one row per training image) at capture positions
    `frame_times` (one per row). A state's embedding (`embedding`) is kept outside autograd until the
    embeddings change."""

    def __init__(self, embeddings: nn.Embedding, frame_times: Sequence[float]):
        self.embeddings = embeddings
        self.frame_times: List[float] = [float(t) for t in frame_times]
        self._cache: Dict[tuple, tuple] = {}  # (name, canonical) -> ((step, version), weight, embedding)
        self._viewer: Optional[tuple] = None  # ((name, canonical), step it was computed at, embedding): `for_viewer`
        self._viewer_step = (-1, 0.0)  # the step of the viewer's last render, and when a render first saw it
        # each row with a training frame on either side (rows in capture order, as `at` reads them):
        # (row, left, right, weight of right)
        rows = range(len(self.frame_times))
        triples = [
            (row, row - 1, row + 1, (self.frame_times[row] - self.frame_times[row - 1]) / span)
            for row in rows[1:-1]
            if (span := self.frame_times[row + 1] - self.frame_times[row - 1]) > 0
        ]
        self._neighbours = (
            torch.tensor([t[:3] for t in triples], dtype=torch.long).reshape(-1, 3),  # [M, 3]
            torch.tensor([t[3] for t in triples], dtype=torch.float32).reshape(-1, 1),  # [M, 1]
        )

    def at(self, t: float, without: Sequence[int] = ()) -> Tensor:
        """The frame embedding [Df] at capture position `t`: linear between the neighbouring
        training frames' embeddings, exactly a training frame's own at its position. `without`:
        rows not to interpolate from."""
        left_out = set(without)
        rows = [k for k in range(len(self.frame_times)) if k not in left_out]
        i, j, w = time_weights([self.frame_times[k] for k in rows], t)
        weight = self.embeddings.weight  # [F, Df]
        return weight[rows[i]] if w == 0.0 else (1.0 - w) * weight[rows[i]] + w * weight[rows[j]]

    def neighbour_residual(self) -> Tensor:
        """[] the mean, over the training frames with a training frame on either side in capture time, of
        the squared distance (per dimension) between a frame's embedding and the state its two neighbours
        predict for it, linear in time (`at(t, without=[row])`, for every such row at once): what the
        `time` protocol does for a held-out frame. Zero with fewer than three frames. A penalty on it
        (`state_smoothness`) keeps the states predictable."""
        weight = self.embeddings.weight  # [F, Df]
        rows, towards_right = self._neighbours  # [M, 3], [M, 1]
        if rows.device != weight.device:  # moved once, not copied from the host at every step
            self._neighbours = rows, towards_right = rows.to(weight.device), towards_right.to(weight.device)
        if rows.shape[0] == 0:
            return weight.sum() * 0.0
        predicted = (1.0 - towards_right) * weight[rows[:, 1]] + towards_right * weight[rows[:, 2]]  # [M, Df]
        return (weight[rows[:, 0]] - predicted).square().mean()

    def fill_from_neighbours(self, rows: Sequence[int]) -> None:
        """Set the embeddings of `rows` (training images that take no gradient) to the state
        interpolated from the other training frames around them."""
        with torch.no_grad():
            for row in rows:
                self.embeddings.weight[row] = self.at(self.frame_times[row], without=rows)

    def embedding(
        self,
        name: StateName,
        canonical: CanonicalEmbedding,
        step: int,
        emission_of: Optional[Callable[[], Optional[Emission]]] = None,
    ) -> Tensor:
        """The frame embedding [Df] the state `name` stands for, kept outside autograd until the embeddings change
        (`step`: fused Adam does not bump tensor versions). `canonical` defines the canonical state: 'typical'
        (`typical_state`, which asks `emission_of` for the emission it matches, only when it computes; where there
        is none, no emission MLP, the state does not change the Gaussians and it is the mean) or 'mean'. A frame's
        and a capture time's: `at` its position."""
        weight = self.embeddings.weight  # [F, Df]
        key, when = (name, canonical), (step, weight._version)
        cached = self._cache.get(key)
        if cached is not None and cached[0] == when and cached[1] is weight:
            return cached[2]
        if name.kind != "canonical":
            value = self.at(name.position)
        elif canonical == "typical":
            emission = None if emission_of is None else emission_of()
            value = weight.mean(dim=0) if emission is None else typical_state(weight.detach(), emission)
        elif canonical == "mean":
            value = weight.mean(dim=0)
        else:
            raise ValueError(f"canonical_embedding must be 'typical' or 'mean', got {canonical!r}")
        if not torch.is_grad_enabled():
            self._cache = {k: v for k, v in self._cache.items() if v[0] == when and v[1] is weight}  # this step's
            self._cache[key] = (when, weight, value)
        return value

    def for_viewer(
        self,
        name: StateName,
        canonical: CanonicalEmbedding,
        step: int,
        emission_of: Optional[Callable[[], Optional[Emission]]] = None,
    ) -> Tensor:
        """`embedding(name, ...)` for the viewer's renders, which come whenever its user moves while a run
        trains: the 'typical' canonical state is a fit of its own (`typical_state`), and refitting it at every
        render of a training run would take that time from the training steps. So while the step moves the
        viewer keeps its typical state for up to `VIEWER_REFIT_STEPS` steps; once the step has stood still for
        `VIEWER_PAUSE_SECONDS` (training paused or done) it is the exact state of that step again. Other states
        cost no fit and are always exact."""
        cached = self._viewer
        now = time.monotonic()
        if step != self._viewer_step[0]:
            self._viewer_step = (step, now)
        paused = now - self._viewer_step[1] >= VIEWER_PAUSE_SECONDS
        choice = (name, canonical)
        lagging = cached is not None and cached[0] == choice and name.kind == "canonical" and canonical == "typical"
        if lagging and not paused and 0 < step - cached[1] < VIEWER_REFIT_STEPS:
            return cached[2]
        value = self.embedding(name, canonical, step, emission_of)  # at the same step, `embedding`'s cache answers
        self._viewer = (choice, step, value)
        return value


VIEWER_REFIT_STEPS = 500
"""Training steps the viewer's canonical state may lag behind a run that is training (`for_viewer`)."""
VIEWER_PAUSE_SECONDS = 1.0
"""How long the step must stand still before the viewer takes it for a run that no longer trains."""


def typical_state(states: Tensor, emission: Emission, steps: int = 100) -> Tensor:
    """The single photometric state that renders a capture's Gaussians as its training frames do on
    average: the embedding e [Df] minimising the expected squared emission error over the training
    frames' states `states` [F, Df], sum_i E_t (c_i(e) - c_i(e_t))^2 = sum_i (c_i(e) - mean_t c_i(e_t))^2
    + a term no single state changes, where `emission(e)` gives the emissions c(e) [N] (weighted as
    the caller wants). The mean embedding is that state only where the emission is linear in it; here
    Adam minimises the first term from the mean embedding (the emission's parameters get no gradient).
    Defined in docs/design.md ("The canonical state")."""
    with torch.no_grad():
        target = torch.stack([emission(e) for e in states]).mean(dim=0)  # [N]
    start = states.mean(dim=0)
    spread = float(states.std(dim=0).mean()) if states.shape[0] > 1 else 0.0
    if spread == 0.0:
        return start
    state = start.clone().requires_grad_(True)
    optimizer = torch.optim.Adam([state], lr=0.05 * spread)
    with torch.enable_grad():
        for _ in range(steps):
            loss = (emission(state) - target).square().mean()
            (grad,) = torch.autograd.grad(loss, state)
            state.grad = grad
            optimizer.step()
    return state.detach()
