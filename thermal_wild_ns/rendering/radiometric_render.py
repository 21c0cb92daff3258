"""`wild-thermal-render`: ns-render's camera-path / interpolate / spiral commands, plus radiometric frames.

ns-render writes every output through its 8-bit colormap writer (video, PNG or JPEG), so it
cannot hand a thermal user their data back. These commands are ns-render's own (same options;
the video or images are ns-render's, in the model's thermal colormap, with the background model)
with two more options:
- `--photometric-state`: the sensor state every frame is rendered at (`pipeline/photometric_state.py`):
  `canonical` (default: the state of a novel view), `frame:N` (training frame N's own) or `time:T`
  (capture position T, interpolated between the training frames around it);
- `--radiometric`: `uint16` writes each frame's thermal render mapped back through that state's
  LUT to the dataset's native levels, as 16-bit PNGs; `celsius` the same as float32 degC arrays
  (.npy), for datasets that document their temperature bounds; `none` only what ns-render writes.
The frames go to `--radiometric-dir` (default: the output path with `_radiometric` appended),
beside a `radiometry.json` that states the mapping.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Optional, Union

import cv2
import numpy as np
import torch
import tyro
from nerfstudio.scripts import render as ns_render
from typing_extensions import Annotated

from thermal_wild_ns._upstream import (
    fast_camera_path_slices,
    interpolation_over_one_pose,
    trajectory_render_hooks,
)
from thermal_wild_ns.errors import report_input_errors_briefly
from thermal_wild_ns.pipeline.photometric_state import resolve_state, to_original
from thermal_wild_ns.pipeline.run_check import check_trained_run
from thermal_wild_ns.state_names import StateName


@dataclass
class RadiometricOptions:
    photometric_state: str = "canonical"
    """Sensor state to render at: canonical, frame:N (a training frame's index) or time:T (a capture position)."""
    radiometric: Literal["none", "uint16", "celsius"] = "uint16"
    """Also write each frame's thermal values: native 16-bit levels (PNG), degC (float32 .npy) or nothing."""
    radiometric_dir: Optional[Path] = None
    """Where those frames go (default: the output path with `_radiometric` appended)."""

    def radiometric_folder(self, output_path: Path) -> Path:
        return self.radiometric_dir or output_path.with_name(output_path.stem + "_radiometric")


class RadiometricFrameWriter:
    """Writes the thermal values of each frame a model renders, in the dataset's units."""

    def __init__(self, pipeline, state, folder: Path, mode: str):
        datamanager = pipeline.datamanager
        rng = datamanager.train_dataset.thermal_range
        if mode == "celsius" and not rng.has_celsius:
            raise ValueError(
                f"{datamanager.config.dataparser.data}: the dataset documents no temperature bounds; use "
                f"--radiometric uint16"
            )
        if mode == "uint16" and not (rng.low >= 0 and rng.high <= 65535):
            raise ValueError(
                f"{datamanager.config.dataparser.data}: native range {rng.low}..{rng.high} ({rng.dtype}) does not "
                f"fit 16 bits; use --radiometric celsius"
            )
        self.pipeline, self.state, self.rng, self.folder, self.mode, self.frames = pipeline, state, rng, folder, mode, 0
        folder.mkdir(parents=True, exist_ok=True)

    def write(self, thermal: torch.Tensor) -> None:
        """thermal [H, W, 1], the model's training space -> the next frame file."""

        normalised = np.clip(to_original(self.pipeline, thermal[..., 0].float().cpu().numpy(), self.state), 0.0, 1.0)
        if self.mode == "uint16":
            cv2.imwrite(
                str(self.folder / f"{self.frames:05d}.png"), np.round(self.rng.to_native(normalised)).astype(np.uint16)
            )
        else:
            np.save(self.folder / f"{self.frames:05d}.npy", self.rng.to_celsius(normalised).astype(np.float32))
        self.frames += 1

    def close(self) -> None:
        rng = self.rng
        (self.folder / "radiometry.json").write_text(
            json.dumps(
                {
                    "frames": self.frames,
                    "format": {"uint16": "16-bit PNG, native levels", "celsius": "float32 .npy, degC"}[self.mode],
                    "native_range": [rng.low, rng.high],
                    "native_dtype": rng.dtype,
                    "celsius_range": [rng.celsius_low, rng.celsius_high],
                    "celsius_calibration": None if rng.planck is None else dataclasses.asdict(rng.planck),
                    "mapping": "render -> the state's LUT inverse -> dataset range"
                    if self.state.lut is not None
                    else "render -> dataset range",
                    "photometric_state": self.state.label,
                },
                indent=1,
            )
        )


@contextlib.contextmanager
def _radiometric_too(options: RadiometricOptions, output_path: Path):
    """While ns-render's command runs, every trajectory is rendered at the chosen photometric state
    (its frame embedding passed to each render) and, unless `--radiometric none`, every frame it
    renders also goes to a RadiometricFrameWriter; each frame's camera is sliced from the path's batch
    without nerfstudio's per-frame rebuild (`fast_camera_path_slices`)."""

    StateName.parse(options.photometric_state)  # a bad name fails before the model loads
    check_trained_run(options.load_config)

    @contextlib.contextmanager
    def per_trajectory(pipeline):
        state = resolve_state(pipeline, options.photometric_state)
        frames = None
        if options.radiometric != "none":
            frames = RadiometricFrameWriter(
                pipeline, state, options.radiometric_folder(output_path), options.radiometric
            )
        yield state.embedding, None if frames is None else (lambda outputs: frames.write(outputs["thermal"]))
        if frames is not None:
            frames.close()

    with trajectory_render_hooks(per_trajectory), fast_camera_path_slices():  # each frame's camera, sliced cheaply
        yield


@dataclass
class RenderCameraPath(RadiometricOptions, ns_render.RenderCameraPath):
    """ns-render camera-path, plus radiometric frames."""

    def main(self) -> None:
        with _radiometric_too(self, self.output_path):
            super().main()


@dataclass
class RenderInterpolated(RadiometricOptions, ns_render.RenderInterpolated):
    """ns-render interpolate, plus radiometric frames; a pose source of one camera renders that pose."""

    def main(self) -> None:
        with _radiometric_too(self, self.output_path), interpolation_over_one_pose():
            super().main()


@dataclass
class SpiralRender(RadiometricOptions, ns_render.SpiralRender):
    """ns-render spiral, plus radiometric frames."""

    def main(self) -> None:
        with _radiometric_too(self, self.output_path):
            super().main()


Commands = tyro.conf.FlagConversionOff[
    Union[
        Annotated[RenderCameraPath, tyro.conf.subcommand(name="camera-path")],
        Annotated[RenderInterpolated, tyro.conf.subcommand(name="interpolate")],
        Annotated[SpiralRender, tyro.conf.subcommand(name="spiral")],
    ]
]


def entrypoint():
    report_input_errors_briefly()
    tyro.cli(Commands).main()


if __name__ == "__main__":
    entrypoint()
