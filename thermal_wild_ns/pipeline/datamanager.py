"""Thermal dataset and datamanager: single-channel float frames, normalised per dataset."""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Dict, List, Optional, Tuple, Type

import cv2
import numpy as np
import torch
import tyro
from nerfstudio.cameras.cameras import Cameras
from nerfstudio.configs.dataparser_configs import AnnotatedDataParserUnion
from nerfstudio.data.datamanagers.full_images_datamanager import FullImageDatamanagerConfig
from nerfstudio.data.dataparsers.base_dataparser import DataparserOutputs
from nerfstudio.data.datasets.base_dataset import InputDataset
from nerfstudio.utils.rich_utils import CONSOLE

from thermal_wild_ns._upstream import SingleChannelFullImageDatamanager, undistorted_as_cached
from thermal_wild_ns.data.content_motion import content_motion
from thermal_wild_ns.data.dataparsers import ThermalDemoDataParserConfig
from thermal_wild_ns.data.thermal_io import RadiometricRange
from thermal_wild_ns.decisions import Decision
from thermal_wild_ns.errors import InputError
from thermal_wild_ns.pipeline.ranks import RankGroup
from thermal_wild_ns.preprocessing.photometric import PREPROCESSING_FLAG, PhotometricConfig
from thermal_wild_ns.preprocessing.stage import PreprocessedSequence, preprocess

NOT_PREPROCESSED = "none (variant)"
"""`ThermalDatamanager.preprocessing_used` of a method that never preprocesses (variant 'none')."""


class ThermalDataset(InputDataset):
    """Frames as float32 [H, W, 1] in the dataset's normalised radiometric scale (no 8-bit rounding)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._recorded: Dict[int, np.ndarray] = {}  # see `recorded_image`

    @property
    def thermal_range(self) -> RadiometricRange:
        value = self.metadata.get("thermal_range")
        if not isinstance(value, RadiometricRange):
            raise InputError("ThermalDataset needs a thermal dataparser (metadata['thermal_range'] is missing)")
        return value

    def frame_index(self, image_idx: int) -> int:
        """Capture-order index of this image (what frame embeddings and preprocessing LUTs use)."""
        return int(self.metadata["frame_indices"][image_idx])

    def get_metadata(self, data: Dict) -> Dict:
        return {"frame_index": torch.tensor(self.frame_index(data["image_idx"]))}

    def get_numpy_image(self, image_idx: int) -> np.ndarray:
        sequence: Optional[PreprocessedSequence] = self.metadata.get("preprocessed")
        if sequence is not None:  # training frames of preprocessed methods
            image = self._scaled(sequence.read_frame(self.frame_index(image_idx)))
        else:  # raw frames (held-out views are always read raw: they are never preprocessed)
            image = self.original_image(image_idx)
        return np.repeat(image[..., None], 3, axis=-1) if self.metadata.get("grey_rgb") else image[..., None]

    def original_image(self, image_idx: int) -> np.ndarray:
        """The image file as captured [H, W] float32, in the dataset-normalised radiometric scale (never
        preprocessed), at the dataset's scale factor, not yet undistorted: what nerfstudio's cache
        undistorts (`recorded_image` is a frame in the geometry the model renders)."""
        return self._read(self._dataparser_outputs.image_filenames[image_idx])

    def _read(self, path: Path) -> np.ndarray:
        return self._scaled(self.thermal_range.read(path))

    def is_clean_truth(self, image_idx: int) -> bool:
        """Whether this image is a generated scene's clean truth (a held-out view no camera recorded)
        rather than a frame as the camera recorded it (`recorded_image`)."""
        flags = self.metadata.get("is_ground_truth")
        return bool(flags[image_idx]) if flags is not None else False

    def recorded_image(self, image_idx: int) -> np.ndarray:
        """The frame as the camera recorded it [H, W] (dataset-normalised, never preprocessed), in the
        geometry the model renders: scaled and undistorted as the cached images are. It is the cached
        image itself except for a preprocessed training frame and for a held-out view of a capture with
        clean ground truth (generated scenes), whose image is that truth while the camera recorded the
        view under its sensor state of the moment (drift, gain, faults). Read once per image."""
        if image_idx not in self._recorded:
            files = self.metadata.get("recorded_filenames") or self._dataparser_outputs.image_filenames
            camera = copy.deepcopy(self._dataparser_outputs.cameras[image_idx : image_idx + 1])  # as captured
            camera.rescale_output_resolution(self.scale_factor)
            self._recorded[image_idx] = undistorted_as_cached(camera.reshape(()), self._read(files[image_idx]))
        return self._recorded[image_idx]

    def _scaled(self, image: np.ndarray) -> np.ndarray:
        if self.scale_factor == 1.0:
            return image

        h, w = image.shape
        return cv2.resize(image, (int(w * self.scale_factor), int(h * self.scale_factor)), interpolation=cv2.INTER_AREA)

    def get_image_float32(self, image_idx: int) -> torch.Tensor:
        return torch.from_numpy(self.get_numpy_image(image_idx))

    def get_image_uint8(self, image_idx: int) -> torch.Tensor:
        raise InputError("Thermal frames are float radiometric data; use cache_images_type='float32'")

    def __getitem__(self, image_idx: int) -> dict:
        """A display copy for nerfstudio's viewer, which draws `dataset[idx]["image"]` as RGB
        thumbnails: grey, 3 channels, clipped to [0, 1]. Training reads `get_data` (1 channel)."""
        data = self.get_data(image_idx)
        data["image"] = data["image"].clamp(0.0, 1.0).expand(-1, -1, 3)
        return data


@dataclass
class ThermalDatamanagerConfig(FullImageDatamanagerConfig):
    """Full-image datamanager for single-channel thermal frames."""

    _target: Type = field(default_factory=lambda: ThermalDatamanager)
    dataparser: AnnotatedDataParserUnion = field(default_factory=ThermalDemoDataParserConfig)
    """Which thermal layout to read (a subcommand: `thermal`, `msx-data`, ...); default: the embedded demo scene."""
    cache_images_type: str = "float32"  # type: ignore[assignment]
    """Thermal frames stay float32 (never re-quantised to 8 bit)."""
    preprocessing: PhotometricConfig = field(default_factory=PhotometricConfig)
    """Photometric stabilization / contrast enhancement applied once at setup (variant 'none' to skip)."""
    preprocessing_cache: Path = Path("outputs/.thermal_cache")
    """Where processed frames and LUTs are cached (keyed by data and parameters)."""
    grey_rgb: bool = False
    """Give frames as 3 equal channels, for RGB models (stock splatfacto as a baseline)."""
    host_cameras: bool = True
    """Hand each training camera to the model on the host, where it reads the image size and
    intrinsics without a GPU round trip (a host sync per read). Off for models that need their
    cameras on the device (stock splatfacto)."""
    train_order_seed: int = 0
    """Training frames are visited in a fresh permutation per pass, drawn from (this seed, pass
    number): the order is a function of the step, so a resumed run sees what the uninterrupted one would."""
    distributed: tyro.conf.Suppress[bool] = False
    """Set by the multi-GPU launcher (`training/distributed.py`): each step trains one image per rank of
    torch.distributed's process group, consecutive in the order (`RankGroup.image_slot`)."""


class ThermalDatamanager(SingleChannelFullImageDatamanager):
    """nerfstudio's full-image datamanager over `ThermalDataset`, with the preprocessing stage:
    the chosen variant runs once over the whole capture (capture order) before caching images."""

    config: ThermalDatamanagerConfig

    def __init__(self, config: ThermalDatamanagerConfig, *args, **kwargs):
        if config.train_cameras_sampling_strategy != "random":
            raise InputError(
                f"train_cameras_sampling_strategy '{config.train_cameras_sampling_strategy}' is not supported by "
                f"the thermal "
                "datamanager: it visits the training frames in a seeded random order per pass (train_order_seed), "
                "so that a "
                "resumed run sees what the uninterrupted one would"
            )
        super().__init__(config, *args, **kwargs)
        self.ranks = RankGroup.current() if config.distributed else RankGroup()
        self._training_cameras: Dict[int, Cameras] = {}  # with host_cameras: built once per training image

    @cached_property
    def preprocessed(self) -> Optional[PreprocessedSequence]:
        """LUTs and processed training frames (None for variant 'none', or where `skip_when_stable`
        finds the capture stable). Only training frames shape the stabilization reference; held-out
        frames are never preprocessed for training or scoring."""
        config = self.config.preprocessing
        if config.variant == "none":
            self.preprocessing_used = NOT_PREPROCESSED
            return None
        capture = self.dataparser.capture()
        train = set(self.train_dataparser_outputs.metadata["frame_indices"])
        sequence = preprocess(
            capture.frames,
            self.dataparser.radiometric_range(),
            config,
            self.config.preprocessing_cache,
            train=[t in train for t in range(len(capture.frames))],
        )
        decision = sequence.decision()
        if config.skip_when_stable and not decision.pays:
            self.preprocessing_used = f"none: {decision.reason}"
            CONSOLE.log(f"Preprocessing skipped, {decision.reason}: training on the raw frames")
            return None
        self.preprocessing_used = f"{config.variant}: {decision.reason}"
        return sequence

    preprocessing_used: str = ""
    """What the training frames went through, and why (set with `preprocessed`)."""

    def decisions(self) -> List[Decision]:
        """The preprocessing of this capture and why (`preprocessed` decides): by the data where the
        method lets its stability rule measure the capture (`skip_when_stable`), else by the config."""
        _ = self.preprocessed  # decides on first use
        config = self.config.preprocessing
        variant, _, reason = self.preprocessing_used.partition(": ")
        by_rule = config.variant != "none" and config.skip_when_stable
        entries = [
            Decision(
                "preprocessing",
                variant,
                reason or f"training on the raw frames ({PREPROCESSING_FLAG} stab+bbhe preprocesses them)",
                "data" if by_rule else "config",
            )
        ]
        settings_of = getattr(self.dataparser, "measurement_settings", None)
        if settings_of is not None and self.dataparser.radiometric_range().planck is not None:
            settings = settings_of()  # a camera's own calibration: each frame's °C at these settings
            given = bool(settings.given())
            why = (
                "the dataparser's options" if given else "each file's own (the dataparser's --emissivity ... override)"
            )
            entries.append(Decision("°C measurement settings", settings.describe(), why, "config" if given else "data"))
        return entries

    def _with_metadata(self, outputs: DataparserOutputs, preprocessed: bool) -> DataparserOutputs:
        outputs.metadata["preprocessed"] = self.preprocessed if preprocessed else None
        outputs.metadata["grey_rgb"] = self.config.grey_rgb
        # what tells the camera's fixed pattern from the scene (the model's `camera_pattern_min_motion`, which
        # reads the training split's: `preprocessed` marks it)
        motion = content_motion(outputs.cameras, outputs.metadata.get("points3D_xyz")) if preprocessed else None
        outputs.metadata["content_motion"] = motion
        return outputs

    held_back: Tuple[int, ...] = ()
    """Training images kept out of the gradient (set by the trainer's automatic stop, which scores
    the model on them)."""

    def hold_back(self, images: Tuple[int, ...]) -> None:
        self.held_back = tuple(sorted(images))
        self._order = (None, [])

    def held_back_truth(self, image: int) -> np.ndarray:
        """A held-back training image as captured [H, W], in the geometry the model renders
        (`ThermalDataset.recorded_image`)."""
        return self.train_dataset.recorded_image(image)

    def train_order(self, epoch: int) -> List[int]:
        """The permutation of the trained images (all but `held_back`) for pass `epoch` (a function
        of the seed, the pass and the held-back images only)."""
        if getattr(self, "_order", (None,))[0] != epoch:
            trained = [k for k in range(len(self.train_dataset)) if k not in self.held_back]
            permutation = np.random.default_rng([self.config.train_order_seed, epoch]).permutation(len(trained))
            self._order = (epoch, [trained[k] for k in permutation])
        return self._order[1]

    def next_train(self, step: int):
        """The training image of `step` (a function of the step alone, so a resumed run sees what
        the uninterrupted one would) and its camera, as nerfstudio's `next_train` gives them."""
        return self._train_at(self.ranks.image_slot(step))

    def next_train_cameras(self, step: int, count: int) -> List[Tuple[Cameras, Dict]]:
        """The `count` training images of a step that trains several at once, on one GPU
        (`ThermalPipelineConfig.cameras_per_step`): the next `count` of the order, as `next_train`."""
        return [self._train_at(step * count + k) for k in range(count)]

    def _train_at(self, slot: int) -> Tuple[Cameras, Dict]:
        """The image at position `slot` of the sequence of training images (a fresh permutation per pass)."""
        epoch, position = divmod(slot, len(self.train_dataset) - len(self.held_back))
        image_idx = self.train_order(epoch)[position]
        data = dict(self.cached_train[image_idx])  # a copy: the cached dictionary is never changed
        data["image"] = data["image"].to(self.device)
        return self.training_camera(image_idx), data

    def training_camera(self, image_idx: int) -> Cameras:
        """Training image `image_idx`'s camera with `metadata['cam_idx']`: on the host (undistorted)
        with `host_cameras`, else on the device. The plugin's model never changes a camera, so each
        is built once; other models (stock splatfacto rescales its camera in place and back, which
        floors odd image sizes) get a fresh one per step."""
        if self.config.host_cameras:
            cached = self._training_cameras.get(image_idx)
            if cached is None:
                cached = self.train_dataset.cameras[image_idx : image_idx + 1]
                cached.metadata = {**(cached.metadata or {}), "cam_idx": image_idx}
                self._training_cameras[image_idx] = cached
            return cached
        camera = self.train_cameras[image_idx : image_idx + 1].to(self.device)
        camera.metadata = {**(camera.metadata or {}), "cam_idx": image_idx}
        return camera

    def create_train_dataset(self) -> ThermalDataset:
        return ThermalDataset(
            self._with_metadata(self.train_dataparser_outputs, True), scale_factor=self.config.camera_res_scale_factor
        )

    def create_eval_dataset(self) -> ThermalDataset:
        outputs = self._with_metadata(self.dataparser.get_dataparser_outputs(split=self.test_split), False)
        return ThermalDataset(outputs, scale_factor=self.config.camera_res_scale_factor)
