"""Thermal dataset and datamanager: single-channel float frames, normalised per dataset."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Type

import numpy as np
import torch
from nerfstudio.data.datamanagers.full_images_datamanager import FullImageDatamanager, FullImageDatamanagerConfig
from nerfstudio.configs.dataparser_configs import AnnotatedDataParserUnion
from nerfstudio.data.datasets.base_dataset import InputDataset

from thermal_wild_ns.data.dataparsers import ThermalDemoDataParserConfig
from thermal_wild_ns.data.thermal_io import RadiometricRange


class ThermalDataset(InputDataset):
    """Frames as float32 [H, W, 1] in the dataset's normalised radiometric scale (no 8-bit rounding)."""

    @property
    def thermal_range(self) -> RadiometricRange:
        value = self.metadata.get("thermal_range")
        if not isinstance(value, RadiometricRange):
            raise ValueError("ThermalDataset needs a thermal dataparser (metadata['thermal_range'] is missing)")
        return value

    def get_numpy_image(self, image_idx: int) -> np.ndarray:
        image = self.thermal_range.read(self._dataparser_outputs.image_filenames[image_idx])
        if self.scale_factor != 1.0:
            import cv2

            h, w = image.shape
            image = cv2.resize(image, (int(w * self.scale_factor), int(h * self.scale_factor)), interpolation=cv2.INTER_AREA)
        return image[..., None]

    def get_image_float32(self, image_idx: int) -> torch.Tensor:
        return torch.from_numpy(self.get_numpy_image(image_idx))

    def get_image_uint8(self, image_idx: int) -> torch.Tensor:
        raise ValueError("Thermal frames are float radiometric data; use cache_images_type='float32'")

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


class ThermalDatamanager(FullImageDatamanager[ThermalDataset]):
    """nerfstudio's full-image datamanager over `ThermalDataset`."""

    config: ThermalDatamanagerConfig

    def _load_images(self, split, cache_images_device):
        images = super()._load_images(split, cache_images_device)
        for cache in images:  # OpenCV's undistortion returns [H, W] for a 1-channel frame
            if cache["image"].ndim == 2:
                cache["image"] = cache["image"][..., None]
        return images
