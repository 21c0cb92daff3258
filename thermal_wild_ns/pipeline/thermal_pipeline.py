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
    eval_embedding: EmbeddingMode = "fixed"
    """Held-out frame embedding for evaluation: 'fixed' (the inference embedding), 'interpolate'
    (between the neighbouring training frames) or 'wild' (optimised on the left half, right half scored)."""


class ThermalPipeline(VanillaPipeline):
    config: ThermalPipelineConfig

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
                "space": "original radiometric (dataset-normalised); *_preprocessed: the model's training space",
                "views": len(rows),
                "gaussians": result["gaussians"],
            }
        )
        self.train()
        return metrics
