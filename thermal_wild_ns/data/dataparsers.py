"""Thermal dataparsers for nerfstudio: every published thermal layout, one implementation.

`ThermalDataParser` reads a capture with the chosen layout reader (`layouts.py`, or the one
`detect_layout` finds), checks it (`capture.validate`, `thermal_io.scan_frames`), orients and
scales the poses as nerfstudio's own parsers do, and adds what thermal training needs:
- `metadata["thermal_range"]`: ONE radiometric range per dataset (declared or measured);
- seed points (`points3D_xyz`, `points3D_rgb` as grey levels) from, in order of preference, the
  layout's sparse model / point cloud, triangulation from the known poses (`triangulation.py`,
  cached), or random points inside the training cameras' view volume; the route taken and its
  point count are logged and kept in `metadata["seed_points"]`;
- the capture-order index of every frame (`metadata["frame_indices"]`);
- clean ground-truth frames for evaluation when the capture has them (generated scenes).

Registered parsers (`ns-train wild-thermal <parser> --data PATH`) are this class with a fixed
layout; `thermal` detects the layout and says which it chose.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Literal, Optional, Tuple, Type

import numpy as np
import torch
from nerfstudio.cameras import camera_utils
from nerfstudio.cameras.cameras import Cameras, CameraType
from nerfstudio.data.dataparsers.base_dataparser import DataParser, DataParserConfig, DataparserOutputs
from nerfstudio.data.scene_box import SceneBox
from nerfstudio.plugins.registry_dataparser import DataParserSpecification
from nerfstudio.utils.rich_utils import CONSOLE

from thermal_wild_ns.data import layouts
from thermal_wild_ns.data.capture import (
    SeedPoints,
    ThermalCapture,
    ThermalFrame,
    fraction_split,
    interval_split,
    opencv_to_opengl,
    validate,
)
from thermal_wild_ns.data.celsius import MeasurementSettings
from thermal_wild_ns.data.demo_scene import STRESS_FAULTS, DemoSceneConfig, generate_demo_scene, stress_scene_config
from thermal_wild_ns.data.palettes import PALETTE_NAMES
from thermal_wild_ns.data.scan_cache import cached_scan, scan_key
from thermal_wild_ns.data.survey_scene import SurveySceneConfig, generate_survey_scene
from thermal_wild_ns.data.thermal_io import DEGENERATE_SHARE, RadiometricRange, scan_frames
from thermal_wild_ns.data.triangulation import TriangulationConfig, cached_triangulation
from thermal_wild_ns.errors import InputError, report_input_errors_briefly

DEMO_SCENE_DIR = Path("outputs/thermal-demo-scene")
MIN_SEED_POINTS = 4
"""Fewer seeds than this cannot initialise Gaussians (their scales come from 3 nearest neighbours)."""
# Choices derived from the registries they name (tyro turns them into --help choices)
LayoutName = Literal[("auto", *layouts.LAYOUTS)]  # type: ignore[valid-type]
PaletteName = Literal[("auto", *PALETTE_NAMES)]  # type: ignore[valid-type]
SceneName = Literal[("demo", *STRESS_FAULTS, "all", "survey")]  # type: ignore[valid-type]


@dataclass
class ThermalDataParserConfig(DataParserConfig):
    """Single-channel thermal captures in any supported layout."""

    _target: Type = field(default_factory=lambda: ThermalDataParser)
    data: Path = Path()
    """Dataset folder (or a transforms.json)."""
    layout: LayoutName = "auto"
    """Dataset layout; 'auto' detects it (and fails listing the layouts it tried)."""
    split: Literal["dataset", "interval", "fraction", "all"] = "dataset"
    """Held-out frames: the dataset's published rule ('dataset'), every `eval_interval`-th frame,
    an evenly spaced `train_split_fraction`, or none held out ('all')."""
    eval_interval: int = 8
    train_split_fraction: float = 0.9
    palette: PaletteName = "auto"
    """Palette of colour-mapped frames; 'auto' uses the layout's or detects it."""
    keep_degenerate_frames: bool = False
    """Train on frames with no contrast (nearly all pixels at one value: an all-zero read-out, a
    frozen frame). By default they are reported by name and left out."""
    range_percentiles: Tuple[float, float] = (0.1, 99.9)
    """Percentiles of all pixels of all frames mapped to 0 and 1 when the dataset declares no range."""
    thermalmix_celsius: Optional[Tuple[float, float]] = None
    """ThermalMix: degC of 8-bit levels 0 and 255 (default: the published bounds of the scene folder's name)."""
    thermalmix_holdout: int = 20
    """ThermalMix: index (by COLMAP image id) of the held-out view."""
    orientation_method: Literal["pca", "up", "vertical", "none"] = "up"
    center_method: Literal["poses", "focus", "none"] = "poses"
    auto_scale_poses: bool = True
    """Scale poses to fit in [-1, 1]."""
    scale_factor: float = 1.0
    scene_scale: float = 1.0
    seed_points: Literal["auto", "sfm", "triangulate", "random"] = "auto"
    """Gaussian seeds: 'auto' takes the dataset's sparse points, else triangulates, else random."""
    num_random_points: int = 50_000
    """Random seeds when nothing better exists."""
    triangulation: TriangulationConfig = field(default_factory=TriangulationConfig)
    lens_calibration: Optional[Path] = None
    """exif-gps layout: the camera's lens calibration (a Metashape / Agisoft Lens calibration XML),
    held fixed by SfM. Without it the focal length comes from the files and lens distortion is
    taken as none: a flight straight down over flat ground cannot measure it."""
    emissivity: Optional[float] = None
    """Drone surveys of radiometric JPEGs (FLIR and DJI format): the surface's emissivity (0-1) for every frame's
    °C, in place of what each file says (None: each file's)."""
    object_distance: Optional[float] = None
    """The same: the distance to the surface in metres. DJI's SDK takes 1-25 m on most of its cameras: a farther
    one is clamped to the camera's range, and the run says so."""
    reflected_temperature: Optional[float] = None
    """The same: the reflected apparent temperature in °C (the sky's and surroundings' radiation)."""
    atmospheric_temperature: Optional[float] = None
    """The same: the air temperature in °C."""
    relative_humidity: Optional[float] = None
    """The same: the relative humidity in percent."""
    cache_dir: Optional[Path] = None
    """Where triangulated points and SfM poses are cached. Default: `<data>/.thermal_wild_ns`, or
    `~/.cache/thermal_wild_ns/<name>-<hash>` when the data folder is read-only."""


class ThermalDataParser(DataParser):
    config: ThermalDataParserConfig

    def __init__(self, config: ThermalDataParserConfig):
        super().__init__(config)
        report_input_errors_briefly()  # a bad dataset is the user's to fix: one line, not a traceback
        self._capture: Optional[ThermalCapture] = None
        self._range: Optional[RadiometricRange] = None
        self._seeds: Optional[SeedPoints] = None
        self.degenerate_frames: List[str] = []
        """File names of the frames with no contrast (left out unless `keep_degenerate_frames`)."""

    # ------------------------------------------------------------------ reading
    def capture(self) -> ThermalCapture:
        if self._capture is None:
            root = Path(self.config.data)
            name = self.config.layout
            if name == "auto":
                name = layouts.detect_layout(root)
                CONSOLE.log(f"{root}: detected layout '{name}' ({layouts.LAYOUTS[name].description})")
            options = {
                "thermalmix": {
                    "holdout_index": self.config.thermalmix_holdout,
                    "celsius": self.config.thermalmix_celsius,
                },
                "exif-gps": {"cache_root": self._cache_root(), "lens_calibration": self.config.lens_calibration},
            }
            for survey in ("metashape", "odm", "exif-gps"):
                options.setdefault(survey, {})["settings"] = self.measurement_settings()
            capture = validate(layouts.LAYOUTS[name].read(root, **options.get(name, {})))
            n = len(capture.frames)
            override = {
                "interval": lambda: interval_split(n, self.config.eval_interval),
                "fraction": lambda: fraction_split(n, self.config.train_split_fraction),
                "all": lambda: ["train"] * n,
            }.get(self.config.split)
            if override is not None:
                for frame, split in zip(capture.frames, override()):
                    frame.split = split
                capture.split_rule = f"split='{self.config.split}'"
            self._range = self._scan(capture)
            self._capture = capture
        return self._capture

    def measurement_settings(self) -> MeasurementSettings:
        """The user's measurement settings for every frame's °C (None fields: each file's own)."""
        cfg = self.config
        return MeasurementSettings(
            cfg.emissivity,
            cfg.object_distance,
            cfg.reflected_temperature,
            cfg.atmospheric_temperature,
            cfg.relative_humidity,
        )

    def _scan(self, capture: ThermalCapture) -> RadiometricRange:
        """Read every frame once (`scan_frames`; kept for the commands after training: `scan_cache`); drop the
        degenerate ones unless told to keep them."""
        paths = [f.image for f in capture.frames]
        settings = dict(
            sizes=[(f.width, f.height) for f in capture.frames],
            declared=capture.declared_range,
            palette=(None if self.config.palette == "auto" else self.config.palette) or capture.palette,
            percentiles=self.config.range_percentiles,
            measure=[f.split != "test" for f in capture.frames],  # held-out pixels never set the scale
        )
        scan = cached_scan(self._cache_root(), scan_key(paths, settings), lambda: scan_frames(paths, **settings))
        self.degenerate_frames = [capture.frames[i].image.name for i in scan.degenerate]
        if scan.degenerate:
            names = ", ".join(self.degenerate_frames)
            share = f"{DEGENERATE_SHARE:.0%}"
            if self.config.keep_degenerate_frames:
                CONSOLE.log(f"[yellow]{capture.root}: training on frames with no contrast (kept as asked): {names}")
            else:
                CONSOLE.log(
                    f"[yellow]{capture.root}: left out {len(scan.degenerate)} frame(s) with no contrast (at least "
                    f"{share} of the pixels at one value): {names}. The dataparser's --keep-degenerate-frames True "
                    "keeps them"
                )
                dropped = set(scan.degenerate)
                capture.frames = [f for i, f in enumerate(capture.frames) if i not in dropped]
                if not any(f.split != "test" for f in capture.frames):
                    raise InputError(f"{capture.root}: no training frame is left once the degenerate ones are out")
        if capture.celsius_calibration is None:
            return scan.range
        own = tuple(f.celsius for f in capture.frames)
        frame_celsius = own if any(c is not None for c in own) else None
        return dataclasses.replace(scan.range, planck=capture.celsius_calibration, frame_celsius=frame_celsius)

    def fingerprint(self) -> Dict[str, str]:
        """What a trained run was trained on, to tell later whether the data changed: each frame
        (its path under the data folder) -> a digest of its file's bytes and of its camera (pose and
        intrinsics, rounded far below any real change)."""
        capture = self.capture()
        root = Path(capture.root)
        digests = {}
        for frame in capture.frames:
            digest = hashlib.sha1(Path(frame.image).read_bytes())
            camera = np.round(
                np.concatenate([np.ravel(frame.camera_to_world), [frame.fx, frame.fy, frame.cx, frame.cy]]), 5
            )
            digest.update(np.ascontiguousarray(camera, dtype=np.float64).tobytes())
            try:
                name = str(Path(frame.image).relative_to(root))
            except ValueError:
                name = str(frame.image)
            digests[name] = digest.hexdigest()
        return digests

    def radiometric_range(self) -> RadiometricRange:
        """Dataset-level range: declared by the dataset or measured over the training frames, once."""
        self.capture()
        return self._range

    # ------------------------------------------------------------------ seed points
    def _cache_root(self) -> Path:
        if self.config.cache_dir is not None:
            return Path(self.config.cache_dir)
        root = Path(self.config.data)
        root = root.parent if root.is_file() else root  # a transforms.json given as the data
        if os.access(root, os.W_OK):
            return root / ".thermal_wild_ns"
        digest = hashlib.sha256(str(root.resolve()).encode()).hexdigest()[:8]
        return (
            Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "thermal_wild_ns" / f"{root.name}-{digest}"
        )

    def seed_points(self) -> SeedPoints:
        """Gaussian seeds in the capture's world frame, each with a value in native units (from the
        seeds' source, or sampled from the training frames that see it), computed once."""
        if self._seeds is None:
            capture, route = self.capture(), self.config.seed_points
            train = [f for f in capture.frames if f.split == "train"]
            seeds = None
            sparse = capture.points
            if route in ("auto", "sfm") and sparse is not None and len(sparse.xyz) >= MIN_SEED_POINTS:
                seeds = sparse
            elif route == "sfm":
                found = "no sparse points" if sparse is None else f"only {len(sparse.xyz)} sparse points"
                raise InputError(f"{capture.root}: seed_points='sfm' but the {capture.layout} layout has {found}")
            elif sparse is not None:
                CONSOLE.log(
                    f"[yellow]{capture.root}: the {capture.layout} layout's sparse model has only {len(sparse.xyz)} "
                    f"points; seeding otherwise"
                )
            if seeds is None and route in ("auto", "triangulate"):
                cache = self._cache_root()
                xyz, report = cached_triangulation(train, self.radiometric_range(), cache, self.config.triangulation)
                CONSOLE.log(
                    f"triangulated {report['points']} points from {report['frames']} training frames with the known "
                    f"poses: median reprojection error {report['reprojection_error_px_median']} px, "
                    f"{report.get('seconds', '?')} s (cache: {cache})"
                )
                if len(xyz) >= 4:
                    seeds = SeedPoints(xyz=xyz, source="triangulated")
                elif route == "triangulate":
                    raise InputError(
                        f"{capture.root}: triangulation found only {len(xyz)} points (SIFT finds too little texture)"
                    )
            if seeds is None:
                seeds = SeedPoints(xyz=random_view_volume_points(train, self.config.num_random_points), source="random")
            if seeds.values is None:  # sample the frames once; train and eval outputs share the seeds
                rng = self.radiometric_range()
                values = sample_point_values(seeds.xyz, train, rng)
                seeds = SeedPoints(xyz=seeds.xyz, source=seeds.source, values=rng.to_native(values))
            CONSOLE.log(f"Gaussian seeds: {len(seeds.xyz)} points ({seeds.source})")
            self._seeds = seeds
        return self._seeds

    # ------------------------------------------------------------------ nerfstudio outputs
    def _generate_dataparser_outputs(self, split: str = "train") -> DataparserOutputs:
        capture = self.capture()
        rng = self.radiometric_range()
        frames = capture.frames
        poses = torch.from_numpy(np.stack([opencv_to_opengl(f.camera_to_world) for f in frames])).float()
        poses, transform = camera_utils.auto_orient_and_center_poses(
            poses, method=self.config.orientation_method, center_method=self.config.center_method
        )
        scale = self.config.scale_factor
        if self.config.auto_scale_poses:
            scale /= float(torch.max(torch.abs(poses[:, :3, 3])).clamp(min=1e-8))
        poses[:, :3, 3] *= scale

        wanted = "train" if split == "train" else "test"
        indices = [i for i, f in enumerate(frames) if f.split == wanted or self.config.split == "all"]
        if not indices:
            raise InputError(f"{capture.root}: no '{wanted}' frames ({capture.split_rule})")
        chosen = [frames[i] for i in indices]

        def column(name: str, dtype: torch.dtype) -> torch.Tensor:
            # readers give numpy float64 (COLMAP) or Python numbers: cast, or gsplat's projection
            # mixes float64 intrinsics with float32 Gaussians and fails at the first step
            return torch.tensor([float(getattr(f, name)) for f in chosen], dtype=dtype)[:, None]

        cameras = Cameras(
            camera_to_worlds=poses[indices, :3, :4],
            fx=column("fx", torch.float32),
            fy=column("fy", torch.float32),
            cx=column("cx", torch.float32),
            cy=column("cy", torch.float32),
            width=column("width", torch.float32).long(),
            height=column("height", torch.float32).long(),
            distortion_params=torch.from_numpy(np.stack([f.distortion for f in chosen])).float(),
            camera_type=CameraType.PERSPECTIVE,
        )
        if split == "train":
            CONSOLE.log(
                f"{capture.root} ({capture.layout}): {len(frames)} frames, "
                f"{sum(f.split == 'train' for f in frames)} for training; held out: {capture.split_rule}"
            )
        images = [f.image if split == "train" or f.ground_truth is None else f.ground_truth for f in chosen]
        metadata: Dict = {
            "thermal_range": rng,
            "frame_indices": indices,
            "is_ground_truth": [image != f.image for image, f in zip(images, chosen)],
            "recorded_filenames": [f.image for f in chosen],  # what the camera recorded, ground truth or not
            "layout": capture.layout,
        }
        seeds = self.seed_points()
        xyz = torch.from_numpy(seeds.xyz).float()
        xyz = (torch.cat([xyz, torch.ones_like(xyz[:, :1])], -1) @ transform.T) * scale
        values = rng.normalize(seeds.values)
        metadata["points3D_xyz"] = xyz
        metadata["points3D_rgb"] = torch.from_numpy((np.clip(values, 0.0, 1.0) * 255).astype(np.uint8))[:, None].repeat(
            1, 3
        )
        metadata["seed_points"] = {"source": seeds.source, "count": len(seeds.xyz)}
        aabb = self.config.scene_scale
        return DataparserOutputs(
            image_filenames=images,
            cameras=cameras,
            scene_box=SceneBox(aabb=torch.tensor([[-aabb] * 3, [aabb] * 3], dtype=torch.float32)),
            metadata=metadata,
            dataparser_transform=transform,
            dataparser_scale=scale,
        )


def _project(xyz: np.ndarray, frame: ThermalFrame) -> Tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates [N, 2] (COLMAP convention) and camera depth [N] of world points."""
    w2c = np.linalg.inv(frame.camera_to_world)
    cam = xyz @ w2c[:3, :3].T + w2c[:3, 3]
    z = cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.stack([frame.fx * cam[:, 0] / z + frame.cx, frame.fy * cam[:, 1] / z + frame.cy], -1)
    return uv, z


def sample_point_values(
    xyz: np.ndarray, frames: List[ThermalFrame], rng: RadiometricRange, max_frames: int = 16
) -> np.ndarray:
    """Normalised thermal value [N] of each point: its mean over (up to `max_frames`, evenly spaced)
    training frames that see it; 0.5 where none does. Occlusion is ignored: this only seeds emission."""
    total, count = np.zeros(len(xyz)), np.zeros(len(xyz))
    for frame in [
        frames[i] for i in np.unique(np.linspace(0, len(frames) - 1, min(max_frames, len(frames))).astype(int))
    ]:
        uv, z = _project(xyz, frame)
        col, row = np.floor(uv[:, 0]).astype(np.int64, copy=False), np.floor(uv[:, 1]).astype(np.int64, copy=False)
        seen = (z > 0) & (col >= 0) & (col < frame.width) & (row >= 0) & (row < frame.height)
        image = rng.read(frame.image)
        total[seen] += image[row[seen], col[seen]]
        count[seen] += 1
    return np.where(count > 0, total / np.maximum(count, 1), 0.5).astype(np.float32)


def random_view_volume_points(frames: List[ThermalFrame], num: int, seed: int = 0) -> np.ndarray:
    """[num, 3] points on random pixels' rays of random training cameras, at depths uniform in
    [0.1, 2] x the cameras' spread (the distance scale of the capture)."""
    generator = np.random.default_rng(seed)
    centres = np.stack([f.camera_to_world[:3, 3] for f in frames])
    spread = float(np.linalg.norm(centres - centres.mean(0), axis=1).max()) if len(frames) > 1 else 1.0
    spread = spread if spread > 1e-6 else 1.0
    which = generator.integers(0, len(frames), num)
    points = np.empty((num, 3))
    for i, frame in enumerate(frames):
        mask = which == i
        n = int(mask.sum())
        u, v = generator.uniform(0, frame.width, n), generator.uniform(0, frame.height, n)
        rays = np.stack([(u - frame.cx) / frame.fx, (v - frame.cy) / frame.fy, np.ones(n)], -1)
        depth = generator.uniform(0.1, 2.0, n) * spread
        points[mask] = (rays * depth[:, None]) @ frame.camera_to_world[:3, :3].T + frame.camera_to_world[:3, 3]
    return points


@dataclass
class ThermalDemoDataParserConfig(ThermalDataParserConfig):
    """The embedded procedural thermal scene (generated into `data` on first use)."""

    _target: Type = field(default_factory=lambda: ThermalDemo)
    data: Path = DEMO_SCENE_DIR
    """Where the demo scene is generated (and read from)."""
    layout: LayoutName = "nerfstudio"
    scene: SceneName = "demo"
    """'demo', or a stress scene: the same content with one fault ('all': every fault; 'clean': none);
    'survey': a synthetic drone survey of `survey_frames` frames (`survey_scene.py`)."""
    survey_frames: int = 250
    """Frames of the synthetic survey (scene 'survey'): its site grows with them."""


class ThermalDemo(ThermalDataParser):
    config: ThermalDemoDataParserConfig

    def capture(self) -> ThermalCapture:
        scene = self.config.scene
        if scene == "survey":
            generate_survey_scene(self.config.data, SurveySceneConfig(num_frames=self.config.survey_frames))
        else:
            generate_demo_scene(self.config.data, DemoSceneConfig() if scene == "demo" else stress_scene_config(scene))
        return super().capture()


def _spec(layout: str, description: str) -> DataParserSpecification:
    return DataParserSpecification(config=ThermalDataParserConfig(layout=layout), description=description)  # type: ignore[arg-type]


thermal_dataparser = _spec("auto", "any supported thermal layout, detected (says which it chose)")
thermal_nerfstudio_dataparser = _spec("nerfstudio", layouts.LAYOUTS["nerfstudio"].description)
thermalnerf_dataparser = _spec("thermalnerf", layouts.LAYOUTS["thermalnerf"].description)
ye_dataparser = _spec("ye", layouts.LAYOUTS["ye"].description)
msx_dataparser = _spec("msx", layouts.LAYOUTS["msx"].description)
thermalmix_dataparser = _spec("thermalmix", layouts.LAYOUTS["thermalmix"].description)
mvtv_dataparser = _spec("mvtv", layouts.LAYOUTS["mvtv"].description)
llff_dataparser = _spec("llff", layouts.LAYOUTS["llff"].description)
colmap_dataparser = _spec("colmap", layouts.LAYOUTS["colmap"].description)
ti_nsd_dataparser = _spec("ti-nsd", layouts.LAYOUTS["ti-nsd"].description)
metashape_dataparser = _spec("metashape", layouts.LAYOUTS["metashape"].description)
odm_dataparser = _spec("odm", layouts.LAYOUTS["odm"].description)
exif_gps_dataparser = _spec("exif-gps", layouts.LAYOUTS["exif-gps"].description)
thermal_demo_dataparser = DataParserSpecification(
    config=ThermalDemoDataParserConfig(),
    description="the embedded procedural thermal demo scene (generated, no download)",
)
