"""`wild-thermal-render`: ns-render's camera-path / interpolate / spiral commands, plus radiometric frames.

ns-render writes every output through its 8-bit colormap writer (video, PNG or JPEG), so it
cannot hand a thermal user their data back. These commands are ns-render's own (same options;
the video or images are ns-render's, in the model's thermal colormap, with the fixed frame
embedding and the background model) with one more option, `--radiometric`:
- `uint16`: each frame's thermal render mapped back through the mean training LUT (no frame was
  captured on the path) to the dataset's native levels, as 16-bit PNGs;
- `celsius`: the same as float32 degC arrays (.npy), for datasets that document their
  temperature bounds;
- `none`: only what ns-render writes.
The frames go to `--radiometric-dir` (default: the output path with `_radiometric` appended),
beside a `radiometry.json` that states the mapping.
"""

from __future__ import annotations

import contextlib
import copy
import inspect
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


def write_radiometric_frames(pipeline, cameras, folder: Path, mode: str, resolution_scale: float = 1.0) -> int:
    """Render `cameras` (fixed embedding) and write their thermal values in the dataset's units;
    returns the number of frames written."""
    from tqdm import tqdm

    datamanager = pipeline.datamanager
    dataset = datamanager.train_dataset
    rng = dataset.thermal_range
    if mode == "celsius" and (rng.celsius_low is None or rng.celsius_high is None):
        raise ValueError(f"{datamanager.config.dataparser.data}: the dataset documents no temperature bounds; use --radiometric uint16")
    if mode == "uint16" and not (rng.low >= 0 and rng.high <= 65535):
        raise ValueError(f"{datamanager.config.dataparser.data}: native range {rng.low}..{rng.high} ({rng.dtype}) does not fit 16 bits; use --radiometric celsius")
    sequence = getattr(datamanager, "preprocessed", None)
    train_frames = list(dataset.metadata["frame_indices"])
    cameras = copy.deepcopy(cameras)  # ns-render rescales its cameras in place afterwards
    cameras.rescale_output_resolution(resolution_scale)
    cameras = cameras.to(pipeline.device)
    folder.mkdir(parents=True, exist_ok=True)
    pipeline.eval()
    import cv2

    for i in tqdm(range(cameras.size), desc=f"radiometric frames ({mode})"):
        with torch.no_grad():
            thermal = pipeline.model.get_outputs_for_camera(cameras[i : i + 1])["thermal"][..., 0].float().cpu().numpy()  # [H, W]
        normalised = sequence.to_original_normalised(thermal, train_frames) if sequence is not None else thermal
        if mode == "uint16":
            levels = np.clip(np.round(rng.low + np.clip(normalised, 0.0, 1.0) * (rng.high - rng.low)), 0, 65535).astype(np.uint16)
            cv2.imwrite(str(folder / f"{i:05d}.png"), levels)
        else:
            np.save(folder / f"{i:05d}.npy", rng.to_celsius(np.clip(normalised, 0.0, 1.0)).astype(np.float32))
    (folder / "radiometry.json").write_text(json.dumps({
        "frames": int(cameras.size),
        "format": {"uint16": "16-bit PNG, native levels", "celsius": "float32 .npy, degC"}[mode],
        "native_range": [rng.low, rng.high],
        "native_dtype": rng.dtype,
        "celsius_range": [rng.celsius_low, rng.celsius_high],
        "mapping": "render -> mean training LUT inverse -> dataset range" if sequence is not None else "render -> dataset range",
        "frame_embedding": pipeline.model.config.inference_embedding,
    }, indent=1))
    return int(cameras.size)


@contextlib.contextmanager
def _radiometric_too(options: RadiometricOptions, output_path: Path):
    """While ns-render's command runs, its trajectory writer first writes the radiometric frames."""
    original = ns_render._render_trajectory_video
    if options.radiometric == "none":
        yield
        return
    signature = inspect.signature(original)

    def writer(*args, **kwargs):
        bound = signature.bind(*args, **kwargs)
        bound.apply_defaults()
        write_radiometric_frames(bound.arguments["pipeline"], bound.arguments["cameras"], options.radiometric_folder(output_path),
                                 options.radiometric, bound.arguments["rendered_resolution_scaling_factor"])
        return original(*args, **kwargs)

    ns_render._render_trajectory_video = writer
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
