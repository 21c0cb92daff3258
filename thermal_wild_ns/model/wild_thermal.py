"""WildThermalModel: splatfacto for thermal-only data ("Thermal is Always Wild", CVPR 2026).

A thin adapter of named parts, overriding only what nerfstudio asks of a model: one scalar emission per
Gaussian from a per-Gaussian and a per-frame embedding (`emission.py`), a background MLP behind the Gaussians
(`background.py`), the camera's own response in every image compared with a recorded frame
(`camera_response.py`), the loss (`thermal_loss.py`), the photometric states (`frame_states.py`), growth
(`growth.py`, beside gsplat's strategy in `strategy.py`) and a render per mode (`renders.py`). Old runs are read
through `old_checkpoints.py`. No LPIPS (it would download weights). Outside training a render is at the state
its caller passes, else the viewer's: renders are stable.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional, Sequence, Tuple, Type, Union

import torch
from nerfstudio.cameras.camera_optimizers import CameraOptimizer
from nerfstudio.cameras.cameras import Cameras
from nerfstudio.models.splatfacto import SplatfactoModel
from torch import Tensor, nn
from torch.nn import Parameter

from thermal_wild_ns._upstream import profiled_section
from thermal_wild_ns.decisions import Decision
from thermal_wild_ns.image_metrics import image_metrics_and_images, psnr
from thermal_wild_ns.model.camera_falloff import FALLOFF_ORDER
from thermal_wild_ns.model.camera_response import CameraChoice
from thermal_wild_ns.model.config_checks import (
    refuse_mismatched_checkpoint,
    refuse_options_across_gpus,
    refuse_options_without_their_part,
    refuse_unused_options,
)
from thermal_wild_ns.model.fields import BackgroundMLP, EmissionMLP
from thermal_wild_ns.model.frame_states import FrameStates
from thermal_wild_ns.model.gaussians import GreyColourAccessors, initial_gaussians
from thermal_wild_ns.model.growth import GrowthPolicy
from thermal_wild_ns.model.old_checkpoints import (
    MLP_NAMES,
    CheckpointParts,
    converted_state_dict,
    match_checkpoint,
    migrate_config,
    packed_optimizer_states,
)
from thermal_wild_ns.model.options import PART_EVIDENCE, ThermalModelOptions
from thermal_wild_ns.model.renders import RenderMode, RenderParts, Scene, render_mode, render_modes
from thermal_wild_ns.model.schedule import schedule_moves_loss, settled_step
from thermal_wild_ns.model.strategy import BudgetedDefaultStrategy
from thermal_wild_ns.model.thermal_loss import ThermalLoss, inverse_lut_table
from thermal_wild_ns.pipeline.ranks import RankGroup
from thermal_wild_ns.rendering.viewer_controls import ThermalViewerControls
from thermal_wild_ns.state_names import CANONICAL, StateName, at_time


@dataclass
class WildThermalModelConfig(ThermalModelOptions):
    """Thermal splatting: scalar emission, appearance embeddings, background MLP (options: `options.py`)."""

    _target: Type = field(default_factory=lambda: WildThermalModel)


class WildThermalModel(GreyColourAccessors, SplatfactoModel):
    """Splatfacto with scalar thermal emission, appearance embeddings and a background MLP."""

    config: WildThermalModelConfig

    # ------------------------------------------------------------------ setup
    def populate_modules(self):
        # Own version rather than super(): splatfacto's builds SH colour features with a hard-coded
        # .cuda(), a 3-channel SSIM and LPIPS (which downloads AlexNet weights).
        cfg = self.config
        migrate_config(cfg)
        refuse_unused_options(cfg)
        refuse_options_without_their_part(cfg)
        metadata = self.kwargs.get("metadata") or {}
        self.ranks = RankGroup.current() if cfg.distributed else RankGroup()
        refuse_options_across_gpus(cfg, self.ranks.split)
        self.growth = GrowthPolicy.of(cfg, self.ranks.world, self.ranks.rank)
        camera = CameraChoice.of(cfg, metadata.get("content_motion"))
        # every rank builds the same initial model (one seed), then keeps its share of the Gaussians
        params = self.ranks.own_rows(initial_gaussians(self.seed_points, cfg, self.k_nearest_sklearn))
        self.gauss_params = nn.ParameterDict({k: Parameter(v) for k, v in params.items()})
        num_frames = max(self.num_train_data, 1)
        self.frame_embed = nn.Embedding(num_frames, cfg.frame_embed_dim)
        nn.init.zeros_(self.frame_embed.weight)
        # each training image's capture position (capture-order frame index): the photometric states' time axis
        indices = metadata.get("frame_indices")
        self.frame_states = FrameStates(self.frame_embed, indices if indices is not None else range(num_frames))
        self.emission_mlp = None
        if cfg.use_emission_mlp:
            dims = (cfg.gaussian_embed_dim, cfg.frame_embed_dim, cfg.emission_mlp_width, cfg.emission_mlp_layers)
            self.emission_mlp = EmissionMLP(*dims)
        self.background_mlp = self.background_mlp_of(cfg.background_frame_coupling)
        # row 0 the gain's polynomial, row 1 the offset's (`camera_falloff.respond`); zero: no fall-off
        self.camera_falloff = Parameter(torch.zeros(2, FALLOFF_ORDER)) if camera.falloff else None
        # [2, n, n]: row 0 the gain's cells, row 1 the offset's (`camera_falloff.flat_field_maps`); zero: flat
        n = cfg.camera_flat_field
        self.camera_flat_field = Parameter(torch.zeros(2, n, n)) if camera.flat_field else None
        self.camera_choice = camera
        self.camera_optimizer: CameraOptimizer = cfg.camera_optimizer.setup(
            num_cameras=self.num_train_data, device="cpu"
        )
        self.step = 0
        self.optimizers = {}  # set by splatfacto's step_cb once training starts
        self.crop_box = None
        self.background_color = torch.tensor([cfg.background_value] * 3)
        self.parts = RenderParts.of(cfg, self.ranks, self.emission_mlp, self.background_mlp, camera.falloff)
        self.renders = render_modes(self.parts)  # one per `RenderMode`, chosen once per render
        sequence = metadata.get("preprocessed")  # the training frames' LUTs
        use_luts = sequence is not None and cfg.loss_space == "original"
        self.thermal_loss = ThermalLoss(cfg, inverse_lut_table(sequence, self.frame_times) if use_luts else None)
        self.strategy = BudgetedDefaultStrategy.for_splatfacto(cfg, self.num_train_data, self.ranks.world)
        self.strategy_state = self.strategy.initialize_state(scene_scale=1.0)
        self.growth_state = self.growth.initialize_state(self.strategy)
        self.viewer_controls = ThermalViewerControls(self.frame_times, cfg.colormap)
        """What the viewer's user chose (colormap, photometric state): read, never set, by the model."""
        self._last_training_losses: Tuple[Optional[Dict[str, Tensor]], Optional[int]] = (None, None)
        self._discard_statistics = False  # `discard_step_statistics`
        self._step_accepted: Optional[Tensor] = None  # `weigh_step_statistics`

    def background_mlp_of(self, coupling: str) -> Optional[BackgroundMLP]:
        cfg = self.config
        if not cfg.use_background_mlp:
            return None
        width, layers = cfg.background_mlp_width, cfg.background_mlp_layers
        return BackgroundMLP(cfg.frame_embed_dim, coupling, width, layers, init_value=cfg.background_value)

    @property
    def frame_times(self) -> List[float]:
        """Capture position of each training image (each row of `frame_embed`)."""
        return self.frame_states.frame_times

    @property
    def emission(self) -> Tensor:
        return self.gauss_params["emission"]

    def get_gaussian_param_groups(self) -> Dict[str, List[Parameter]]:
        # every tensor in gauss_params needs its own group: gsplat's strategies look optimizers
        # up by the gauss_params key when they clone, split and prune
        return {name: [param] for name, param in self.gauss_params.items()}

    def get_param_groups(self) -> Dict[str, List[Parameter]]:
        groups = self.get_gaussian_param_groups()
        groups["frame_embed"] = list(self.frame_embed.parameters())
        parts = ("emission_mlp", "background_mlp", "camera_falloff", "camera_flat_field")
        for name, part in ((name, getattr(self, name)) for name in parts):
            if isinstance(part, nn.Module):
                groups[name] = list(part.parameters())
            elif part is not None:
                groups[name] = [part]
        self.camera_optimizer.get_param_groups(param_groups=groups)
        return groups

    # ------------------------------------------------------------------ photometric states
    @property
    def uses_frame_embedding(self) -> bool:
        """Whether renders depend on the frame embedding (through either MLP)."""
        return self.emission_mlp is not None or self.background_mlp is not None

    def state_embedding(self, name: StateName) -> Tensor:
        """The frame embedding [Df] of the photometric state `name` (`FrameStates.embedding`)."""
        return self.frame_states.embedding(name, self.config.canonical_embedding, self.step, self.typical_emission)

    def viewer_embedding(self) -> Tensor:
        """The frame embedding [Df] of a render that names no state (ns-viewer): its user's capture time, else
        the canonical state, which lags a training run by up to `frame_states.VIEWER_REFIT_STEPS` steps."""
        t = self.viewer_controls.capture_time
        name = CANONICAL if t is None else at_time(t)
        return self.frame_states.for_viewer(name, self.config.canonical_embedding, self.step, self.typical_emission)

    def typical_emission(self):
        """What the 'typical' canonical state matches (`GaussianEmission.typical`); None while the Gaussians are
        split across GPUs: each holds a share, and the state must be one on every GPU (there the canonical
        state is the mean until one GPU loads the run)."""
        return None if self.ranks.split else self.parts.emission.typical(self.gauss_params)

    def gaussian_emission(self, frame_embed: Tensor) -> Tensor:
        """Every Gaussian's emission [N, 1] under `frame_embed` [Df] as a render outside training gives it
        (baked), without the view term: what the exports and nerfstudio's colour accessors read."""
        return self.parts.emission.baked(self.gauss_params, frame_embed, self.step)

    # ------------------------------------------------------------------ rendering
    def get_outputs(self, camera: Cameras, frame_embedding: Optional[Tensor] = None) -> Dict[str, Union[Tensor, List]]:
        """The render of `camera`: in training, at its training frame's state; otherwise at the photometric state
        whose `frame_embedding` [Df] the caller passes, else the viewer's (`viewer_embedding`)."""
        if not isinstance(camera, Cameras):
            raise TypeError(f"WildThermalModel.get_outputs needs a Cameras object, got {type(camera).__name__}")
        if self.training:
            assert camera.shape[0] == 1, "Only one camera at a time"
        return self.render_cameras([camera], frame_embedding)[0]

    def get_training_outputs(self, cameras: Sequence[Cameras]) -> List[Dict[str, Union[Tensor, List]]]:
        """The training renders of several cameras of one size, each at its frame's state, in one rasterization
        (`ThermalPipelineConfig.cameras_per_step`): the step's fixed costs are paid once for all of them; the
        densification statistics count each camera a Gaussian is seen from, as gsplat's own."""
        if not self.training or (self.ranks.split and len(cameras) > 1):
            raise RuntimeError("several cameras per render: training on one GPU only")
        return self.render_cameras(cameras)

    def render_cameras(self, cameras: Sequence[Cameras], frame_embedding: Optional[Tensor] = None) -> List[Dict]:
        """Every render: its mode chosen once (`renders.render_mode`), each camera at its state (a training camera
        at its frame's, else `frame_embedding`, else the viewer's); a training render's `info` kept for the
        densification after the step."""
        ids = None if self.training or self.crop_box is None else self.crop_box.within(self.means).squeeze()
        mode = render_mode(self.training, torch.is_grad_enabled(), ids is not None, self.ranks.split)
        weight = self.frame_embed.weight  # [F, Df]
        train = lambda c: self.training and "cam_idx" in (c.metadata or {})
        embeds = [weight[int(c.metadata["cam_idx"])] if train(c) else frame_embedding for c in cameras]
        embeds = [self.viewer_embedding() if e is None else e for e in embeds]
        renders = self.renders[mode]
        outputs, info = renders.render_cameras(self.scene(), cameras, embeds, ids)
        if info is not None:  # a training render's screen-space gradients enter the statistics after backward
            self.info = info
            if torch.is_grad_enabled():
                self.strategy.step_pre_backward(
                    self.gauss_params, self.optimizers, self.strategy_state, self.step, info
                )
        return outputs

    def fitting_views(self, cameras: Sequence[Cameras]) -> Callable[[Tensor], Tensor]:
        """The thermal renders of `cameras` [B] (one size) outside training as the camera records them
        (`as_recorded`), as one function of their frame embeddings [B, Df] -> [B, H, W], for fits of their states
        through the render (the geometry fixed: `FittingRender.fixed_views`)."""
        ids = None if self.crop_box is None else self.crop_box.within(self.means).squeeze()
        scene = self.renders[RenderMode.FITTING].fixed_views(self.scene(), cameras, ids)
        recorded = self.parts.camera.fixed(self.camera_falloff, self.camera_flat_field, cameras)
        return lambda embeds: recorded(scene(embeds))[..., 0]

    def scene(self) -> Scene:
        """What a render reads of the model now (`renders.Scene`)."""
        view_term = self.growth.renders_view_term(self.growth_state, self.training, self.step)
        pose = lambda camera: self.camera_optimizer.apply_to_camera(camera)
        downscale, colormap = self._get_downscale_factor(), self.viewer_controls.colormap
        falloff, flat_field, weight = self.camera_falloff, self.camera_flat_field, self.frame_embed.weight
        return Scene(self.gauss_params, falloff, flat_field, self.step, view_term, downscale, pose, weight, colormap)

    @torch.no_grad()
    def get_outputs_for_camera(
        self, camera: Cameras, obb_box=None, frame_embedding: Optional[Tensor] = None
    ) -> Dict[str, Tensor]:
        """Splatfacto's, at the state of `frame_embedding` (`get_outputs`), without its copy of a camera already
        on the model's device (a new Cameras object per frame, whose construction costs more host time than
        the splatting)."""
        self.set_crop(obb_box)
        return self.get_outputs(camera if camera.device == self.device else camera.to(self.device), frame_embedding)

    def as_recorded(self, thermal: Tensor, camera: Cameras) -> Tensor:
        """A render `thermal` [H, W, 1] of `camera` as the camera records it (`CameraResponse.as_recorded`)."""
        return self.parts.camera.as_recorded(self.camera_falloff, self.camera_flat_field, thermal, camera)

    # ------------------------------------------------------------------ losses
    def _training_image(self, batch: Dict) -> Optional[int]:
        """The batch's training image while training (its frame checks are kept), else None."""
        return int(batch["image_idx"]) if self.training and "image_idx" in batch else None

    def _ground_truth(self, outputs: Dict, batch: Dict) -> Tuple[Tensor, Optional[Tensor]]:
        """The frame at the render's resolution and its contrast (`ThermalLoss.frame_of`)."""
        image = self._training_image(batch)
        return self.thermal_loss.frame_of(outputs, batch, image, self._get_downscale_factor(), self.get_gt_img)

    def get_metrics_dict(self, outputs, batch) -> Dict[str, Tensor]:
        gt, _ = self._ground_truth(outputs, batch)
        return {"psnr": psnr(outputs["thermal"].detach(), gt), "gaussian_count": self.num_points}

    def get_loss_dict(self, outputs, batch, metrics_dict=None) -> Dict[str, Tensor]:
        image = self._training_image(batch)
        losses = self._camera_losses(outputs, batch, image)
        if self.training:
            losses = self._step_losses(losses)
            self._last_training_losses = (losses, image)  # summed where needed: the step sums them anyway
        return losses

    def _camera_losses(self, outputs, batch, image: Optional[int], slot: int = 0) -> Dict[str, Tensor]:
        """The losses of one camera's render against its frame (`image`: its training image, None outside
        training); `slot`: the camera's place among a training step's cameras (`GraphedCalls`)."""
        with profiled_section("thermal/loss"):
            gt, contrast = self._ground_truth(outputs, batch)
            losses = self.thermal_loss(outputs, gt, contrast, image, slot)
        if "view_radial" in outputs:  # the view term's radial part (`view_radial_penalty`)
            losses["view_radial"] = self.config.view_radial_penalty * outputs["view_radial"]
        return losses

    def _step_losses(self, losses: Dict[str, Tensor]) -> Dict[str, Tensor]:
        """`losses` with the terms of the step rather than of a camera added (once, however many cameras the
        step trains): the states' smoothness and the camera optimizer's regulariser."""
        if self.config.state_smoothness > 0:
            # the embeddings are one copy per GPU whose gradients are summed: each rank adds its share
            share = self.config.state_smoothness / self.ranks.world
            losses["state_smoothness"] = share * self.frame_states.neighbour_residual()
        self.camera_optimizer.get_loss_dict(losses)
        return losses

    def get_training_metrics_and_losses(
        self, outputs: Sequence[Dict], batches: Sequence[Dict], metrics: bool = True
    ) -> Tuple[Dict[str, Tensor], Dict[str, Tensor]]:
        """The metrics and losses of a step of several cameras (`get_training_outputs`): each camera's as a step
        of its own, averaged over the cameras, and the step's own terms once. The step's loss has no one training
        image: the divergence guard reads it against the recent steps' alone. `metrics` off: an empty dict."""
        if len(outputs) == 1:
            metrics_dict = self.get_metrics_dict(outputs[0], batches[0]) if metrics else {}
            return metrics_dict, self.get_loss_dict(outputs[0], batches[0], metrics_dict)
        images = [self._training_image(b) for b in batches]
        losses = [self._camera_losses(*camera, slot) for slot, camera in enumerate(zip(outputs, batches, images))]
        mean = lambda dicts, key: torch.stack([d[key] for d in dicts]).mean()
        loss_dict = self._step_losses({key: mean(losses, key) for key in losses[0]})
        metrics_dict = {}
        if metrics:
            psnrs = [self.get_metrics_dict(o, b) for o, b in zip(outputs, batches)]
            metrics_dict = {"psnr": mean(psnrs, "psnr"), "gaussian_count": self.num_points}
        self._last_training_losses = (loss_dict, None)
        return metrics_dict, loss_dict

    def get_image_metrics_and_images(self, outputs, batch) -> Tuple[Dict[str, float], Dict[str, Tensor]]:
        return image_metrics_and_images(outputs["thermal"], self._ground_truth(outputs, batch)[0], self.num_points)

    # ------------------------------------------------------------------ densification
    def step_post_backward(self, step):
        accepted, self._step_accepted = self._step_accepted, None
        if self._discard_statistics:  # a rolled-back step: no statistics from it
            self._discard_statistics = False
            return
        assert step == self.step
        info = self.info if accepted is None else {**self.info, "accepted": accepted}
        with profiled_section("thermal/densify"):  # splatfacto's, but with the layout this model rendered
            # splatfacto passes packed=False; across GPUs the render is packed ([nnz] per visible splat), and
            # statistics read as [C, N] summed every splat into every Gaussian: each rank's screen-size
            # rule then pruned all its Gaussians within a few refinements after the first opacity reset
            args = dict(params=self.gauss_params, optimizers=self.optimizers, state=self.strategy_state, step=step)
            self.strategy.step_post_backward(**args, info=info, packed=self.ranks.split)
            if self.growth.few_view_prune_runs(self.strategy) and self.strategy.refines_at(step):
                views = list({cam: view for (cam, _), view in self.parts.training_views.kept.items()}.values())
                self.growth.prune_few_view(self.growth_state, self.strategy, *args.values(), views)

    # ------------------------------------------------- the trainer's interface (training/model_interface.py)
    def last_training_losses(self) -> Tuple[Optional[Dict[str, Tensor]], Optional[int]]:
        return self._last_training_losses

    def discard_step_statistics(self) -> None:
        self._discard_statistics = True

    def weigh_step_statistics(self, accepted: Tensor) -> None:
        self._step_accepted = accepted

    @property
    def settled_step(self) -> int:
        return settled_step(self.config, self.strategy)

    def schedule_moves_loss(self, step: int) -> bool:
        return schedule_moves_loss(self.config, self.strategy, step)

    def interpolate_embeddings(self, rows: Sequence[int]) -> None:
        self.frame_states.fill_from_neighbours(rows)

    def decisions(self) -> List[Decision]:
        """What each part chose for this run, and why (`training/decisions.py` reports them)."""
        cfg = self.config
        entries = self.growth.budget_decisions(self.strategy, self.num_points)
        parts = (
            ("emission MLP", cfg.use_emission_mlp, "use_emission_mlp"),
            ("background MLP", cfg.use_background_mlp, "use_background_mlp"),
            ("heat-aware SSIM", cfg.heat_aware_ssim, "heat_aware_ssim"),
            ("alpha regulariser", cfg.alpha_lambda > 0, "alpha_lambda"),
        )
        entries += [
            Decision(part, "on" if on else "off", part_why(cfg, option), "config") for part, on, option in parts
        ]
        entries += self.growth.part_decisions(self.growth_state, self.strategy, cfg.view_sh_degree)
        return entries + self.camera_choice.decisions(self.camera_falloff, self.camera_flat_field)

    def gaussian_budget(self) -> Tuple[int, int]:
        return self.num_points, self.strategy.max_gaussians

    def start_budget(self, count: int) -> None:
        self.growth.start_budget(self.growth_state, self.strategy, count, self.step)

    def raise_budget(self, count: int) -> None:
        self.growth.raise_budget(self.growth_state, self.strategy, count, self.step)

    def densifies(self, step: int) -> bool:
        return step < self.strategy.refine_stop_iter

    def limit_growth(self, count: int) -> None:
        self.growth.limit_growth(self.growth_state, self.strategy, count)

    def has_view_term(self) -> bool:
        return self.growth.has_view_term

    def use_view_term(self, on: bool) -> None:
        self.growth.use_view_term(self.growth_state, self.gauss_params.get("view_sh"), on)

    def try_view_term(self) -> None:
        self.growth.try_view_term(self.growth_state, self.gauss_params.get("view_sh"))

    def renders_view_term(self) -> bool:
        return self.growth.renders_view_term(self.growth_state, self.training, self.step)

    def optimizer_states_of(self, states: dict) -> dict:
        return packed_optimizer_states(states, self._mlps())

    # ------------------------------------------------------------------ checkpoints
    def _mlps(self) -> Dict[str, nn.Module]:
        return {name: getattr(self, name) for name in MLP_NAMES if getattr(self, name) is not None}

    def load_state_dict(self, state_dict, strict: bool = True, **kwargs):  # type: ignore[override]
        """Today's layout of an old checkpoint (`old_checkpoints.py`), the model made as the checkpoint's run
        trained it where an older config file cannot say, then a refusal of a checkpoint of another config."""
        state_dict = converted_state_dict(state_dict, self._mlps())
        match_checkpoint(self, CheckpointParts.of(state_dict))
        has_parts = (self.emission_mlp, self.background_mlp, self.camera_falloff, self.camera_flat_field)
        has_parts = tuple(part is not None for part in has_parts)
        refuse_mismatched_checkpoint(state_dict, *has_parts, tuple(self.frame_embed.weight.shape))
        loaded = super().load_state_dict(state_dict, strict=strict, **kwargs)
        self.growth.loaded(self.growth_state, self.gauss_params.get("view_sh"))
        return loaded

    # densification statistics, torch's RNG (gsplat's splits draw from it) and the few-view prune's count are saved:
    # a resume continues the run, and its decisions count what the whole run pruned
    def get_extra_state(self) -> dict:
        state = {k: v for k, v in self.strategy_state.items() if v is not None}
        pruned = self.growth_state.few_view_pruned
        return {"strategy_state": state, "torch_rng_state": torch.get_rng_state(), "few_view_pruned": pruned}

    def set_extra_state(self, state: dict) -> None:
        if not state:
            return
        for key, value in state.get("strategy_state", {}).items():
            self.strategy_state[key] = value.to(self.device) if isinstance(value, Tensor) else value
        if "torch_rng_state" in state:
            torch.set_rng_state(state["torch_rng_state"])
        self.growth_state.few_view_pruned = state.get("few_view_pruned", 0)


def part_why(config: WildThermalModelConfig, option: str) -> str:
    """Why a switchable part is as `config` has it: at its default, what the default rests on (`PART_EVIDENCE`);
    otherwise the option that set it, with the default and its evidence beside."""
    value, default = getattr(config, option), WildThermalModelConfig.__dataclass_fields__[option].default
    if value == default:
        return f"the default: {PART_EVIDENCE[option]}"
    return f"{option} {value} in this run's config (the default {default}: {PART_EVIDENCE[option]})"
