"""Thermal dataparsers for nerfstudio.

`thermal-nerfstudio-data`: a nerfstudio `transforms.json` capture of single-channel thermal
frames (8/16-bit or float), e.g. `../shared/data/dunr`. Poses, intrinsics and splits are read by
nerfstudio's own parser; this subclass adds what thermal data needs:
- the dataset-level radiometric range (`metadata["thermal_range"]`), from the transforms'
  `thermal` block if present, otherwise measured over all frames (percentiles 0.1 / 99.9);
- clean ground-truth frames for evaluation where frames carry `gt_file_path` (the demo scene);
- seed points from a `.ply` with a `thermal` (native units) or grey colour property, read
  with plyfile (nerfstudio's reader needs open3d);
- a default split of every 8th frame held out (`eval_mode='interval'`).

`thermal-demo-data`: the same parser whose default data is the embedded procedural scene,
generated on first use (see `demo_scene.py`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Optional, Type

import numpy as np
import torch
from nerfstudio.data.dataparsers.nerfstudio_dataparser import Nerfstudio, NerfstudioDataParserConfig
from nerfstudio.plugins.registry_dataparser import DataParserSpecification

from thermal_wild_ns.data.demo_scene import generate_demo_scene
from thermal_wild_ns.data.thermal_io import RadiometricRange, measure_range

DEMO_SCENE_DIR = Path("outputs/thermal-demo-scene")


@dataclass
class ThermalNerfstudioDataParserConfig(NerfstudioDataParserConfig):
    """nerfstudio transforms.json with single-channel thermal frames."""

    _target: Type = field(default_factory=lambda: ThermalNerfstudio)
    downscale_factor: Optional[int] = 1
    """Thermal frames are small; never downscale unless asked."""
    eval_mode: Literal["fraction", "filename", "interval", "all"] = "interval"
    """Held-out split when transforms.json has no explicit one: every `eval_interval`-th frame."""
    eval_interval: int = 8
    """Every n-th frame is held out for evaluation."""
    load_3D_points: bool = True
    """Seed Gaussians from the transforms' point cloud (ply_file_path) when there is one."""
    range_percentiles: tuple[float, float] = (0.1, 99.9)
    """Percentiles of all pixels of all frames that map to 0 and 1 when the data has no declared range."""


class ThermalNerfstudio(Nerfstudio):
    config: ThermalNerfstudioDataParserConfig

    def _transforms(self) -> tuple[dict, Path]:
        path = self.config.data if self.config.data.suffix == ".json" else self.config.data / "transforms.json"
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no transforms.json (nerfstudio layout) in the thermal data folder")
        with open(path) as f:
            return json.load(f), path.parent

    def radiometric_range(self) -> RadiometricRange:
        """Dataset-level range: declared in transforms.json, or measured over every frame once."""
        if getattr(self, "_range", None) is None:
            meta, data_dir = self._transforms()
            declared = meta.get("thermal")
            if declared and "low" in declared and "high" in declared:
                self._range = RadiometricRange(**{k: declared.get(k) for k in RadiometricRange.__dataclass_fields__})
            else:
                paths = [data_dir / frame["file_path"] for frame in meta["frames"]]
                self._range = measure_range(paths, self.config.range_percentiles)
        return self._range

    def _generate_dataparser_outputs(self, split="train"):
        outputs = super()._generate_dataparser_outputs(split)
        meta, data_dir = self._transforms()
        outputs.metadata["thermal_range"] = self.radiometric_range()
        if split != "train":
            # evaluate against clean ground truth where the capture provides it
            gt = {
                (data_dir / f["file_path"]).resolve(): data_dir / f["gt_file_path"]
                for f in meta["frames"]
                if "gt_file_path" in f
            }
            outputs.image_filenames = [gt.get(Path(p).resolve(), p) for p in outputs.image_filenames]
        return outputs

    def _load_3D_points(self, ply_file_path: Path, transform_matrix: torch.Tensor, scale_factor: float):
        from plyfile import PlyData

        vertex = PlyData.read(str(ply_file_path))["vertex"]
        if len(vertex) == 0:
            return None
        xyz = torch.from_numpy(np.stack([vertex[a] for a in ("x", "y", "z")], -1).astype(np.float32))
        xyz = torch.cat([xyz, torch.ones_like(xyz[:, :1])], -1) @ transform_matrix.T * scale_factor
        names = vertex.data.dtype.names
        if "thermal" in names:
            value = self.radiometric_range().normalize(np.asarray(vertex["thermal"]))
        elif "red" in names:
            value = np.asarray(vertex["red"], dtype=np.float32) / 255.0
        else:
            value = np.full(len(vertex), 0.5, dtype=np.float32)
        grey = torch.from_numpy((np.clip(value, 0, 1) * 255).astype(np.uint8))[:, None].repeat(1, 3)
        return {"points3D_xyz": xyz, "points3D_rgb": grey}


@dataclass
class ThermalDemoDataParserConfig(ThermalNerfstudioDataParserConfig):
    """The embedded procedural thermal scene (generated into `data` on first use)."""

    _target: Type = field(default_factory=lambda: ThermalDemo)
    data: Path = DEMO_SCENE_DIR
    """Where the demo scene is generated (and read from)."""


class ThermalDemo(ThermalNerfstudio):
    config: ThermalDemoDataParserConfig

    def _generate_dataparser_outputs(self, split="train"):
        generate_demo_scene(self.config.data)
        return super()._generate_dataparser_outputs(split)


thermal_nerfstudio_dataparser = DataParserSpecification(
    config=ThermalNerfstudioDataParserConfig(), description="nerfstudio transforms.json of single-channel thermal frames"
)
thermal_demo_dataparser = DataParserSpecification(
    config=ThermalDemoDataParserConfig(), description="the embedded procedural thermal demo scene (generated, no download)"
)
