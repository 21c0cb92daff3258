"""The photometric state of a frame, continuous in capture time, and rendering at a state.

A thermal frame's photometric condition (drift, flat-field jumps, gain) is modelled twice: by
its frame embedding (the emission and background MLPs) and, for preprocessed methods, by the LUT
that took its raw levels to the training space. state(t) = (embedding, LUT) at any capture
position t: a training frame's own at its index, between the neighbouring training frames in
between (the embedding linearly, the LUT through its inverse: `blend_luts`). No held-out pixel
enters a state: a held-out frame's state is predicted from its neighbours.

A state is named in the package's one grammar (`state_names.StateName`: `canonical`, `frame:N`,
`time:T`); `resolve_state` is where a name becomes an embedding (the model's) and a LUT (the
preprocessing's).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, Optional, Protocol, Tuple, Union, runtime_checkable

import numpy as np
import torch
from torch import Tensor

from thermal_wild_ns._upstream import training_state_kept
from thermal_wild_ns.errors import InputError
from thermal_wild_ns.pipeline.datamanager import ThermalDatamanager
from thermal_wild_ns.preprocessing.stage import PreprocessedSequence
from thermal_wild_ns.state_names import CANONICAL, StateName, at_time


@dataclass(frozen=True)
class PhotometricState:
    label: str
    """What the state is, for records ('canonical', 'frame:12', 'time:12.5', 'oracle:12', ...)."""
    embedding: Optional[Tensor]
    """Frame embedding [Df] to render with; None: the model has none (or keeps its own choice)."""
    lut: Optional[np.ndarray]
    """LUT [levels] from raw levels to the training space; None: frames are not preprocessed."""


@runtime_checkable
class FrameEmbeddingModel(Protocol):
    """A model whose renders depend on a frame embedding (`WildThermalModel`); any other (stock
    splatfacto) renders the same at every state and only the LUT changes."""

    uses_frame_embedding: bool

    def state_embedding(self, name: StateName) -> Tensor: ...


def preprocessed_sequence(pipeline) -> Optional[PreprocessedSequence]:
    """The training frames' LUTs (`PreprocessedSequence`); None where they were not preprocessed."""
    datamanager = pipeline.datamanager
    return datamanager.preprocessed if isinstance(datamanager, ThermalDatamanager) else None


def _model_embedding(model, name: StateName) -> Optional[Tensor]:
    if not (isinstance(model, FrameEmbeddingModel) and model.uses_frame_embedding):
        return None
    with torch.no_grad():
        return model.state_embedding(name).detach()


def canonical_state(pipeline) -> PhotometricState:
    """The state every novel view renders with (whatever the viewer shows)."""
    return resolve_state(pipeline, CANONICAL)


def state_at(pipeline, t: float) -> PhotometricState:
    """state(t) from the training frames around capture position `t`."""
    return resolve_state(pipeline, at_time(t))


def resolve_state(pipeline, name: Union[StateName, str]) -> PhotometricState:
    """The state a name stands for in this pipeline: the model's embedding, the preprocessing's LUT (the median
    training LUT for `canonical`, else the one interpolated at the position)."""
    name = StateName.parse(name) if isinstance(name, str) else name
    if name.kind == "frame":
        train = list(pipeline.datamanager.train_dataset.metadata["frame_indices"])
        if int(name.position) not in train:
            raise InputError(
                f"photometric state '{name}': frame {int(name.position)} is not a training frame (use "
                f"time:{int(name.position)} for its interpolated state)"
            )
    sequence = preprocessed_sequence(pipeline)
    lut = None
    if sequence is not None:
        lut = sequence.median_lut() if name.kind == "canonical" else sequence.lut_at(name.position)
    return PhotometricState(str(name), _model_embedding(pipeline.model, name), lut)


def to_original(pipeline, values: np.ndarray, state: PhotometricState) -> np.ndarray:
    """Training-space values -> the dataset-normalised original space at `state` (float32)."""
    if state.lut is None:
        return np.asarray(values, dtype=np.float32)
    return pipeline.datamanager.preprocessed.to_original_normalised(values, state.lut).astype(np.float32)


def to_training_space(pipeline, values: np.ndarray, state: PhotometricState) -> np.ndarray:
    """Original (dataset-normalised) values -> what the model trains on, at `state` (float32)."""
    if state.lut is None:
        return np.asarray(values, dtype=np.float32)
    return pipeline.datamanager.preprocessed.to_processed_normalised(values, state.lut).astype(np.float32)


def outputs_at(model, camera, state: PhotometricState, **kwargs) -> dict:
    """`model.get_outputs_for_camera(camera)` at `state`: its frame embedding passed to a model that
    has them (`WildThermalModel.get_outputs`), nothing to one that has none."""
    if state.embedding is not None:
        kwargs["frame_embedding"] = state.embedding
    return model.get_outputs_for_camera(camera, **kwargs)


def thermal_output(outputs: dict) -> Tensor:
    """[H, W, 1] training-space render of any model (grey mean of RGB for RGB models)."""
    return outputs["thermal"] if "thermal" in outputs else outputs["rgb"].mean(dim=-1, keepdim=True)


def as_recorded(model, thermal: Tensor, camera) -> Tensor:
    """A render `thermal` [H, W, 1] of `camera` through the camera's own fall-off where the model fits
    one (`WildThermalModel.as_recorded`): what is compared with a recorded frame. Unchanged otherwise."""
    return model.as_recorded(thermal, camera) if hasattr(model, "as_recorded") else thermal


def render(pipeline, camera, state: PhotometricState, recorded: bool = True) -> Tuple[np.ndarray, np.ndarray]:
    """One view at `state`: ([H, W] training space, [H, W] original space), float32 numpy; through
    the camera's own fall-off (`as_recorded`) unless `recorded` is False (compared with a generated
    scene's clean truth, which no camera recorded).

    The one render every scorer and command compares with a frame (the automatic stop, the
    evaluation protocols, the demo's panels): always as outside training, whatever mode the model is
    in, so at the camera's own resolution (the geometry of `ThermalDataset.recorded_image`, never
    the warm-up's coarser training resolution), over the baked background, with no densification
    statistics. The model's training mode and its record of the last training render (`info`,
    `last_size`, which the densification after a training step reads) are left as they were."""
    layers = render_layers(pipeline, camera, state, recorded=recorded)
    return layers["training"], layers["original"]


def render_layers(pipeline, camera, state: PhotometricState, recorded: bool = False) -> Dict[str, np.ndarray]:
    """`render` ('training', 'original'), with the Gaussians' 'coverage' of each pixel ([H, W]
    accumulated opacity, 0..1; ones for a model without it: where it is low the pixel is the
    background model, not the scene) and their 'depth' ([H, W] along the camera's axis, the
    model's units; NaN for a model without it). `recorded`: through the camera's own fall-off
    (`as_recorded`), for a comparison with a recorded frame; else the scene (the exports)."""
    model = pipeline.model
    was_training = model.training
    model.eval()
    try:
        with torch.no_grad(), training_state_kept(model):
            outputs = outputs_at(model, camera, state)
            thermal = thermal_output(outputs)  # [H, W, 1]
            if recorded:
                thermal = as_recorded(model, thermal, camera)
            rendered = thermal[..., 0].float().cpu().numpy()  # [H, W]
            alpha, depth = outputs.get("accumulation"), outputs.get("depth")
            coverage = np.ones_like(rendered) if alpha is None else alpha[..., 0].float().cpu().numpy()
            depth = np.full_like(rendered, np.nan) if depth is None else depth[..., 0].float().cpu().numpy()
    finally:
        model.train(was_training)
    original = to_original(pipeline, rendered, state)
    return {"training": rendered, "original": original, "coverage": coverage, "depth": depth}


def check_same_geometry(pred: np.ndarray, frame: np.ndarray, what: str) -> None:
    """A render and the frame it is scored against must be the same pixels: a clear error naming the
    frame where they are not (a bug of the caller, never of the data)."""
    if pred.shape != frame.shape:
        raise ValueError(
            f"{what}: the render is {pred.shape[1]}x{pred.shape[0]} but the frame {frame.shape[1]}x"
            f"{frame.shape[0]}; both must come from `render` and `recorded_image`"
        )
