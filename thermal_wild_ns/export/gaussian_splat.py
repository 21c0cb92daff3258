"""`wild-thermal-export gaussian-splat`: ns-export's Gaussian-splat PLY, with the thermal values.

ns-export already writes this plugin's Gaussians (the baked emission as grey in the DC colour
fields, so standard splat viewers show a grey scene). This command is ns-export's own
`gaussian-splat` (same options) and adds to the PLY:
- a float vertex property `thermal`: each Gaussian's baked emission (fixed frame embedding)
  mapped back through the median training LUT to the dataset's native units;
- header comments: the frame embedding the emission was baked with, the units of `thermal`,
  the dataset's native range and its temperature bounds where documented.
ns-export drops NaN and transparent Gaussians before writing; the kept rows are found by their
positions, which it copies unchanged and in order.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import List

import numpy as np
import torch

from thermal_wild_ns._upstream import gaussian_splat_export_hooks, nerfstudio_exporter
from thermal_wild_ns.data.celsius import DjiCalibration
from thermal_wild_ns.pipeline.photometric_state import canonical_state, to_original
from thermal_wild_ns.pipeline.run_check import check_trained_run
from thermal_wild_ns.state_names import CANONICAL


def _kept_rows(means: np.ndarray, exported: np.ndarray) -> np.ndarray:
    """Indices into `means` [N, 3] of the exported positions [M, 3] (an ordered subset)."""
    kept, j = np.empty(len(exported), dtype=np.int64), 0
    for i, row in enumerate(exported):
        while not np.array_equal(means[j], row):
            j += 1
        kept[i], j = j, j + 1
    return kept


def canonical_emission(pipeline) -> np.ndarray:
    """Baked emission of every Gaussian at the canonical state, dataset-normalised original space [N]."""

    model = pipeline.model
    state = canonical_state(pipeline)
    with torch.no_grad():
        emission = model.gaussian_emission(model.state_embedding(CANONICAL))
        emission = model.parts.emission.radiance(emission)[:, 0].float().cpu().numpy()
    return to_original(pipeline, emission, state)


def thermal_values(pipeline) -> np.ndarray:
    """Baked emission of every Gaussian at the canonical state, in the dataset's native units [N]."""
    rng = pipeline.datamanager.train_dataset.thermal_range
    return rng.to_native(canonical_emission(pipeline)).astype(np.float32)


def header_comments(pipeline) -> List[str]:
    rng = pipeline.datamanager.train_dataset.thermal_range
    lines = [
        f"frame_embedding canonical ({pipeline.model.config.canonical_embedding}; the emission MLP was baked with "
        f"this frame embedding)",
        f"thermal: baked emission in native units ({rng.dtype}) at the canonical photometric state (median training "
        f"LUT)",
        "f_dc_0..2: the same emission as grey in the training space, clamped to [0, 1]",
        f"native_range {rng.low:g} {rng.high:g}",
    ]
    if isinstance(rng.planck, DjiCalibration):
        lines.append(f"celsius_table {len(rng.planck.raw)} entries of native units -> degC ({rng.planck.source})")
    elif rng.planck is not None:
        cal = rng.planck
        lines.append(
            f"celsius_planck R1 {cal.planck_r1:g} R2 {cal.planck_r2:g} B {cal.planck_b:g} F {cal.planck_f:g} "
            f"O {cal.planck_o:g} emissivity {cal.emissivity:g} distance {cal.object_distance:g} (of native units)"
        )
    elif rng.celsius_low is not None and rng.celsius_high is not None:
        lines.append(f"celsius_range {rng.celsius_low:g} {rng.celsius_high:g} (at native_range, linear)")
    return [f"thermal_wild_ns {line}" for line in lines]


@dataclass
class ExportThermalSplat(nerfstudio_exporter().ExportGaussianSplat):
    """ns-export gaussian-splat, plus a `thermal` property and header comments."""

    def main(self) -> None:
        check_trained_run(self.load_config)  # before ns-export creates the output folder

        loaded = {}

        def add_thermal(map_to_tensors):
            pipeline = loaded["pipeline"]
            means = pipeline.model.means.detach().cpu().numpy()
            exported = np.concatenate(
                [map_to_tensors[k][:, None] if map_to_tensors[k].ndim == 1 else map_to_tensors[k] for k in "xyz"], 1
            )
            map_to_tensors["thermal"] = thermal_values(pipeline)[_kept_rows(means, exported)]

        with gaussian_splat_export_hooks(
            lambda pipeline: loaded.update(pipeline=pipeline), add_thermal, lambda: header_comments(loaded["pipeline"])
        ):
            super().main()
