"""The published thermal layouts built on a COLMAP model (`sparse/0`): plain COLMAP, TI-NSD (by its numeric
names), MSX / RGBT-Scenes and ThermalMix, each returning a `ThermalCapture` with its dataset's split rule (the
facts of each from the authors' loader, cited per reader)."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Callable, List, Optional, Tuple

import numpy as np

from thermal_wild_ns.data.capture import (
    SeedPoints,
    ThermalCapture,
    ThermalFrame,
    interval_split,
)
from thermal_wild_ns.data.colmap_model import ColmapModel, camera_intrinsics, read_colmap_model
from thermal_wild_ns.data.frame_files import natural_key
from thermal_wild_ns.data.thermal_io import RadiometricRange, load_npy
from thermal_wild_ns.errors import InputError, MissingInput

THERMALMIX_CELSIUS = {
    "face": (22.5, 35.2),
    "hand": (22.1, 33.6),
    "panel": (22.7, 55.8),
    "lion": (16.8, 48.3),
    "pan": (19.4, 129.8),
    "laptop": (21.6, 40.2),
}
"""ThermalMix (Ozer et al.): 8-bit frames are linear in degC between these per-scene bounds."""


def _colmap_frames(
    model: ColmapModel, folder: Path, find_image: Callable[[str], Tuple[Path, Optional[str]]], order: str = "name"
) -> List[ThermalFrame]:
    """Frames of a COLMAP model; `find_image(name)` gives the thermal file and split of an image."""
    keys = {
        "name": lambda im: natural_key(im.name),  # frame_2 before frame_10
        "string": lambda im: Path(im.name).stem,  # 3DGS's sort of image names: "10" before "2"
        "id": lambda im: im.image_id,
    }
    frames = []
    for image in sorted(model.images, key=keys[order]):
        camera = model.cameras[image.camera_id]
        fx, fy, cx, cy, dist = camera_intrinsics(camera, folder)
        path, split = find_image(image.name)
        frames.append(
            ThermalFrame(
                image=path,
                camera_to_world=np.linalg.inv(image.world_to_camera),
                fx=fx,
                fy=fy,
                cx=cx,
                cy=cy,
                width=camera.width,
                height=camera.height,
                distortion=dist,
                split=split,
            )
        )
    return frames


def _colmap_points(model: ColmapModel) -> Optional[SeedPoints]:
    return SeedPoints(xyz=model.points, source="colmap") if len(model.points) else None


def read_colmap(root: Path, images: str = "images", layout: str = "colmap") -> ThermalCapture:
    """Generic COLMAP: `sparse/0` (binary or text) + a folder of thermal frames named as in the
    model, in natural name order (frame_2 before frame_10), every 8th held out.

    TI-NSD (Thermal3D-GS, `mzzcdf/Thermal3DGS`, `scene/dataset_readers.py`) is the same layout
    (`images/` + `sparse/0`, PINHOLE, numeric names) read as 3DGS reads it: image names sorted as
    strings ("10" before "2"), every 8th from the first held out (`--eval`, llffhold 8). The two
    orders give different held-out frames once names are unpadded numbers past 9."""
    colmap = read_colmap_model(root / "sparse" / "0")
    order = "string" if layout == "ti-nsd" else "name"
    frames = _colmap_frames(colmap, root / "sparse" / "0", lambda name: (root / images / name, None), order=order)
    for frame, split in zip(frames, interval_split(len(frames))):
        frame.split = split
    rule = f"sorted by name{' as strings' if order == 'string' else ''}, every 8th frame held out"
    return ThermalCapture(layout, root, frames, rule, points=_colmap_points(colmap))


def read_msx(root: Path) -> ThermalCapture:
    """MSX (ThermalGaussian / RGBT-Scenes): `rgb/{train,test}/`, `thermal/{train,test}/`,
    `sparse/0` computed on the RGB frames; a thermal frame has its RGB frame's file name
    (ThermalGaussian's `readTemperSceneInfo`). Thermal frames are 3-channel colour-mapped JPGs
    (iron palette), 640x480. The split is the folders' (test: every 8th image)."""
    colmap = read_colmap_model(root / "sparse" / "0")

    def find(name: str):
        base = Path(name).name
        for split in ("train", "test"):
            if (root / "thermal" / split / base).is_file():
                return root / "thermal" / split / base, split
        raise MissingInput(
            f"{root / 'thermal'}/{{train,test}}/{base}: thermal frame of COLMAP image '{name}' is missing"
        )

    frames = _colmap_frames(colmap, root / "sparse" / "0", find)
    return ThermalCapture(
        "msx", root, frames, "the thermal/{train,test} folders", palette="iron", points=_colmap_points(colmap)
    )


def read_thermalmix(
    root: Path, holdout_index: int = 20, celsius: Optional[Tuple[float, float]] = None
) -> ThermalCapture:
    """ThermalMix (Ozer et al.), as the authors' loader reads it (`mert-o/thermalnerfs`,
    `nerf/colmap_provider.py` at c8e8f8b): the COLMAP model in `colmap_sparse/0` (or `sparse/0`);
    for each model image, in image-id order, the thermal frame the poses belong to is
    `warped_thermal/<stem>.npy` (float degC). Where only `warped_thermal/<stem>.jpg` exists (8-bit
    grey, linear in degC between the scene's bounds, which `img_temp_mapper.py` turns into the
    `.npy`), that is read. The unwarped `thermal/` frames are never used (they do not match the
    poses). Model images without a frame are dropped BEFORE the held-out view is picked by its
    index (`--val_idx`, 20 in the authors' README), as their loader does. Bounds per scene
    (`THERMALMIX_CELSIUS`) come from the folder name unless `celsius` is given; without either the
    range is measured."""
    model = next(
        (root / d / "0" for d in ("colmap_sparse", "sparse") if (root / d / "0").is_dir()), root / "colmap_sparse" / "0"
    )
    colmap = read_colmap_model(model)
    folder = root / "warped_thermal"
    if not folder.is_dir():
        raise MissingInput(f"{folder}: no warped_thermal/ (the frames the poses belong to; thermal/ is not used)")

    def find(name: str):
        stem = Path(name).stem
        for path in (folder / f"{stem}.npy", folder / f"{stem}.jpg", folder / f"{stem}.png"):
            if path.is_file():
                return path, None
        return None, None

    listed = _colmap_frames(colmap, model, find, order="id")
    frames = [f for f in listed if f.image is not None]
    if not frames:
        raise MissingInput(f"{folder}: none of the {len(listed)} images of {model} has a frame here (.npy/.jpg)")
    if len(frames) < len(listed):
        warnings.warn(
            f"{folder}: {len(listed) - len(frames)} of the {len(listed)} images of {model} have no frame; "
            "dropped before the held-out view is picked, as the authors' loader does",
            stacklevel=2,
        )
    if not 0 <= holdout_index < len(frames):
        raise InputError(f"{model}: held-out view index {holdout_index} is outside the {len(frames)} frames")
    for i, frame in enumerate(frames):
        frame.split = "test" if i == holdout_index else "train"
    suffixes = {f.image.suffix for f in frames}
    if len(suffixes) > 1:
        raise InputError(f"{folder}: frames of mixed formats ({', '.join(sorted(suffixes))}); use one")
    bounds = celsius or THERMALMIX_CELSIUS.get(root.name.lower())
    declared = None
    if bounds is not None:
        if frames[0].image.suffix == ".npy":
            declared = RadiometricRange(
                bounds[0], bounds[1], str(load_npy(frames[0].image, mmap_mode="r").dtype), *bounds
            )
        else:
            declared = RadiometricRange(0.0, 255.0, "uint8", *bounds)
    return ThermalCapture(
        "thermalmix",
        root,
        frames,
        f"view {holdout_index} (by image id, among the images with a frame) held out",
        declared_range=declared,
        points=_colmap_points(colmap),
    )


# --------------------------------------------------------------------------- per-file poses / LLFF
