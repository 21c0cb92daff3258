"""What each Gaussian emits toward a camera under a photometric state: its scalar base, plus the emission MLP
of its embedding and the frame's (`fields.EmissionMLP`), plus the view-dependent term where it renders
(`view_emission.py`), clamped at zero where radiance must not be negative. One way per render mode: a training
step's (the MLP's forward and backward replayed as CUDA graphs), the Gaussians a camera can see (large scenes),
one channel per GPU (the Gaussians split across GPUs), and outside training (baked: the MLP evaluated once per
state and parameter state). State passes in: the Gaussians' parameters `params` (the model's `gauss_params`)."""

from __future__ import annotations

from typing import Callable, Optional

import torch
from torch import Tensor

from thermal_wild_ns.model.bake import BakedValues
from thermal_wild_ns.model.fields import EmissionMLP
from thermal_wild_ns.model.graphed import PaddedRowCalls
from thermal_wild_ns.model.in_view import in_view, in_views
from thermal_wild_ns.model.view_emission import view_term

TYPICAL_STATE_GAUSSIANS = 16_384
"""Gaussians the 'typical' canonical state is fitted on (`GaussianEmission.typical`)."""

BAKE_ROWS = 1 << 22
"""Gaussians per evaluation of the emission MLP when its output is baked (`GaussianEmission.baked`)."""


class GaussianEmission:
    """The emission of the Gaussians in `params` [N, 1] under a frame embedding `frame_embed` [Df]: `mlp` (None:
    the base alone, the 3DGS baseline) replayed as CUDA graphs in training where `graphed`; radiance clamped at
    zero where `nonnegative`. `view_term`: whether the render adds the view-dependent term (the growth policy's
    answer), seen from `camera_position` [3]."""

    def __init__(self, mlp: Optional[EmissionMLP], graphed: bool, nonnegative: bool):
        self.mlp = mlp
        # its rows follow the Gaussian count, which moves on at every densification
        self.graphed = PaddedRowCalls("emission MLP") if graphed and mlp is not None else None
        self.baked_values = BakedValues()
        self.nonnegative = nonnegative

    # ------------------------------------------------------------------ the four ways
    def training_radiance(
        self, params, frame_embed: Tensor, camera_position: Tensor, view_term: bool, slot: int = 0
    ) -> Tensor:
        """Every Gaussian's radiance [N, 1] in a training step (`slot`: the camera's place among the step's
        cameras, whose recordings are its own)."""
        base = params["emission"]  # [N, 1]
        if self.mlp is None:
            emission = base
        elif self.graphed is not None and torch.is_grad_enabled():
            emission = self.graphed(self.mlp, (base, params["gauss_embed"]), (frame_embed,), slot=slot)
        else:
            emission = self.mlp(base, params["gauss_embed"], frame_embed)
        return self.radiance(self._with_view_term(emission, params, camera_position, view_term))

    def radiance_in_view(
        self,
        params,
        frame_embed: Tensor,
        viewmat: Tensor,
        K: Tensor,
        width: int,
        height: int,
        camera_position: Tensor,
        view_term: bool,
    ) -> Tensor:
        """The radiance [N, 1] of the Gaussians the camera (gsplat's `viewmat` [4, 4], `K` [3, 3]) can see
        (`in_view`), zero for the others (which it does not draw): memory and time that follow the frame."""
        means = params["means"]
        seen = in_view(means, params["scales"], viewmat, K, width, height).nonzero().squeeze(-1)  # [M]
        values = self.selected(params, frame_embed, seen)  # [M, 1]
        if view_term:
            values = values + view_term_of(params, camera_position, seen)
        return self.radiance(values.new_zeros(means.shape[0], 1).index_copy(0, seen, values))

    def radiance_per_rank(self, params, embeddings: Tensor, views: Tensor, width: int, height: int, view_term: bool):
        """This GPU's Gaussians' radiance [N, W] as every GPU's camera of the step sees them (gsplat's distributed
        rasterization takes per-Gaussian colours only; each GPU keeps its own channel): channel s at the frame
        embedding `embeddings[s]` [W, Df], for the Gaussians GPU s's camera can see; `views` [W, 29] each GPU's
        training image, camera position, world-to-camera [4, 4] and intrinsics [3, 3], flattened."""
        channels = []
        for s in range(views.shape[0]):
            viewmat, K = views[s, 4:20].reshape(4, 4), views[s, 20:29].reshape(3, 3)
            channels.append(
                self.radiance_in_view(params, embeddings[s], viewmat, K, width, height, views[s, 1:4], view_term)
            )
        return torch.cat(channels, dim=-1)

    def rendered_radiance(
        self, params, frame_embed: Tensor, step: int, camera_position: Tensor, view_term: bool, ids=None
    ) -> Tensor:
        """The radiance [N, 1] of every (or the selected `ids`) Gaussian of a render outside training and autograd:
        the emission baked (`baked`)."""
        emission = self.baked(params, frame_embed, step)
        emission = emission if ids is None else emission[ids]
        return self.radiance(self._with_view_term(emission, params, camera_position, view_term, ids))

    def exact_radiance(self, params, frame_embed: Tensor, camera_position: Tensor, view_term: bool, ids=None):
        """The radiance [N, 1] of every (or the selected `ids`) Gaussian of a render outside training under
        autograd (a fit through the render): the MLP itself."""
        emission = self.selected(params, frame_embed, ids)
        return self.radiance(self._with_view_term(emission, params, camera_position, view_term, ids))

    def exact_radiances(self, params, frame_embeds: Tensor, camera_positions: Tensor, view_term: bool, ids=None):
        """`exact_radiance` of several states at once: frame embeddings [B, Df], each seen from its camera position
        [B, 3] -> [B, N, 1] (or [B, M, 1] of `ids`), the MLP called once for all of them."""
        emission = self.selected(params, frame_embeds, ids)  # [B, N, 1], or [N, 1] without the MLP
        emission = emission.expand(frame_embeds.shape[0], -1, -1)
        if view_term:
            emission = emission + torch.stack([view_term_of(params, p, ids) for p in camera_positions])
        return self.radiance(emission)

    def seen_radiances(
        self,
        params,
        viewmats: Tensor,
        Ks: Tensor,
        width: int,
        height: int,
        positions: Tensor,
        view_term: bool,
        ids=None,
    ):
        """`exact_radiances` as a function of the frame embeddings [B, Df] -> [B, N, 1] (or [B, M, 1] of the crop
        box's `ids` [N] bool), for the Gaussians each camera (gsplat's `viewmats` [B, 4, 4], `Ks` [B, 3, 3], at
        `positions` [B, 3]) can see (`in_views`), zero for the others (which it does not draw): the MLP runs on the
        (camera, Gaussian) pairs drawn, a fit's time following its views, not the site. Which pairs, and their view
        term, are made once."""
        means, log_scales = params["means"], params["scales"]
        if ids is not None:
            means, log_scales = means[ids], log_scales[ids]
        views, seen = in_views(means, log_scales, viewmats, Ks, width, height).nonzero(as_tuple=True)  # [R] each
        rows = seen if ids is None else ids.nonzero().squeeze(-1)[seen]  # [R], among all the Gaussians
        base = params["emission"][rows]  # [R, 1]
        gauss_embed = params["gauss_embed"][rows] if self.mlp is not None else None  # [R, Dg]
        offset = view_term_of(params, positions[views], rows) if view_term else None  # [R, 1], each its camera's
        shape = (viewmats.shape[0], means.shape[0], 1)

        def radiances(frame_embeds: Tensor) -> Tensor:
            emission = base if self.mlp is None else self.mlp.rows(base, gauss_embed, frame_embeds[views])  # [R, 1]
            emission = emission if offset is None else emission + offset
            return self.radiance(emission.new_zeros(shape).index_put((views, seen), emission))

        return radiances

    # ------------------------------------------------------------------ pieces
    def selected(self, params, frame_embed: Tensor, ids: Optional[Tensor] = None) -> Tensor:
        """The emission [N, 1] (or [M, 1] of `ids`) without view term, evaluated as it stands ([B, N, 1] for
        frame embeddings [B, Df] with the MLP)."""
        base = params["emission"] if ids is None else params["emission"][ids]
        if self.mlp is None:
            return base
        embed = params["gauss_embed"] if ids is None else params["gauss_embed"][ids]
        return self.mlp(base, embed, frame_embed)

    def baked(self, params, frame_embed: Tensor, step: int) -> Tensor:
        """The emission [N, 1] without view term under `frame_embed`, kept until the embedding or any parameter it
        depends on changes (`BakedValues`; `step`: fused Adam does not bump versions): a viewer's render costs what
        plain splatting costs. Evaluated `BAKE_ROWS` Gaussians at a time: the hidden activations of a model of
        hundreds of millions at once would need more memory than the model."""
        base = params["emission"]
        if self.mlp is None:
            return base
        embed = params["gauss_embed"]
        tensors = (base, embed, *self.baked_values.parameters_of(self.mlp), frame_embed)

        def bake() -> Tensor:
            rows = range(0, embed.shape[0], BAKE_ROWS)
            parts = [self.mlp(base[i : i + BAKE_ROWS], embed[i : i + BAKE_ROWS], frame_embed) for i in rows]
            return parts[0] if len(parts) == 1 else torch.cat(parts)

        return self.baked_values.get("emission", tensors, step, bake)

    def radiance(self, emission: Tensor) -> Tensor:
        """What Gaussians send toward the camera [N, C] from their emission (view term included) [N, C]: clamped
        at zero with `nonnegative` (every render and export goes through this)."""
        return emission.clamp_min(0.0) if self.nonnegative else emission

    def typical(self, params) -> Optional[Callable[[Tensor], Tensor]]:
        """What the 'typical' canonical state matches (`frame_states.typical_state`): the emission of up to
        `TYPICAL_STATE_GAUSSIANS` Gaussians (a fixed draw) under a state [Df] -> [n], each weighted by its
        opacity (a faint Gaussian barely shows in a render). None without the emission MLP."""
        count = params["emission"].shape[0]
        if self.mlp is None or count == 0:
            return None
        g = torch.Generator(device="cpu").manual_seed(0)
        pick = torch.randperm(count, generator=g)[: min(count, TYPICAL_STATE_GAUSSIANS)].to(params["means"].device)
        base, embed = params["emission"][pick].detach(), params["gauss_embed"][pick].detach()  # [n, 1], [n, Dg]
        weight = torch.sigmoid(params["opacities"][pick].detach()).squeeze(-1)  # [n]
        return lambda state: self.mlp(base, embed, state).squeeze(-1) * weight

    @staticmethod
    def _with_view_term(emission: Tensor, params, camera_position: Tensor, on: bool, ids=None) -> Tensor:
        return emission + view_term_of(params, camera_position, ids) if on else emission


def view_term_of(params, camera_position: Tensor, ids: Optional[Tensor] = None) -> Tensor:
    """The view-dependent term [N, 1] (or [M, 1] of `ids`) of the Gaussians in `params` seen from
    `camera_position` [3] (or each from its own, [M, 3]: `view_emission.view_term`)."""
    means, coefficients = params["means"], params["view_sh"]
    if ids is not None:
        means, coefficients = means[ids], coefficients[ids]
    return view_term(means, coefficients, camera_position)
