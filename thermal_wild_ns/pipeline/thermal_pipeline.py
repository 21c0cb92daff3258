"""VanillaPipeline whose evaluation (`ns-eval`, and nerfstudio's all-image evaluations during
training) follows the benchmark's protocol (`analysis/evaluation.py`): metrics in the original
radiometric space, with a stated held-out embedding mode."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Type

import numpy as np
from nerfstudio.pipelines.base_pipeline import VanillaPipeline, VanillaPipelineConfig

from thermal_wild_ns.analysis.evaluation import EmbeddingMode


@dataclass
class ThermalPipelineConfig(VanillaPipelineConfig):
    _target: Type = field(default_factory=lambda: ThermalPipeline)
    eval_embedding: EmbeddingMode = "interpolate"
    """Held-out frame embedding for evaluation: 'interpolate' (between the neighbouring training
    frames in capture order), 'fixed' (the inference embedding every rendered novel view uses) or
    'wild' (optimised on the left half, right half scored). 'interpolate' beat 'fixed' in 11 of the
    13 committed GPU runs with frame embeddings (results/; README): a held-out frame shares its
    neighbours' drift."""


def colour_bar(datamanager, ticks: int = 5) -> str:
    """The data values at evenly spaced points of the colormap: the model's [0, 1] training space
    mapped back through the median training LUT to the dataset's range, in degC where the dataset
    documents its temperature bounds, else in native units."""
    rng = datamanager.train_dataset.thermal_range
    levels = datamanager.novel_view_to_original(np.linspace(0.0, 1.0, ticks, dtype=np.float32))
    if rng.celsius_low is not None and rng.celsius_high is not None:
        return ", ".join(f"{v:.1f}" for v in rng.to_celsius(levels)) + " degC"
    return ", ".join(f"{v:.0f}" for v in rng.to_native(levels)) + f" ({rng.dtype} levels)"


class ThermalPipeline(VanillaPipeline):
    config: ThermalPipelineConfig

    def __init__(self, config: ThermalPipelineConfig, *args, **kwargs):
        super().__init__(config, *args, **kwargs)
        bar = getattr(self.model, "viewer_colour_bar", None)
        if bar is not None:
            bar.value = f"{self.model.config.colormap} 0->1: {colour_bar(self.datamanager)}"

    def get_average_eval_image_metrics(self, step: Optional[int] = None, output_path: Optional[Path] = None, get_std: bool = False):
        from thermal_wild_ns.analysis.evaluation import evaluate

        result = evaluate(self, self.config.eval_embedding, out_dir=output_path)
        rows = result["per_view"]
        metrics = {key: value for key, value in result.items() if isinstance(value, float)}
        if get_std:
            metrics.update({f"{key}_std": float(np.std([r[key] for r in rows])) for key in list(metrics)})
        metrics.update(
            {
                "embedding_mode": self.config.eval_embedding,
                "space": "original radiometric (dataset-normalised); *_preprocessed: the model's training space; "
                "*_median_lut: mapped back through the median training LUT, as a novel view is",
                "views": len(rows),
                "gaussians": result["gaussians"],
            }
        )
        self.train()
        return metrics
