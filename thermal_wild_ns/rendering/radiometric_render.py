"""`wild-thermal-render`: ns-render's camera-path / interpolate / spiral commands, plus radiometric frames.

ns-render writes every output through its 8-bit colormap writer (video, PNG or JPEG), so it
cannot hand a thermal user their data back. These commands are ns-render's own (same options;
the video or images are ns-render's, in the model's thermal colormap, with the fixed frame
embedding and the background model) with one more option, `--radiometric`:
- `uint16`: each frame's thermal render mapped back through the median training LUT (no frame was
  captured on the path) to the dataset's native levels, as 16-bit PNGs;
- `celsius`: the same as float32 degC arrays (.npy), for datasets that document their
  temperature bounds;
- `none`: only what ns-render writes.
The frames go to `--radiometric-dir` (default: the output path with `_radiometric` appended),
beside a `radiometry.json` that states the mapping.
"""

from __future__ import annotations

import contextlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Optional, Union

import numpy as np
import torch
import tyro
from nerfstudio.scripts import render as ns_render
from typing_extensions import Annotated

import thermal_wild_ns.compat  # noqa: F401  (checkpoint loading on torch >= 2.6; ffmpeg)


@dataclass
class RadiometricOptions:
    radiometric: Literal["none", "uint16", "celsius"] = "uint16"
    """Also write each frame's thermal values: native 16-bit levels (PNG), degC (float32 .npy) or nothing."""
    radiometric_dir: Optional[Path] = None
    """Where those frames go (default: the output path with `_radiometric` appended)."""

    def radiometric_folder(self, output_path: Path) -> Path:
        return self.radiometric_dir or output_path.with_name(output_path.stem + "_radiometric")


class RadiometricFrameWriter:
    """Writes the thermal values of each frame a model renders, in the dataset's units."""

    def __init__(self, datamanager, folder: Path, mode: str):
        rng = datamanager.train_dataset.thermal_range
        if mode == "celsius" and (rng.celsius_low is None or rng.celsius_high is None):
            raise ValueError(f"{datamanager.config.dataparser.data}: the dataset documents no temperature bounds; use --radiometric uint16")
        if mode == "uint16" and not (rng.low >= 0 and rng.high <= 65535):
            raise ValueError(f"{datamanager.config.dataparser.data}: native range {rng.low}..{rng.high} ({rng.dtype}) does not fit 16 bits; use --radiometric celsius")
        self.datamanager, self.rng, self.folder, self.mode, self.frames = datamanager, rng, folder, mode, 0
        folder.mkdir(parents=True, exist_ok=True)

    def write(self, thermal: torch.Tensor) -> None:
        """thermal [H, W, 1], the model's training space -> the next frame file."""
        import cv2

        normalised = np.clip(self.datamanager.novel_view_to_original(thermal[..., 0].float().cpu().numpy()), 0.0, 1.0)
        if self.mode == "uint16":
            cv2.imwrite(str(self.folder / f"{self.frames:05d}.png"), np.round(self.rng.to_native(normalised)).astype(np.uint16))
        else:
            np.save(self.folder / f"{self.frames:05d}.npy", self.rng.to_celsius(normalised).astype(np.float32))
        self.frames += 1

    def close(self, frame_embedding: str) -> None:
        rng = self.rng
        (self.folder / "radiometry.json").write_text(json.dumps({
            "frames": self.frames,
            "format": {"uint16": "16-bit PNG, native levels", "celsius": "float32 .npy, degC"}[self.mode],
            "native_range": [rng.low, rng.high],
            "native_dtype": rng.dtype,
            "celsius_range": [rng.celsius_low, rng.celsius_high],
            "mapping": "render -> median training LUT inverse -> dataset range" if self.datamanager.preprocessed is not None else "render -> dataset range",
            "frame_embedding": frame_embedding,
        }, indent=1))


@contextlib.contextmanager
def _radiometric_too(options: RadiometricOptions, output_path: Path):
    """While ns-render's command runs, every frame its trajectory writer renders also goes to a
    RadiometricFrameWriter: the same renders as the video, not a second pass."""
    original = ns_render._render_trajectory_video
    if options.radiometric == "none":
        yield
        return

    def trajectory_writer(pipeline, *args, **kwargs):
        model = pipeline.model
        frames = RadiometricFrameWriter(pipeline.datamanager, options.radiometric_folder(output_path), options.radiometric)
        render = model.get_outputs_for_camera

        def recording(*render_args, **render_kwargs):
            outputs = render(*render_args, **render_kwargs)
            frames.write(outputs["thermal"])
            return outputs

        model.get_outputs_for_camera = recording
        try:
            return original(pipeline, *args, **kwargs)
        finally:
            del model.get_outputs_for_camera  # back to the class's method
            frames.close(model.config.inference_embedding)

    ns_render._render_trajectory_video = trajectory_writer
    try:
        yield
    finally:
        ns_render._render_trajectory_video = original


@dataclass
class RenderCameraPath(RadiometricOptions, ns_render.RenderCameraPath):
    """ns-render camera-path, plus radiometric frames."""

    def main(self) -> None:
        with _radiometric_too(self, self.output_path):
            super().main()


@dataclass
class RenderInterpolated(RadiometricOptions, ns_render.RenderInterpolated):
    """ns-render interpolate, plus radiometric frames."""

    def main(self) -> None:
        with _radiometric_too(self, self.output_path):
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
    tyro.cli(Commands).main()


if __name__ == "__main__":
    entrypoint()
