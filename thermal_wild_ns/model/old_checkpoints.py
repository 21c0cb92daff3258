"""Runs saved by earlier versions of the model, read as today's: each conversion takes what such a run saved
(its config.yml, its checkpoint's state dict, its optimizers' states) to today's layout before it loads, or
says what the model must be to render as the run trained (`CheckpointParts`). Every conversion of an old
run lives here; the model applies them in `load_state_dict`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, Optional, Sequence, Tuple

import torch
from nerfstudio.utils.rich_utils import CONSOLE

from thermal_wild_ns.errors import InputError
from thermal_wild_ns.model.background import ThermalBackground
from thermal_wild_ns.model.camera_response import CameraResponse

MLP_NAMES = ("emission_mlp", "background_mlp")
"""The model's `PackedMLP` holders: `NAME.net` is the packed MLP."""


def migrate_config(config) -> None:
    """A config.yml written before `canonical_embedding` named the canonical state's embedding
    (`inference_embedding`, which took 'mean', 'typical', 'zero' or a training frame's index) set as today's.
    nerfstudio rebuilds a run's config from its YAML without the dataclass's constructor, so the old field
    arrives as a plain attribute beside today's default."""
    old = vars(config).pop("inference_embedding", None)
    if old is None:
        return
    if old not in ("typical", "mean"):
        raise InputError(
            f"this run's config.yml renders novel views at inference_embedding {old!r}, which is no longer a canonical "
            "state: render its views with --photometric-state frame:N (a training frame's state), or set "
            "canonical_embedding: typical or mean in the config.yml"
        )
    config.canonical_embedding = old


def packed_mlp_state(state_dict: dict, prefix: str, shapes: Sequence[Tuple[int, int]]) -> dict:
    """`state_dict` with a `PackedMLP`'s layers saved one tensor each (as an `nn.Sequential`: `PREFIX0.weight`,
    `PREFIX0.bias`, `PREFIX2.weight`, ...; `shapes` its layers' weights [out, in]) as its one `PREFIXpacked`."""
    old = [f"{prefix}{2 * i}.{name}" for i in range(len(shapes)) for name in ("weight", "bias")]
    if prefix + "packed" in state_dict or not all(k in state_dict for k in old):
        return state_dict
    state_dict = dict(state_dict)
    state_dict[prefix + "packed"] = torch.cat([state_dict.pop(k).reshape(-1) for k in old])
    return state_dict


def packed_adam_state(state: dict, start: int, count: int) -> dict:
    """An Adam state dict (`Optimizer.state_dict()`, one param group) whose tensors `start` to `start + count`
    are an MLP's separate weights and biases, as saved before the MLP was a `PackedMLP`, with those tensors as
    one: their moments concatenated in `packed`'s order (Adam is elementwise: the same moments), the first
    one's step count; the group's tensors numbered on from its first. A tensor never stepped has no state (a
    checkpoint before the first step): where one of the layers has none, the packed tensor starts without."""
    (group,) = state["param_groups"]
    ids = group["params"]
    moments = [state["state"].get(i) for i in ids]  # None: no state
    layers = moments[start : start + count]
    packed = None
    if all(m is not None for m in layers):
        packed = {**layers[0]}
        for key in ("exp_avg", "exp_avg_sq"):
            packed[key] = torch.cat([m[key].reshape(-1) for m in layers])
    moments = moments[:start] + [packed] + moments[start + count :]
    renumbered = list(range(ids[0], ids[0] + len(moments)))
    kept = {i: m for i, m in zip(renumbered, moments) if m is not None}
    return {"state": kept, "param_groups": [{**group, "params": renumbered}]}


def packed_optimizer_states(states: dict, mlps: Dict[str, torch.nn.Module]) -> dict:
    """A checkpoint's optimizer states (optimizer name -> state dict) with the Adam state of each MLP in `mlps`
    (name -> its holder, whose `net` is a `PackedMLP`) saved before the packing, packed."""
    for name, mlp in mlps.items():
        if name not in states:
            continue
        parameters = list(mlp.parameters())
        count = 2 * len(mlp.net.shapes)  # the separate layers' weights and biases
        if len(states[name]["param_groups"][0]["params"]) == len(parameters) + count - 1:
            start = next(i for i, p in enumerate(parameters) if p is mlp.net.packed)  # the tensors before stay
            states = {**states, name: packed_adam_state(states[name], start, count)}
    return states


@dataclass(frozen=True)
class CheckpointParts:
    """What a checkpoint's state dict says of the model that saved it, where today's config may differ."""

    has_falloff: bool
    background_coupling: Optional[str]
    """How its background MLP took the frame embedding ('affine' or 'mlp'); None: it has no background MLP."""

    @classmethod
    def of(cls, state_dict: dict) -> "CheckpointParts":
        coupling = None
        if any(k.startswith("background_mlp.") for k in state_dict):
            coupling = "affine" if "background_mlp.frame_affine.weight" in state_dict else "mlp"
        return cls("camera_falloff" in state_dict, coupling)


def converted_state_dict(state_dict: dict, mlps: Dict[str, torch.nn.Module]) -> dict:
    """A model's state dict with every old layout converted (today: each MLP's layers as one tensor)."""
    for name, mlp in mlps.items():
        state_dict = packed_mlp_state(state_dict, f"{name}.net.", mlp.net.shapes)
    return state_dict


def match_checkpoint(model, saved: CheckpointParts) -> None:
    """`model` (a `WildThermalModel` about to load a checkpoint of the parts `saved`) made as the checkpoint's run
    trained it, where that run's config.yml cannot say so: a run from when the content-motion rule decided the
    camera model as a whole (it fitted no fall-off where it left the map out), and a run older than
    `background_frame_coupling` (its config.yml does not name the coupling it trained)."""
    if model.camera_falloff is not None and not saved.has_falloff and model.camera_choice.map_left_by_motion():
        model.camera_falloff, model.parts.camera = None, CameraResponse(graphed=False)
        choice = model.camera_choice
        choice.falloff = False
        choice.falloff_why = "the checkpoint's: trained when the content-motion rule decided the whole camera model"
        CONSOLE.log(f"camera fall-off off: {choice.falloff_why}")
    coupling, config = saved.background_coupling, model.config
    if model.background_mlp is None or coupling in (None, config.background_frame_coupling):
        return
    if model.training:  # a resume: the optimizers already hold this config's background parameters
        raise ValueError(
            f"checkpoint's background MLP couples the frame as {coupling!r}, this config as "
            f"{config.background_frame_coupling!r}: resume it with "
            f"--pipeline.model.background-frame-coupling {coupling}"
        )
    config.background_frame_coupling = coupling
    model.background_mlp = model.background_mlp_of(coupling).to(model.frame_embed.weight.device)
    model.parts.background = ThermalBackground(model.background_mlp, config)
    CONSOLE.log(f"background frame coupling {coupling!r}: the checkpoint's")
