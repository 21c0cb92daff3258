"""The camera model as a part of the thermal model: what it fits on this capture and why (`CameraChoice`), and
its response rendered into every image compared with a recorded frame (`CameraResponse`). The response's
mathematics is `camera_falloff.py`'s; its parameters stay the model's (`camera_falloff`, `camera_flat_field`, in
its checkpoints) and are passed in."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Dict, List, Optional, Sequence, Tuple

import torch
from nerfstudio.cameras.cameras import Cameras
from torch import Tensor

from thermal_wild_ns.decisions import Decision
from thermal_wild_ns.errors import InputError
from thermal_wild_ns.model.background import CameraFrameDirections
from thermal_wild_ns.model.camera_falloff import (
    describe_falloff,
    describe_flat_field,
    falloff_basis,
    respond,
    response_terms,
    through_terms,
)
from thermal_wild_ns.model.camera_views import host_sizes, intrinsics
from thermal_wild_ns.model.compositing import camera_planes, composite, over_background, thermal_outputs
from thermal_wild_ns.model.graphed import GraphedCalls


@dataclass
class CameraChoice:
    """Whether the camera's radial fall-off and its flat-field map are fitted on this capture, and why."""

    falloff: bool
    falloff_why: str
    flat_field: bool
    flat_field_why: str
    flat_field_decided_by: str  # 'config', or 'data': the capture's content motion

    @classmethod
    def of(cls, config, content_motion: Optional[float]) -> "CameraChoice":
        """The config's choice on a capture whose content moves `content_motion` across the sensor (the seed
        points' mean spread of image position, in frame sizes; None: no seed point is seen twice)."""
        if config.camera_flat_field < 0:
            raise InputError(f"camera_flat_field {config.camera_flat_field}: cells per image side, 0 (no map) or more")
        threshold = config.camera_pattern_min_motion
        if not config.camera_falloff or config.camera_flat_field == 0:
            why = "camera_flat_field 0" if config.camera_falloff else "no camera model (camera_falloff)"
            return cls(config.camera_falloff, "camera_falloff", False, why, "config")
        if threshold <= 0:
            return cls(True, "camera_falloff", True, f"camera_flat_field {config.camera_flat_field}", "config")
        if content_motion is None:
            why = "no seed point is seen in two frames: how far the content moves is unknown"
            return cls(True, "camera_falloff", False, why, "data")
        verdict = ">=" if content_motion >= threshold else "<: a fixed pattern is not told apart from the scene there"
        why = f"the content moves {content_motion:.2f} of the frame across the sensor ({verdict} {threshold:g})"
        return cls(True, "camera_falloff", content_motion >= threshold, why, "data")

    def map_left_by_motion(self) -> bool:
        """Whether the content-motion rule (not the config) left the flat-field map out."""
        return not self.flat_field and self.flat_field_decided_by == "data"

    def decisions(self, falloff: Optional[Tensor], flat_field: Optional[Tensor]) -> List[Decision]:
        """The fitted parts as a person reads them (the coefficients [2, K] and cells [2, n, n] where fitted)."""
        described = "off" if falloff is None else f"on: {describe_falloff(falloff)}"
        mapped = "off" if flat_field is None else f"on: {describe_flat_field(flat_field)}"
        return [
            Decision("camera fall-off", described, self.falloff_why, "config"),
            Decision("camera flat-field map", mapped, self.flat_field_why, self.flat_field_decided_by),
        ]


class CameraResponse:
    """A render as the camera records it, through the fitted fall-off `falloff` [2, K] and flat-field map
    `flat_field` [2, n, n] (None: none), the basis kept per camera and size; in training replayed as CUDA graphs
    where `graphed`."""

    def __init__(self, graphed: bool) -> None:
        self.basis = CameraFrameDirections(derive=falloff_basis)  # [H, W, K] per camera and size
        self.graphed = GraphedCalls("camera model") if graphed else None

    def recorded(
        self,
        falloff: Tensor,
        flat_field: Optional[Tensor],
        emission: Tensor,
        alpha: Tensor,
        background: Tensor,
        K: Tensor,
        pinhole: Tuple[float, float, float, float],
        slot: int = 0,
    ) -> Tensor:
        """A training render of a camera of intrinsics `K` [3, 3] (`pinhole`: its fx, fy, cx, cy on the host):
        gsplat's `emission` [H, W, 1] (premultiplied) and `alpha` [H, W, 1] over the `background` [H, W, 1],
        through the camera's response (`recorded_over_background`), one CUDA graph on a GPU; `slot`: the camera's
        place among a training step's cameras (`GraphedCalls`)."""
        height, width = emission.shape[:2]
        basis = self.basis(K, pinhole, width, height, 1)  # [H, W, K], kept
        inputs = (emission, alpha, background, falloff, basis)
        if flat_field is not None:
            inputs += (flat_field,)
        if self.graphed is not None and torch.is_grad_enabled():
            # the key: what besides the inputs' shapes picks the function, whether there is a map
            return self.graphed(len(inputs) == 6, recorded_over_background, *inputs, slot=slot)
        return recorded_over_background(*inputs)

    def outputs(
        self,
        falloff: Optional[Tensor],
        flat_field: Optional[Tensor],
        render: Tensor,
        alpha: Tensor,
        background: Tensor,
        K: Tensor,
        pinhole: Tuple[float, float, float, float],
        c: int,
    ) -> Dict:
        """The outputs of camera `c` of a training render (gsplat's render [C, H, W, 1(+1)], alpha [C, H, W, 1])
        over its `background` [H, W, 1], as the camera records it where the model fits a camera model (`falloff`
        not None), else as rendered."""
        if falloff is None:
            thermal, alpha, depth = composite(render, alpha, background, c)
        else:
            emission, alpha, depth = camera_planes(render, alpha, c)
            thermal = self.recorded(falloff, flat_field, emission, alpha, background, K, pinhole, c)
        return thermal_outputs(thermal, alpha, background, depth, None)

    def as_recorded(
        self, falloff: Optional[Tensor], flat_field: Optional[Tensor], thermal: Tensor, camera: Cameras
    ) -> Tensor:
        """A render `thermal` [H, W, 1] of `camera` (outside training: the scene) as the camera records it;
        unchanged without a camera model. For every image compared with a recorded frame
        (`pipeline.photometric_state.render`)."""
        if falloff is None:
            return thermal
        return through_terms(thermal, self.terms(falloff, flat_field, camera, *thermal.shape[:2]))

    def fixed(
        self, falloff: Optional[Tensor], flat_field: Optional[Tensor], cameras: Sequence[Cameras]
    ) -> Callable[[Tensor], Tensor]:
        """`as_recorded` for renders [B, H, W, 1] of `cameras` [B] (one size) at their full resolution, the
        response's terms made once: a fit calls it at every step with the cameras and the response fixed."""
        if falloff is None:
            return lambda thermal: thermal
        width, height, _ = host_sizes(cameras[0])
        terms = torch.stack([self.terms(falloff, flat_field, c, int(height), int(width)) for c in cameras])
        return lambda thermal: through_terms(thermal, terms)  # terms [B, H, W, 2]

    def terms(self, falloff: Tensor, flat_field: Optional[Tensor], camera: Cameras, height: int, width: int) -> Tensor:
        """The response's terms [H, W, 2] (`camera_falloff.response_terms`) of `camera` at height x width."""
        _, _, pinhole = host_sizes(camera)  # the camera's full resolution, as the render
        basis = self.basis(intrinsics(camera)[0].to(falloff.device), pinhole, width, height, 1)
        return response_terms(falloff.detach(), basis, None if flat_field is None else flat_field.detach())


def recorded_over_background(
    emission: Tensor,
    alpha: Tensor,
    background: Tensor,
    coefficients: Tensor,
    basis: Tensor,
    flat_field: Optional[Tensor] = None,
) -> Tensor:
    """`over_background`, as the camera records it (`camera_falloff.respond`): one function of tensors, so
    that a training step records the compositing and the camera model in one CUDA graph."""
    return respond(over_background(emission, alpha, background), coefficients, basis, flat_field)
