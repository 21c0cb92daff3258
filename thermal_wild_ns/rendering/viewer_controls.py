"""The thermal controls of ns-viewer's "Custom Elements" panel: the colormap, the photometric
state to render with (canonical, or any capture time on a slider), the colour bar at that state,
and a button (and the first view) through a training camera.

The model owns one `ThermalViewerControls` (an `nn.Module` without parameters, so that nerfstudio's
viewer finds its elements on the model) and reads the user's choices from it as values
(`capture_time`, `colormap`); the pipeline subscribes to state changes (`on_state_change`) to
update the colour bar (`show_colour_bar`). Outside the viewer the elements keep their defaults:
canonical state, the configured colormap.
"""

from __future__ import annotations

import functools
from typing import Callable, List, Optional, Sequence

import numpy as np
import torch
import viser.transforms as vtf
from nerfstudio.viewer.viewer_elements import ViewerButton, ViewerDropdown, ViewerSlider, ViewerText
from torch import Tensor, nn

from thermal_wild_ns._upstream import ViewerControlOnConnect
from thermal_wild_ns.data.palettes import palette_rgb

COLORMAPS = ("iron", "inferno", "grey")


@functools.lru_cache(maxsize=8)
def colormap_table(name: str, device: str) -> Tensor:
    """Colormap `name`'s 256 colours [256, 3] in [0, 1] on `device`: made once, looked up per render."""
    return torch.from_numpy(palette_rgb(name).astype("float32") / 255.0).to(device)


def thermal_rgb(thermal: Tensor, colormap: Optional[str]) -> Tensor:
    """A thermal image [H, W, 1] (clipped to [0, 1]) as RGB [H, W, 3]: through `colormap`, or grey
    without one (a view expanded, no copy)."""
    clipped = thermal.clamp(0.0, 1.0)
    if colormap is None:
        return clipped.expand(-1, -1, 3)
    return colormap_table(colormap, str(clipped.device))[(clipped[..., 0] * 255).round().long()]


class ThermalViewerControls(nn.Module):
    """The viewer's thermal elements for a model trained on frames at `frame_times` (capture order)."""

    def __init__(self, frame_times: Sequence[float], colormap: str):
        super().__init__()

        self.frame_times: List[float] = list(frame_times)
        self._listeners: List[Callable[[], None]] = []
        self.viewer_colormap = ViewerDropdown(
            "Thermal colormap", colormap, list(COLORMAPS), hint="colours of the rgb output"
        )
        self.viewer_state = ViewerDropdown(
            "Photometric state",
            "canonical",
            ["canonical", "capture time"],
            cb_hook=lambda _: self._state_changed(),
            hint="canonical: the state every novel view renders with; capture time: the sensor's state at the "
            "slider's position",
        )
        first, last = min(self.frame_times), max(self.frame_times)
        self.viewer_time = ViewerSlider(
            "Capture time",
            first,
            first,
            max(last, first + 1e-3),
            step=0.1,
            cb_hook=lambda _: self._state_changed(),
            hint="capture position (frame index); between training frames the state is interpolated",
        )
        self.viewer_colour_bar = ViewerText(
            "Colour bar", "set by the pipeline", disabled=True, hint="values at 0, 25, 50, 75, 100 % of the colormap"
        )
        # the viewer opens looking at the scene, not from an arbitrary pose
        self.viewer_control = ViewerControlOnConnect(
            lambda client: self._look_through_training_camera(self.nearest_training_image(), client)
        )
        self.viewer_go_to_frame = ViewerButton(
            "Look through the nearest training camera",
            cb_hook=lambda _: self._look_through_training_camera(self.nearest_training_image()),
        )

    @property
    def capture_time(self) -> Optional[float]:
        """The capture position the viewer renders at; None: the canonical state."""
        return float(self.viewer_time.value) if self.viewer_state.value == "capture time" else None

    @property
    def colormap(self) -> str:
        return str(self.viewer_colormap.value)

    def on_state_change(self, listener: Callable[[], None]) -> None:
        """Call `listener()` after every change of the photometric state."""
        self._listeners.append(listener)

    def _state_changed(self) -> None:
        for listener in self._listeners:
            listener()

    def show_colour_bar(self, text: str) -> None:
        self.viewer_colour_bar.value = text

    def nearest_training_image(self) -> int:
        """The training image closest in capture time to the viewer's state (the first one when canonical)."""
        t = self.capture_time
        if t is None:
            return 0
        return min(range(len(self.frame_times)), key=lambda k: abs(self.frame_times[k] - t))

    def _look_through_training_camera(self, image: int, client=None) -> None:
        """Put a viewer client (default: all) at training image `image`'s camera (or else the first
        one), as clicking its frustum does."""
        viewer = self.viewer_control.started_viewer()
        handles = None if viewer is None else viewer.camera_handles
        if not handles:
            return
        handle = handles.get(image) or handles[min(handles)]

        # just past the frustum's image plane, which would otherwise cover the view (viser cameras look along +z)
        forward = vtf.SO3(np.asarray(handle.wxyz)).as_matrix()[:, 2]
        position = np.asarray(handle.position) + forward * 2.0 * viewer.config.camera_frustum_scale
        for each in [client] if client is not None else viewer.viser_server.get_clients().values():
            with each.atomic():
                each.camera.wxyz = handle.wxyz
                each.camera.position = position
