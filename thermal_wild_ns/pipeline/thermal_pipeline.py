"""VanillaPipeline whose evaluations (`ns-eval`, and nerfstudio's evaluations during training)
follow the benchmark's protocols (`pipeline/evaluation.py`): scores in the original radiometric
space, held-out frames at their predicted photometric state, never through their own pixels."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Dict, List, Optional, Protocol, Sequence, Tuple, Type, runtime_checkable

import numpy as np
import torch
from nerfstudio.cameras.cameras import Cameras
from nerfstudio.pipelines.base_pipeline import VanillaPipeline, VanillaPipelineConfig
from nerfstudio.utils import profiler
from torch import Tensor

from thermal_wild_ns._upstream import prepare_checkpoint_commands
from thermal_wild_ns.data.dataparsers import ThermalDataParser
from thermal_wild_ns.errors import InputError, MissingInput, report_input_errors_briefly
from thermal_wild_ns.pipeline.evaluation import evaluate, scores
from thermal_wild_ns.pipeline.photometric_state import PhotometricState, canonical_state, render, state_at, to_original
from thermal_wild_ns.pipeline.run_check import PARTIAL_FOLDER, check_checkpoint, write_text_atomically

DATA_RECORD = "data.json"
"""Beside a run's config: what the run was trained on (`ThermalPipeline._record_or_check_data`)."""


@runtime_checkable
class ViewerControlledModel(Protocol):
    """A model with the thermal viewer controls (`rendering.viewer_controls.ThermalViewerControls`):
    the pipeline keeps their colour bar in step with the state they choose."""

    viewer_controls: "ThermalViewerControlsLike"


class ThermalViewerControlsLike(Protocol):
    capture_time: Optional[float]
    colormap: str

    def on_state_change(self, listener: Callable[[], None]) -> None: ...

    def show_colour_bar(self, text: str) -> None: ...


@runtime_checkable
class SeveralCamerasModel(Protocol):
    """A model that renders several training cameras per step (`WildThermalModel`)."""

    def get_training_outputs(self, cameras: Sequence[Cameras]) -> List[Dict]: ...

    def get_training_metrics_and_losses(
        self, outputs: Sequence[Dict], batches: Sequence[Dict], metrics: bool = True
    ) -> Tuple[Dict[str, Tensor], Dict[str, Tensor]]: ...


@dataclass
class ThermalPipelineConfig(VanillaPipelineConfig):
    _target: Type = field(default_factory=lambda: ThermalPipeline)
    eval_fit_steps: int = 100
    """Optimisation steps per held-out view of the `half` and `oracle` protocols (their frame
    embedding fit); 0 scores them without fitting an embedding."""
    eval_fit_views: int = 8
    """Held-out views whose fits step together, one render of them all per step (one rasterization on a GPU);
    each view's fit ends where it would alone. Fewer: less memory."""
    checkpoint_dir: Optional[Path] = None
    """Where the run keeps its checkpoints, recorded when its config is saved, so that ns-eval,
    ns-render and ns-viewer can find a run without checkpoints before they read any data."""
    cameras_per_step: int = 1
    """Training frames per step, rendered together in one rasterization and their losses averaged:
    the step's fixed costs (launches, sorting, the Python around them) are paid once for all of them.
    The schedule counts training frames (`--max-num-iterations`, densification, the automatic stop's
    checks: the trainer runs them in 1/this many steps; the optimizers' settings are kept), so a run
    sees the frames a run of one camera per step sees at each point of its schedule. One GPU, frames
    of one size, the plugin's models only."""


def colour_bar(pipeline, state: PhotometricState, ticks: int = 5) -> str:
    """The data values at evenly spaced points of the colormap: the model's [0, 1] training space
    mapped back through `state`'s LUT to the dataset's range, in degC where the dataset documents
    its temperature bounds, else in native units."""

    rng = pipeline.datamanager.train_dataset.thermal_range
    levels = to_original(pipeline, np.linspace(0.0, 1.0, ticks, dtype=np.float32), state)
    if rng.has_celsius:
        return ", ".join(f"{v:.1f}" for v in rng.to_celsius(levels)) + " degC"
    return ", ".join(f"{v:.0f}" for v in rng.to_native(levels)) + f" ({rng.dtype} levels)"


class ThermalPipeline(VanillaPipeline):
    config: ThermalPipelineConfig

    def __init__(self, config: ThermalPipelineConfig, *args, **kwargs):
        # every nerfstudio command that loads a checkpoint of this plugin builds this pipeline first
        prepare_checkpoint_commands()
        report_input_errors_briefly()
        test_mode = kwargs.get("test_mode", args[1] if len(args) > 1 else "val")
        loads_a_run = test_mode in ("test", "inference")  # nerfstudio's eval_setup; training uses "val"
        if loads_a_run and config.checkpoint_dir is not None:
            check_checkpoint(config.checkpoint_dir)  # the one nerfstudio loads next: whole, or a clear error
        try:
            super().__init__(config, *args, **kwargs)
        except MissingInput as err:
            if not loads_a_run:
                raise
            raise MissingInput(
                f"{err}. This run was trained on {config.datamanager.dataparser.data}: where the data has moved, "
                f"set its new folder as `data:` in the run's config.yml"
            ) from None
        if config.checkpoint_dir is not None:
            self._record_or_check_data(Path(config.checkpoint_dir).parent / DATA_RECORD, loads_a_run)
        if config.cameras_per_step != 1:
            self._check_several_cameras(config.cameras_per_step)
        if isinstance(self.model, ViewerControlledModel):  # a thermal model (its ThermalViewerControls)
            self.model.viewer_controls.on_state_change(self.update_colour_bar)
            self.update_colour_bar()

    def train(self, mode: bool = True):
        """`nn.Module.train`, skipped where every module already is in `mode`: nerfstudio's training loop
        calls it before every step, and it sets an attribute on each of the pipeline's modules (host
        time in every step, for a flag that changes only around evaluations)."""
        if all(module.training == mode for module in self.modules()):
            return self
        return super().train(mode)

    def _check_several_cameras(self, count: int) -> None:
        """`cameras_per_step` above 1 needs a model that renders several cameras at once, one GPU and
        training frames of one size: else an error that says which."""
        why = None
        if count < 1:
            why = "it must be at least 1"
        elif not isinstance(self.model, SeveralCamerasModel):
            why = f"{type(self.model).__name__} renders one camera per step (the plugin's models render several)"
        elif self.datamanager.ranks.world > 1:
            why = "each GPU of a multi-GPU run trains its own frame per step"
        else:
            cameras = self.datamanager.train_dataset.cameras
            sizes = sorted({(int(w), int(h)) for w, h in zip(cameras.width.reshape(-1), cameras.height.reshape(-1))})
            if len(sizes) > 1:
                why = f"the training frames differ in size ({', '.join(f'{w}x{h}' for w, h in sizes)})"
        if why is not None:
            raise InputError(f"--pipeline.cameras-per-step {count}: {why}")

    @profiler.time_function
    def get_train_loss_dict(self, step: int, metrics: bool = True):
        """nerfstudio's step (one training frame), or `cameras_per_step` frames rendered together.
        `metrics`: whether the step's metrics (the training PSNR) are computed; nerfstudio's trainer logs
        them at its log steps alone, and the plugin's trainer asks for them there (a model that renders
        one camera per step computes them always)."""
        if not isinstance(self.model, SeveralCamerasModel):  # one camera a step (`_check_several_cameras`)
            return super().get_train_loss_dict(step)
        count = self.config.cameras_per_step
        if count == 1:  # VanillaPipeline's step (its `_model`: the model wrapped for several GPUs)
            camera, batch = self.datamanager.next_train(step)
            outputs = self._model(camera)
            metrics_dict, loss_dict = self.model.get_training_metrics_and_losses([outputs], [batch], metrics)
            return outputs, loss_dict, metrics_dict
        cameras, batches = zip(*self.datamanager.next_train_cameras(step, count))
        outputs = self.model.get_training_outputs(cameras)
        metrics_dict, loss_dict = self.model.get_training_metrics_and_losses(outputs, batches, metrics)
        return outputs, loss_dict, metrics_dict

    def _record_or_check_data(self, record: Path, loads_a_run: bool) -> None:
        """Training: record what the run is trained on (`ThermalDataParser.fingerprint`) beside its
        config. Loading a run (ns-eval, ns-render, the viewer): the data must be what it was, or the
        scores and renders would silently be of other frames."""
        parser = self.datamanager.dataparser
        if not isinstance(parser, ThermalDataParser):  # its data's fingerprint
            return
        now = {"data": str(parser.config.data), "frames": parser.fingerprint()}
        if not loads_a_run:
            georeference = parser.capture().georeference
            # where the run's world frame is on the Earth (before nerfstudio's dataparser transform,
            # dataparser_transforms.json beside it), for outputs that land where the site is
            now["georeference"] = None if georeference is None else georeference.as_dict()
            write_text_atomically(record, json.dumps(now, indent=1), record.parent / PARTIAL_FOLDER)
            return
        if not record.is_file():  # a run of an older version of the plugin: nothing to compare with
            return
        then = json.loads(record.read_text())
        if then["frames"] == now["frames"]:
            return
        gone = sorted(set(then["frames"]) - set(now["frames"]))
        new = sorted(set(now["frames"]) - set(then["frames"]))
        changed = sorted(k for k in set(then["frames"]) & set(now["frames"]) if then["frames"][k] != now["frames"][k])
        what = "; ".join(
            f"{label}: {', '.join(names[:5])}{' ...' if len(names) > 5 else ''}"
            for label, names in (("missing", gone), ("added", new), ("changed (pixels or camera)", changed))
            if names
        )
        raise InputError(
            f"{now['data']}: the data changed since this run was trained on it ({then['data']}): {what}. "
            f"Scores and renders would be of other frames: train again, or restore the data (the run's record: "
            f"{record})"
        )

    def viewer_state(self) -> PhotometricState:
        """The state the viewer renders at: canonical, or its capture-time slider's."""
        t = self.model.viewer_controls.capture_time
        return canonical_state(self) if t is None else state_at(self, t)

    def update_colour_bar(self) -> None:
        state = self.viewer_state()
        controls = self.model.viewer_controls
        controls.show_colour_bar(f"{controls.colormap} 0->1 at {state.label}: {colour_bar(self, state)}")

    @torch.no_grad()
    def get_eval_image_metrics_and_images(self, step: int):
        """One held-out view during training (nerfstudio's eval image): scored at its `time` state
        in the original space against the frame as recorded, like `ns-eval`'s `time`."""

        self.eval()
        camera, batch = self.datamanager.next_eval_image(step)
        dataset = self.datamanager.eval_dataset
        frame = int(dataset.metadata["frame_indices"][int(batch["image_idx"])])
        _, pred = render(self, camera, state_at(self, frame))
        gt = dataset.recorded_image(int(batch["image_idx"]))  # [H, W]: a generated scene's image is its truth
        metrics = {f"{key}_time": value for key, value in scores(pred, gt, device=self.model.device).items()}
        metrics["num_rays"] = int(gt.size)
        image = torch.from_numpy(np.concatenate([gt, pred], axis=1)).clamp(0, 1)[..., None].expand(-1, -1, 3)
        self.train()
        return metrics, {"img": image}

    def get_average_eval_image_metrics(
        self, step: Optional[int] = None, output_path: Optional[Path] = None, get_std: bool = False
    ):

        cfg = self.config
        result = evaluate(self, out_dir=output_path, fit_steps=cfg.eval_fit_steps, fit_views=cfg.eval_fit_views)
        rows = result["per_view"]
        metrics = {key: value for key, value in result.items() if isinstance(value, float)}
        if get_std:
            metrics.update({f"{key}_std": float(np.std([r[key] for r in rows])) for key in list(metrics)})
        protocols = (
            "novel: canonical state; time: state from the neighbouring training frames; "
            "aligned: novel + per-view gain/offset; half: fitted on the left half, right half scored; "
            "oracle: the frame's own LUT and embedding fitted on all its pixels "
            "(uses the test pixels; an upper bound only)"
        )
        metrics.update(
            {
                # nerfstudio's headline keys: a held-out frame of a sequence at its time state
                "psnr": metrics["psnr_time"],
                "ssim": metrics["ssim_time"],
                "space": "original radiometric (dataset-normalised); targets: the held-out frame as "
                "recorded (time, half, oracle), the view's truth where the capture has one, else the "
                "same frame (novel, aligned)",
                "protocols": protocols,
                "views": len(rows),
                "gaussians": result["gaussians"],
            }
        )
        self.train()
        return metrics
