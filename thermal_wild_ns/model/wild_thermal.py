"""WildThermalModel: splatfacto for thermal-only data ("Thermal is Always Wild", CVPR 2026).

Differences from `SplatfactoModel`, and only these are overridden:
- one scalar emission per Gaussian (no spherical harmonics), rendered as a 1-channel image;
- a per-Gaussian embedding (in `gauss_params`, so densification clones/splits/prunes it with
  its Gaussian) and a per-frame embedding feed an emission MLP (`fields.EmissionMLP`);
- a background MLP b(view direction, frame embedding) fills the residual transmittance:
  image = render + (1 - alpha) * b  (gsplat's render is premultiplied by alpha);
- loss = l1 * L1 + ssim * (1 - heat-aware SSIM) + alpha * alpha regulariser (`losses.py`);
- rendering goes through `thermal_wild_ns.rendering.rasterization` (gsplat on CUDA, the
  pure-torch rasterizer elsewhere) on the model's device; no LPIPS (it would download weights).
Outside training the frame embedding is fixed (`inference_embedding`), so renders are stable.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, List, Literal, Optional, Sequence, Tuple, Type, Union

import numpy as np
import torch
import tyro
from nerfstudio.cameras.camera_optimizers import CameraOptimizer
from nerfstudio.cameras.cameras import Cameras
from nerfstudio.models.splatfacto import RGB2SH, SplatfactoModel, SplatfactoModelConfig
from nerfstudio.utils.rich_utils import CONSOLE
from torch import Tensor, nn
from torch.nn import Parameter
from torch.profiler import record_function

from thermal_wild_ns.data.palettes import palette_rgb
from thermal_wild_ns.errors import InputError
from thermal_wild_ns.image_metrics import psnr, ssim
from thermal_wild_ns.model.background import CameraFrameDirections, background_map, sample_map, upsampled
from thermal_wild_ns.model.bake import BakedValues
from thermal_wild_ns.model.camera_views import View, make_view, ray_directions
from thermal_wild_ns.model.fields import BackgroundMLP, EmissionMLP
from thermal_wild_ns.model.gaussians import initial_gaussians
from thermal_wild_ns.model.losses import alpha_regularizer, heat_aware_ssim, thermal_contrast
from thermal_wild_ns.model.strategy import BudgetedDefaultStrategy
from thermal_wild_ns.preprocessing.photometric import time_weights
from thermal_wild_ns.rendering import Backend, rasterization
from thermal_wild_ns.rendering.viewer_controls import ThermalViewerControls


@dataclass
class WildThermalModelConfig(SplatfactoModelConfig):
    """Thermal splatting: scalar emission, appearance embeddings, background MLP."""

    _target: Type = field(default_factory=lambda: WildThermalModel)
    rasterizer: Backend = "auto"
    """Rendering backend: 'auto' (gsplat on CUDA, pure torch elsewhere), 'gsplat' or 'torch'."""
    use_emission_mlp: bool = True
    """Condition each Gaussian's emission on per-Gaussian and per-frame embeddings through an MLP.
    Off: plain scalar emission per Gaussian (the 3DGS baseline)."""
    gaussian_embed_dim: int = 16
    """Size of the per-Gaussian appearance embedding."""
    frame_embed_dim: int = 16
    """Size of the per-frame appearance embedding (also conditions the background MLP)."""
    emission_mlp_width: int = 128
    """Width of the emission MLP's hidden layers."""
    emission_mlp_layers: int = 3
    """Number of hidden layers (ReLU) of the emission MLP."""
    use_background_mlp: bool = True
    """Fill the residual transmittance with a background MLP b(view direction, frame embedding).
    Off: a constant background of `background_value`."""
    background_value: float = 0.0
    """Constant background (normalised intensity) when the background MLP is off; the background
    MLP's initial value when it is on."""
    random_background: bool = False
    """Without the background MLP: composite each training render over a background drawn afresh
    at every step (uniform in [0, 1]), as splatfacto does. No Gaussian can then leave a pixel to
    the background, so the frames must be covered by opaque Gaussians, the sky included. Renders
    outside training use `background_value`."""
    background_stride: int = 4
    """The background MLP is evaluated every this many pixels and upsampled bilinearly: its
    direction encoding (spherical harmonics up to degree 3) varies far more slowly than that."""
    inference_embedding: str = "mean"
    """Frame embedding used outside training (evaluation, viewer, renders): 'mean' (average of the
    training frames' embeddings), 'zero', or a training-frame index such as '12'."""
    colormap: Literal["iron", "inferno", "grey"] = "iron"
    """Thermal colormap of the `rgb` output outside training (ns-viewer, ns-render videos); the
    viewer has a control for it. `thermal` stays the scalar image."""
    loss_space: Literal["training", "original"] = "training"
    """Where the photometric loss compares render and frame: 'training' (the preprocessed frames the
    model renders) or 'original' (both taken back through the frame's inverse LUT, so that
    equalization shapes the gradients' reach but cannot amplify errors where it stretched the
    levels). The same for frames that were not preprocessed."""
    heat_aware_ssim: bool = True
    """SSIM loss with constants scaled to each frame's contrast (off: plain SSIM, as 3DGS uses)."""
    l1_lambda: float = 0.8
    """Weight of the L1 loss."""
    ssim_lambda: float = 0.2
    """Weight of the heat-aware SSIM loss (1 - SSIM)."""
    alpha_lambda: float = 0.01
    """Weight of the alpha regulariser against floaters in front of the background."""
    alpha_reg_tolerance: float = 0.02
    """Intensity difference (normalised units) under which a target pixel counts as 'explained by
    the background' for the alpha regulariser."""
    # splatfacto's and nerfstudio's options this model does not use: hidden from `--help`, and a
    # config that changes one is refused by name (`refuse_unused_options`)
    background_color: tyro.conf.Suppress[str] = "black"  # type: ignore[assignment]
    sh_degree: tyro.conf.Suppress[int] = 0
    sh_degree_interval: tyro.conf.Suppress[int] = 1000
    n_split_samples: tyro.conf.Suppress[int] = 2
    use_scale_regularization: tyro.conf.Suppress[bool] = False
    max_gauss_ratio: tyro.conf.Suppress[float] = 10.0
    use_bilateral_grid: tyro.conf.Suppress[bool] = False
    grid_shape: tyro.conf.Suppress[Tuple[int, int, int]] = (16, 16, 8)
    color_corrected_metrics: tyro.conf.Suppress[bool] = False
    enable_collider: tyro.conf.Suppress[bool] = True
    collider_params: tyro.conf.Suppress[Optional[Dict[str, float]]] = field(
        default_factory=lambda: {"near_plane": 2.0, "far_plane": 6.0}
    )
    loss_coefficients: tyro.conf.Suppress[Dict[str, float]] = field(
        default_factory=lambda: {"rgb_loss_coarse": 1.0, "rgb_loss_fine": 1.0}
    )
    eval_num_rays_per_chunk: tyro.conf.Suppress[int] = 4096
    prompt: tyro.conf.Suppress[Optional[str]] = None
    max_gaussians: int = 100_000
    """Densification never grows the model past this many Gaussians. The default is the knee of a
    budget sweep on DUNR (docs/results.md); raise it for captures with much more to see."""


UNUSED_OPTIONS = {
    "background_color": "the background is the background MLP, or background_value",
    "sh_degree": "thermal emission is a scalar: no spherical harmonics",
    "sh_degree_interval": "no spherical harmonics",
    "n_split_samples": "gsplat's strategy splits each Gaussian in two",
    "use_scale_regularization": "not implemented for thermal splats",
    "max_gauss_ratio": "not implemented for thermal splats",
    "use_bilateral_grid": "a colour-camera correction; thermal frames' drift is the frame embeddings' and the LUTs'",
    "grid_shape": "no bilateral grid",
    "color_corrected_metrics": "metrics are scored by the evaluation protocols in the original space",
    "enable_collider": "splats have no ray sampling",
    "collider_params": "splats have no ray sampling",
    "loss_coefficients": "the loss weights are l1_lambda, ssim_lambda and alpha_lambda",
    "eval_num_rays_per_chunk": "splats render whole images",
    "prompt": "no text prompts",
}
"""Options `WildThermalModelConfig` inherits but the model does not use, and why."""


def refuse_unused_options(config: WildThermalModelConfig) -> None:
    """An `InputError` naming any option of `UNUSED_OPTIONS` set away from its default (a config
    file edited by hand, or written for splatfacto): it would do nothing."""
    defaults = WildThermalModelConfig()
    changed = [name for name in UNUSED_OPTIONS if getattr(config, name) != getattr(defaults, name)]
    if changed:
        raise InputError(
            "wild-thermal does not use "
            + "; ".join(f"{name} (set to {getattr(config, name)!r}: {UNUSED_OPTIONS[name]})" for name in changed)
            + ". Remove it from the config"
        )


class WildThermalModel(SplatfactoModel):
    """Splatfacto with scalar thermal emission, appearance embeddings and a background MLP."""

    config: WildThermalModelConfig

    # ------------------------------------------------------------------ setup
    def populate_modules(self):
        # Own version rather than super(): splatfacto's builds SH colour features with a hard-coded
        # .cuda(), a 3-channel SSIM and LPIPS (which downloads AlexNet weights).
        cfg = self.config
        refuse_unused_options(cfg)
        params = initial_gaussians(self.seed_points, cfg, self.k_nearest_sklearn)
        self.gauss_params = nn.ParameterDict({k: Parameter(v) for k, v in params.items()})

        num_frames = max(self.num_train_data, 1)
        self.frame_embed = nn.Embedding(num_frames, cfg.frame_embed_dim)
        indices = self.kwargs.get("metadata", {}).get("frame_indices")
        self.frame_times: List[float] = (
            [float(t) for t in indices] if indices is not None else [float(k) for k in range(num_frames)]
        )
        """Capture position (capture-order frame index) of each training image, i.e. of each row of
        `frame_embed`: the time axis along which the photometric state is interpolated."""
        self._last_training_loss: Tuple[Optional[Tensor], Optional[int]] = (None, None)  # `last_training_loss`
        self._discard_statistics = False  # `discard_step_statistics`
        nn.init.zeros_(self.frame_embed.weight)
        self.emission_mlp = (
            EmissionMLP(cfg.gaussian_embed_dim, cfg.frame_embed_dim, cfg.emission_mlp_width, cfg.emission_mlp_layers)
            if cfg.use_emission_mlp
            else None
        )
        if cfg.random_background and cfg.use_background_mlp:
            raise InputError("random_background needs use_background_mlp False: the background MLP models it")
        self.background_mlp = (
            BackgroundMLP(cfg.frame_embed_dim, init_value=cfg.background_value) if cfg.use_background_mlp else None
        )
        self.camera_optimizer: CameraOptimizer = cfg.camera_optimizer.setup(
            num_cameras=self.num_train_data, device="cpu"
        )
        self.step = 0
        self.optimizers = {}  # set by splatfacto's step_cb once training starts
        self.crop_box = None
        self.background_color = torch.tensor([cfg.background_value] * 3)
        self._warned_nonfinite = False
        self.baked = BakedValues()  # outside training: `baked_emission`, `baked_background_map`
        self._colormap_table: Optional[tuple] = None  # ((colormap, device), [256, 3] table): `colormap_table`
        self._embedding_cache: Optional[tuple] = None  # (choice, step, version) -> embedding: `_cached_embedding`
        self._encoded_directions: Dict[tuple, Tensor] = {}  # training camera -> encoded background directions
        self._training_views: Dict[tuple, View] = {}  # (training camera, downscale) -> its `_view`
        self._frame_directions = CameraFrameDirections()  # what the baked background is sampled along
        self._frame_checks: Dict[tuple, tuple] = {}  # training image -> (all finite, contrast, original frame)
        self.register_buffer("inverse_luts", self._inverse_luts(), persistent=False)
        """[training images, S] each training frame's inverse LUT sampled at S evenly spaced training-space
        values, for `loss_space` 'original' when the frames are preprocessed; else None."""
        self.strategy = BudgetedDefaultStrategy.for_splatfacto(cfg, self.num_train_data)
        self.strategy_state = self.strategy.initialize_state(scene_scale=1.0)
        self.viewer_controls = ThermalViewerControls(self.frame_times, cfg.colormap)
        """What the viewer's user chose (colormap, photometric state): read, never set, by the model."""

    INVERSE_LUT_SAMPLES = 4096
    """Training-space values at which each training frame's inverse LUT is tabulated for a loss in
    the original space (linear in between: far finer than any step of the equalization)."""

    def _inverse_luts(self) -> Optional[Tensor]:
        """The training frames' inverse LUTs [images, S], from what the model is built with (the
        training data's `preprocessed` sequence and capture positions); None where unused."""
        metadata = self.kwargs.get("metadata") or {}
        sequence = metadata.get("preprocessed")
        if sequence is None or self.config.loss_space != "original":
            return None
        values = np.linspace(0.0, 1.0, self.INVERSE_LUT_SAMPLES)
        tables = np.stack([sequence.to_original_normalised(values, sequence.lut(int(t))) for t in self.frame_times])
        return torch.from_numpy(tables.astype(np.float32))  # [images, S]

    @property
    def emission(self) -> Tensor:
        return self.gauss_params["emission"]

    @property
    def colors(self) -> Tensor:
        """Grey RGB in [0, 1] per Gaussian, for nerfstudio's exporters and viewers: the emission as
        rendered outside training (MLP included, under the inference embedding)."""
        with torch.no_grad():
            emission = self.gaussian_emission(self.inference_embedding())
        return emission.clamp(0.0, 1.0).expand(-1, 3)

    # splatfacto's SH accessors, which nerfstudio's viewer and exporters read: the grey emission
    # as the DC band and no higher bands (the model has no spherical harmonics)
    @property
    def features_dc(self) -> Tensor:
        return RGB2SH(self.colors)

    @property
    def features_rest(self) -> Tensor:
        return self.emission.new_zeros(self.num_points, 0, 3)

    @property
    def shs_0(self) -> Tensor:
        return self.features_dc

    @property
    def shs_rest(self) -> Tensor:
        return self.features_rest

    def get_gaussian_param_groups(self) -> Dict[str, List[Parameter]]:
        # every tensor in gauss_params needs its own group: gsplat's strategies look optimizers
        # up by the gauss_params key when they clone, split and prune
        return {name: [param] for name, param in self.gauss_params.items()}

    def get_param_groups(self) -> Dict[str, List[Parameter]]:
        groups = self.get_gaussian_param_groups()
        groups["frame_embed"] = list(self.frame_embed.parameters())
        if self.emission_mlp is not None:
            groups["emission_mlp"] = list(self.emission_mlp.parameters())
        if self.background_mlp is not None:
            groups["background_mlp"] = list(self.background_mlp.parameters())
        self.camera_optimizer.get_param_groups(param_groups=groups)
        return groups

    # -------------------------------------------------------------- rendering
    def frame_embedding(self, camera: Cameras, given: Optional[Tensor] = None) -> Tensor:
        """The frame embedding for this camera [Df]: the training frame's own while training; else
        `given` (a photometric state's, passed by the caller), else the viewer's choice
        (`viewer_embedding`)."""
        weight = self.frame_embed.weight  # [F, Df]
        if self.training and camera.metadata is not None and "cam_idx" in camera.metadata:
            return weight[int(camera.metadata["cam_idx"])]
        return given if given is not None else self.viewer_embedding()

    def viewer_embedding(self) -> Tensor:
        """The frame embedding [Df] of a render that names no state (ns-viewer): the state at the
        viewer's capture time where its user chose one, else the canonical `inference_embedding`."""
        t = self.viewer_controls.capture_time
        return self.inference_embedding() if t is None else self._cached_embedding(f"time:{t}")

    @property
    def uses_frame_embedding(self) -> bool:
        """Whether renders depend on the frame embedding (through either MLP)."""
        return self.emission_mlp is not None or self.background_mlp is not None

    def embedding_at(self, t: float, without: Sequence[int] = ()) -> Tensor:
        """The frame embedding [Df] at capture position `t`: linear between the neighbouring
        training frames' embeddings, exactly a training frame's own at its position. `without`:
        rows of `frame_embed` not to interpolate from."""
        left_out = set(without)
        rows = [k for k in range(len(self.frame_times)) if k not in left_out]
        i, j, w = time_weights([self.frame_times[k] for k in rows], t)
        weight = self.frame_embed.weight  # [F, Df]
        return weight[rows[i]] if w == 0.0 else (1.0 - w) * weight[rows[i]] + w * weight[rows[j]]

    def interpolate_embeddings(self, rows: Sequence[int]) -> None:
        """Set the embeddings of training images that take no gradient (held back to score the
        run, `training/auto_stop.py`) to the state interpolated from the other training frames
        around them, so that every use of the embeddings (their mean, `embedding_at`) sees
        states the data shaped."""
        with torch.no_grad():
            for row in rows:
                self.frame_embed.weight[row] = self.embedding_at(self.frame_times[row], without=rows)

    def inference_embedding(self) -> Tensor:
        """The canonical frame embedding [Df]: the configured `inference_embedding` (the training
        frames' mean by default). Outside autograd the same tensor is returned until the embeddings
        change, so the baked emission keyed on it stays valid."""
        return self._cached_embedding(self.config.inference_embedding)

    def _cached_embedding(self, choice: str) -> Tensor:
        """The frame embedding [Df] `choice` names ('mean', 'zero', a training image's index, or
        'time:T'), kept outside autograd until the embeddings change (`_embedding_cache`)."""
        weight = self.frame_embed.weight  # [F, Df]
        cached = self._embedding_cache
        key = (choice, self.step, weight._version)  # the step: fused Adam does not bump tensor versions
        if cached is not None and cached[0] == key and cached[1] is weight:
            return cached[2]
        if choice.startswith("time:"):
            value = self.embedding_at(float(choice[5:]))
        elif choice == "mean":
            value = weight.mean(dim=0)
        elif choice == "zero":
            value = torch.zeros_like(weight[0])
        elif choice.isdigit() and int(choice) < weight.shape[0]:
            value = weight[int(choice)]
        else:
            raise ValueError(
                f"inference_embedding must be 'mean', 'zero' or a training-frame index below {weight.shape[0]}, "
                f"got {choice!r}"
            )
        if not torch.is_grad_enabled():
            self._embedding_cache = (key, weight, value)
        return value

    def gaussian_emission(self, frame_embed: Tensor, ids: Optional[Tensor] = None) -> Tensor:
        """Scalar emission of every (or the selected) Gaussian in the frame [N, 1]. Outside
        training and autograd the MLP's output is baked: computed once per (frame embedding,
        parameter state) and reused, so viewing costs what plain splatting costs."""
        if self.emission_mlp is None:
            return self.emission if ids is None else self.emission[ids]
        if not self.training and not torch.is_grad_enabled():
            emission = self.baked_emission(frame_embed)
            return emission if ids is None else emission[ids]
        base = self.emission if ids is None else self.emission[ids]
        embed = self.gauss_params["gauss_embed"]
        return self.emission_mlp(base, embed if ids is None else embed[ids], frame_embed)

    def baked_emission(self, frame_embed: Tensor) -> Tensor:
        """The emission MLP evaluated for every Gaussian under `frame_embed` [N, 1], kept until the
        embedding or any parameter it depends on changes (`BakedValues`)."""
        embed = self.gauss_params["gauss_embed"]
        tensors = (self.emission, embed, *self.baked.parameters_of(self.emission_mlp), frame_embed)
        return self.baked.get(
            "emission", tensors, self.step, lambda: self.emission_mlp(self.emission, embed, frame_embed)
        )

    def baked_background_map(self, frame_embed: Tensor) -> Tensor:
        """The background MLP over every direction under `frame_embed` (`background.background_map`),
        kept like `baked_emission`: a render samples this map instead of running the MLP per pixel."""
        tensors = (*self.baked.parameters_of(self.background_mlp), frame_embed)
        return self.baked.get(
            "background", tensors, self.step, lambda: background_map(self.background_mlp, frame_embed)
        )

    def _view(self, camera: Cameras, scale: int, cam_idx: Optional[int]) -> View:
        """Where and how a render looks, at 1/`scale` of the camera's resolution (`View`). The camera
        object is left as it is (a datamanager may hand the same one again). `cam_idx` names a
        training camera whose pose is fixed: its view is computed once per scale."""
        key = (cam_idx, scale)
        if cam_idx is not None and key in self._training_views:
            return self._training_views[key]
        camera_to_world = self.camera_optimizer.apply_to_camera(camera) if self.training else camera.camera_to_worlds
        view = make_view(camera, camera_to_world, scale, self.device)
        if cam_idx is not None:
            self._training_views[key] = view
        return view

    def background(
        self,
        K: Tensor,
        camera_to_world: Tensor,
        frame_embed: Tensor,
        width: int,
        height: int,
        cam_idx: Optional[int] = None,
        pinhole: Optional[Tuple[float, float, float, float]] = None,
    ) -> Tensor:
        """Background radiance per pixel [H, W, 1], evaluated on the `background_stride` grid and
        upsampled. In training (and under autograd) the MLP runs on every grid point; `cam_idx`
        names a training camera whose pose is fixed (no pose optimisation), whose encoded
        directions are computed once and reused. Every other render samples the baked map
        (`baked_background_map`) along the camera-frame directions of `K`, rotated; `pinhole`:
        `K`'s fx, fy, cx, cy on the host, where the caller has them (else they are read from `K`)."""
        if self.background_mlp is None:
            if self.training and self.config.random_background:
                return torch.rand(1, 1, 1, device=self.device).expand(height, width, 1)
            return torch.full((height, width, 1), self.config.background_value, device=self.device)
        stride = self.config.background_stride
        if not self.training and not torch.is_grad_enabled():  # every render a user sees: from the baked map
            if pinhole is None:
                pinhole = tuple(K[[0, 1, 0, 1], [0, 1, 2, 2]].tolist())  # fx, fy, cx, cy
            dirs = self._frame_directions(K, pinhole, width, height, stride) @ camera_to_world[:3, :3].T  # [h, w, 3]
            return upsampled(sample_map(self.baked_background_map(frame_embed), dirs), width, height)
        key = (cam_idx, width, height)
        encoded = self._encoded_directions.get(key) if cam_idx is not None else None
        if encoded is None:
            dirs = ray_directions(K, camera_to_world, width, height, stride)  # [h, w, 3]
            encoded = self.background_mlp.encode(dirs)  # [h, w, E]
            if cam_idx is not None:
                self._encoded_directions[key] = encoded
        return upsampled(self.background_mlp.from_encoded(encoded, frame_embed), width, height)

    def get_outputs(self, camera: Cameras, frame_embedding: Optional[Tensor] = None) -> Dict[str, Union[Tensor, List]]:
        """The render of `camera`: in training, at its training frame's state; otherwise at the
        photometric state whose `frame_embedding` [Df] the caller passes, else the viewer's
        (`viewer_embedding`)."""
        if not isinstance(camera, Cameras):
            raise TypeError(f"WildThermalModel.get_outputs needs a Cameras object, got {type(camera).__name__}")
        if self.training:
            assert camera.shape[0] == 1, "Only one camera at a time"
        fixed_pose = (
            self.training
            and self.config.camera_optimizer.mode == "off"
            and camera.metadata
            and "cam_idx" in camera.metadata
        )
        cam_idx = int(camera.metadata["cam_idx"]) if fixed_pose else None
        view = self._view(camera, self._get_downscale_factor(), cam_idx)
        viewmat, K, W, H = view.viewmat, view.K, view.width, view.height
        self.last_size = (H, W)
        frame_embed = self.frame_embedding(camera, frame_embedding)
        with record_function("thermal/background"):  # named sections for python -m experiments.profile_step
            background = self.background(
                K[0], view.camera_to_world[0], frame_embed, W, H, cam_idx, pinhole=view.pinhole
            )  # [H, W, 1]

        ids = None
        if self.crop_box is not None and not self.training:
            ids = self.crop_box.within(self.means).squeeze()
        if self.num_points == 0 or (ids is not None and ids.sum() == 0):
            if self.training:
                raise RuntimeError(
                    "All Gaussians have been pruned: training collapsed. Lower cull_alpha_thresh or "
                    "check the data (constant or NaN frames)."
                )
            CONSOLE.log("[yellow]WildThermalModel: no Gaussians to render; returning the background only.")
            return self._outputs(background, torch.zeros_like(background), background, None)

        def crop(x: Tensor) -> Tensor:
            return x if ids is None else x[ids]

        render_mode = "RGB+ED" if (self.config.output_depth_during_training or not self.training) else "RGB"
        with record_function("thermal/emission"):
            colors = self.gaussian_emission(frame_embed, ids)  # [N, 1]
        with record_function("thermal/rasterize"):
            render, alpha, self.info = rasterization(
                means=crop(self.means),
                quats=crop(self.quats),  # rasterization normalises internally
                scales=torch.exp(crop(self.scales)),
                opacities=torch.sigmoid(crop(self.opacities)).squeeze(-1),
                colors=colors,
                viewmats=viewmat,
                Ks=K,
                width=W,
                height=H,
                packed=False,
                near_plane=0.01,
                far_plane=1e10,
                render_mode=render_mode,
                sh_degree=None,
                sparse_grad=False,
                absgrad=self.strategy.absgrad,
                rasterize_mode=self.config.rasterize_mode,
                backend=self.config.rasterizer,
            )  # [1, H, W, 1(+1)], [1, H, W, 1]
        if self.training and torch.is_grad_enabled():  # no densification statistics from no-grad renders
            self.strategy.step_pre_backward(
                self.gauss_params, self.optimizers, self.strategy_state, self.step, self.info
            )
        alpha = alpha[0]
        thermal = render[0, ..., :1] + (1.0 - alpha) * background  # premultiplied render over background
        depth = None
        if render_mode == "RGB+ED":
            depth = render[0, ..., 1:2]
            depth = torch.where(alpha > 0, depth, depth.detach().max())
        return self._outputs(thermal, alpha, background, depth)

    @torch.no_grad()
    def get_outputs_for_camera(
        self, camera: Cameras, obb_box=None, frame_embedding: Optional[Tensor] = None
    ) -> Dict[str, Tensor]:
        """Splatfacto's, at the state of `frame_embedding` (`get_outputs`), without its copy of a
        camera already on the model's device (a new Cameras object per frame, whose construction
        costs more host time than the splatting)."""
        self.set_crop(obb_box)
        return self.get_outputs(camera if camera.device == self.device else camera.to(self.device), frame_embedding)

    def _outputs(self, thermal: Tensor, alpha: Tensor, background: Tensor, depth: Optional[Tensor]) -> Dict:
        clipped = thermal.clamp(0.0, 1.0)
        if self.training:  # nothing reads rgb while training: the cheapest grey view
            rgb = clipped.expand(-1, -1, 3)
        else:  # the thermal colormap (viewer, ns-render)
            rgb = self.colormap_table(clipped.device)[(clipped[..., 0] * 255).round().long()]  # [H, W, 3]
        return {  # rgb first: the viewer shows the first output by default
            "rgb": rgb,
            "thermal": thermal,  # [H, W, 1], normalised dataset units (training space)
            "accumulation": alpha,
            "background": background,
            "depth": depth,
        }

    def colormap_table(self, device) -> Tensor:
        """The viewer's colormap's (the configured one outside the viewer) 256 colours [256, 3] in
        [0, 1] on `device`."""
        name = self.viewer_controls.colormap
        cached = self._colormap_table
        if cached is None or cached[0] != (name, str(device)):
            table = torch.from_numpy(palette_rgb(name).astype("float32") / 255.0).to(device)
            self._colormap_table = cached = ((name, str(device)), table)
        return cached[1]

    # ----------------------------------------------------------------- losses
    def _ground_truth(self, outputs: Dict, batch: Dict) -> Tuple[Tensor, Optional[Tensor]]:
        """Ground-truth thermal image at the render's resolution (non-finite pixels replaced by the
        render, so they add nothing to losses and metrics) and, for a training frame without
        such pixels, its thermal contrast (for the heat-aware SSIM). Both checks run once per
        training frame and resolution: the frames never change."""
        image = batch["image"]
        if image.dim() != 3 or image.shape[-1] != 1:
            raise ValueError(
                f"WildThermalModel expects single-channel thermal images [H, W, 1]; image {batch.get('image_idx')} "
                f"has shape {tuple(image.shape)}. Use the thermal datamanager/dataparsers of thermal_wild_ns."
            )
        gt = self.get_gt_img(image)
        key = (int(batch["image_idx"]), tuple(gt.shape)) if self.training and "image_idx" in batch else None
        checked = self._frame_checks.get(key) if key is not None else None
        if checked is None:
            all_finite = bool(torch.isfinite(gt).all())
            original = self.to_original_space(gt, key[0]) if key is not None and all_finite else None
            reference = gt if original is None else original
            checked = (all_finite, thermal_contrast(reference) if all_finite else None, original)
            if key is not None:
                self._frame_checks[key] = checked
        all_finite, contrast, _ = checked
        if not all_finite:
            finite = torch.isfinite(gt)
            if not self._warned_nonfinite:
                CONSOLE.log(
                    f"[yellow]Image {batch.get('image_idx')} has {int((~finite).sum())} non-finite pixels; "
                    "they are left out of the loss and metrics."
                )
                self._warned_nonfinite = True
            gt = torch.where(finite, gt, outputs["thermal"].detach())
        return gt, contrast

    def get_metrics_dict(self, outputs, batch) -> Dict[str, Tensor]:
        gt, _ = self._ground_truth(outputs, batch)
        return {"psnr": psnr(outputs["thermal"].detach(), gt), "gaussian_count": self.num_points}

    def get_loss_dict(self, outputs, batch, metrics_dict=None) -> Dict[str, Tensor]:
        with record_function("thermal/loss"):
            losses = self._loss_dict(outputs, batch)
        if self.training:
            frame = int(batch["image_idx"]) if "image_idx" in batch else None
            self._last_training_loss = (sum(losses.values()).detach(), frame)
        return losses

    # ------------------------------------------------- the trainer's interface (training/model_interface.py)
    def last_training_loss(self) -> Tuple[Optional[Tensor], Optional[int]]:
        """The last training step's total loss (detached) and its training image (the divergence guard's)."""
        return self._last_training_loss

    def discard_step_statistics(self) -> None:
        """This step's gradients stay out of the densification statistics (a step the guard skipped)."""
        self._discard_statistics = True

    def to_original_space(self, values: Tensor, image: int) -> Optional[Tensor]:
        """Training-space values of training image `image` taken back to the original space through
        its inverse LUT (piecewise linear, differentiable); None without inverse LUTs."""
        if self.inverse_luts is None or self.config.loss_space != "original":
            return None
        table = self.inverse_luts[image]  # [S]
        position = values.clamp(0.0, 1.0) * (table.shape[0] - 1)
        lower = position.detach().floor().clamp(max=table.shape[0] - 2)
        weight = position - lower
        lower = lower.long()
        return table[lower] * (1.0 - weight) + table[lower + 1] * weight

    def _loss_dict(self, outputs, batch) -> Dict[str, Tensor]:
        gt, contrast = self._ground_truth(outputs, batch)
        pred = outputs["thermal"]
        cfg = self.config
        compared_pred, compared_gt, l1_scale = pred, gt, 1.0
        if self.training and "image_idx" in batch and cfg.loss_space == "original":
            key = (int(batch["image_idx"]), tuple(gt.shape))
            original = self._frame_checks.get(key, (None, None, None))[2]
            if original is not None:
                # L1 in units of the frame's own contrast, so that its weight against the
                # (contrast-relative) SSIM and the alpha term stays what it is in training space
                compared_pred, compared_gt = self.to_original_space(pred, key[0]), original
                l1_scale = 1.0 / contrast
        plain_ssim = lambda: ssim(compared_pred, compared_gt, data_range=1.0)
        losses = {
            "l1_loss": cfg.l1_lambda * l1_scale * (compared_gt - compared_pred).abs().mean(),
            "ssim_loss": cfg.ssim_lambda
            * (1.0 - (heat_aware_ssim(compared_pred, compared_gt, contrast) if cfg.heat_aware_ssim else plain_ssim())),
        }
        if cfg.alpha_lambda > 0:
            losses["alpha_loss"] = cfg.alpha_lambda * alpha_regularizer(
                outputs["accumulation"], gt, outputs["background"], cfg.alpha_reg_tolerance
            )
        if self.training:
            self.camera_optimizer.get_loss_dict(losses)
        return losses

    def load_state_dict(self, state_dict, strict: bool = True, **kwargs):  # type: ignore[override]
        """Refuse checkpoints that do not fit this config, with the reason, before nerfstudio's
        loader falls back to a non-strict load that would silently drop the MLPs or embeddings."""
        parts = {
            "emission MLP (use_emission_mlp)": ("emission_mlp.", self.emission_mlp is not None),
            "per-Gaussian embeddings (use_emission_mlp)": ("gauss_params.gauss_embed", self.emission_mlp is not None),
            "background MLP (use_background_mlp)": ("background_mlp.", self.background_mlp is not None),
        }
        for what, (prefix, wanted) in parts.items():
            present = any(k.startswith(prefix) for k in state_dict)
            if present != wanted:
                raise ValueError(
                    f"checkpoint {'has' if present else 'lacks'} the {what} but this config "
                    f"{'disables' if present else 'enables'} it: "
                    "load it with the config it was trained with (its config.yml)"
                )
        frames = state_dict.get("frame_embed.weight")
        if frames is not None and tuple(frames.shape) != tuple(self.frame_embed.weight.shape):
            raise ValueError(
                f"checkpoint has {frames.shape[0]} frame embeddings of size {frames.shape[1]}, this config "
                f"{self.frame_embed.weight.shape[0]} of size {self.frame_embed.weight.shape[1]}: it was trained on "
                f"other data or settings"
            )
        return super().load_state_dict(state_dict, strict=strict, **kwargs)

    # The densification statistics and the global torch RNG (gsplat's splits sample from it) go into
    # the checkpoint with the parameters, so a resumed run continues the same run.
    def get_extra_state(self) -> dict:
        state = {k: v for k, v in self.strategy_state.items() if v is not None}
        return {"strategy_state": state, "torch_rng_state": torch.get_rng_state()}

    def set_extra_state(self, state: dict) -> None:
        if not state:
            return
        for key, value in state.get("strategy_state", {}).items():
            self.strategy_state[key] = value.to(self.device) if isinstance(value, Tensor) else value
        if "torch_rng_state" in state:
            torch.set_rng_state(state["torch_rng_state"])

    def step_post_backward(self, step):
        if self._discard_statistics:  # the guard skipped this step: no statistics from it
            self._discard_statistics = False
            return
        with record_function("thermal/densify"):
            super().step_post_backward(step)

    @property
    def settled_step(self) -> int:
        """The first step past the schedule's start-up: training at full resolution (splatfacto's
        warm-up halves the downscale factor every `resolution_schedule` steps, from
        2^num_downscales) and past the first opacity reset. Before it, each of these moves every
        score by itself (the automatic stop does not score before it)."""
        return max(self.config.num_downscales * self.config.resolution_schedule, self.strategy.reset_every)

    def schedule_moves_loss(self, step: int) -> bool:
        """Whether the training schedule itself moves the loss at `step`: the first step after an
        opacity reset, or the first at a finer training resolution. The divergence guard takes a
        new baseline there rather than skipping each frame's jump as a spike."""
        reset_every, stop = self.strategy.reset_every, self.strategy.refine_stop_iter
        after_reset = 1 < step <= stop and (step - 1) % reset_every == 0  # gsplat resets at step % reset_every == 0
        r = self.config.resolution_schedule
        finer = step % r == 0 and 0 < step // r <= self.config.num_downscales  # splatfacto halves the downscale here
        return after_reset or finer

    def get_image_metrics_and_images(self, outputs, batch) -> Tuple[Dict[str, float], Dict[str, Tensor]]:
        gt, _ = self._ground_truth(outputs, batch)
        pred = outputs["thermal"]
        metrics = {
            "psnr": float(psnr(pred, gt)),
            "ssim": float(ssim(pred, gt, data_range=1.0)),
            "gaussian_count": float(self.num_points),
        }
        images = {"img": torch.cat([gt, pred], dim=1).clamp(0, 1).expand(-1, -1, 3)}
        return metrics, images
