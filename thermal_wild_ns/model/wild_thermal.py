"""WildThermalModel: splatfacto for thermal-only data ("Thermal is Always Wild", CVPR 2026).

What differs from `SplatfactoModel` (only these methods are overridden): one scalar emission per
Gaussian, from a per-Gaussian and a per-frame embedding through an emission MLP (`fields.py`), plus an
optional view-dependent term (`view_emission.py`); a background MLP b(direction, frame embedding) fills
the residual transmittance, image = render + (1 - alpha) * b (`background.py`); the loss is L1 +
heat-aware SSIM + alpha regulariser (`thermal_loss.py`); renders go through `rendering.rasterization`
(gsplat on CUDA, pure torch elsewhere); no LPIPS (it would download weights). Outside training a
render is at the state its caller passes (`frame_embedding`), else the canonical one: renders are stable.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, List, Literal, Optional, Sequence, Tuple, Type, Union

import torch
import tyro
from nerfstudio.cameras.camera_optimizers import CameraOptimizer
from nerfstudio.cameras.cameras import Cameras
from nerfstudio.models.splatfacto import SplatfactoModel, SplatfactoModelConfig
from nerfstudio.utils.rich_utils import CONSOLE
from torch import Tensor, nn
from torch.nn import Parameter

from thermal_wild_ns._upstream import profiled_section
from thermal_wild_ns.decisions import Decision
from thermal_wild_ns.errors import InputError
from thermal_wild_ns.image_metrics import image_metrics_and_images, psnr
from thermal_wild_ns.model.background import CameraFrameDirections, ThermalBackground
from thermal_wild_ns.model.bake import BakedValues
from thermal_wild_ns.model.camera_falloff import (
    FALLOFF_ORDER,
    describe_falloff,
    describe_flat_field,
    falloff_basis,
    respond,
)
from thermal_wild_ns.model.camera_views import TrainingViews, View, ViewingViews, host_sizes, intrinsics
from thermal_wild_ns.model.config_checks import (
    refuse_mismatched_checkpoint,
    refuse_options_without_their_part,
    refuse_unused_options,
)
from thermal_wild_ns.model.fields import BackgroundMLP, EmissionMLP, packed_adam_state
from thermal_wild_ns.model.frame_states import Emission, FrameStates
from thermal_wild_ns.model.gaussians import GreyColourAccessors, initial_gaussians
from thermal_wild_ns.model.graphed import GraphedCalls, PaddedRowCalls
from thermal_wild_ns.model.in_view import few_view_mask, in_view
from thermal_wild_ns.model.schedule import schedule_moves_loss, settled_step
from thermal_wild_ns.model.strategy import BudgetedDefaultStrategy
from thermal_wild_ns.model.thermal_loss import ResizedFrames, ThermalLoss, checked_thermal_image, inverse_lut_table
from thermal_wild_ns.model.view_emission import radial_part, view_term
from thermal_wild_ns.pipeline.ranks import RankGroup
from thermal_wild_ns.rendering import (
    FAR_PLANE,
    NEAR_PLANE,
    Backend,
    rasterization,
    rasterize_unpacked,
    render_one_view,
    world_to_camera,
)
from thermal_wild_ns.rendering.captured import CapturedCalls
from thermal_wild_ns.rendering.viewer_controls import ThermalViewerControls, thermal_rgb

TYPICAL_STATE_GAUSSIANS = 16_384
"""Gaussians the 'typical' canonical state is fitted on (`typical_state_emission`)."""

BAKE_ROWS = 1 << 22
"""Gaussians per evaluation of the emission MLP when its output is baked (`baked_emission`)."""

TRAINING_COLLAPSED = (
    "All Gaussians have been pruned: training collapsed. Lower cull_alpha_thresh or check the data (constant or "
    "NaN frames)."
)

GROUND_TRUTH_KEY = "_ground_truth"
"""Where a training step's outputs keep its frame as the loss compares it (`_ground_truth`)."""


def composite(
    render: Tensor, alpha: Tensor, background: Tensor, camera: int = 0
) -> Tuple[Tensor, Tensor, Optional[Tensor]]:
    """Camera `camera` of gsplat's render [C, H, W, 1(+1)] (emission, and depth where asked) with its alpha
    [C, H, W, 1] over `background` [H, W, 1]: the thermal image (premultiplied render over the background),
    the alpha [H, W, 1] and the depth [H, W, 1] (the farthest rendered depth where nothing was drawn) or None."""
    emission, alpha, depth = camera_planes(render, alpha, camera)
    return over_background(emission, alpha, background), alpha, depth


def camera_planes(render: Tensor, alpha: Tensor, camera: int = 0) -> Tuple[Tensor, Tensor, Optional[Tensor]]:
    """Camera `camera` of gsplat's render [C, H, W, 1(+1)] and alpha [C, H, W, 1]: its emission [H, W, 1]
    (premultiplied), alpha [H, W, 1] and depth [H, W, 1] (the farthest rendered depth where nothing was
    drawn) or None."""
    # one camera's render as views autograd undoes as views (a squeeze; the whole last axis): an indexing
    # view's backward (a select's, a slice's) fills a zero tensor and copies into it, kernels and host
    # operations at every training step
    if render.shape[0] == 1:
        render, alpha = render.squeeze(0), alpha.squeeze(0)
    else:
        render, alpha = render[camera], alpha[camera]
    emission = render if render.shape[-1] == 1 else render[..., :1]
    depth = None
    if render.shape[-1] > 1:
        depth = render[..., 1:2]
        depth = torch.where(alpha > 0, depth, depth.detach().max())
    return emission, alpha, depth


def over_background(emission: Tensor, alpha: Tensor, background: Tensor) -> Tensor:
    """The premultiplied `emission` [H, W, 1] of a render of `alpha` [H, W, 1] over `background` [H, W, 1]."""
    return emission + (1.0 - alpha) * background


def recorded_over_background(
    emission: Tensor,
    alpha: Tensor,
    background: Tensor,
    coefficients: Tensor,
    basis: Tensor,
    flat_field: Optional[Tensor] = None,
) -> Tensor:
    """`over_background`, as the camera records it (`camera_falloff.respond`): one function of tensors, so
    that a training step records the compositing and the camera model in one CUDA graph."""
    return respond(over_background(emission, alpha, background), coefficients, basis, flat_field)


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
    background_frame_coupling: Literal["mlp", "affine"] = "affine"
    """How the frame embedding enters the background MLP: 'affine', as a gain and an offset of a
    direction-only map (a frame's state changes the whole background alike, as a sensor's drift or
    flat-field step does; chosen on both real captures and the drifting scenes, docs/results.md's
    defaults table); 'mlp', as an input beside the view direction (the paper's b(d, e_t), free to
    change the background's shape from frame to frame)."""
    background_mlp_width: int = 64
    """Width of the background MLP's hidden layers."""
    background_mlp_layers: int = 2
    """Number of hidden layers (ReLU) of the background MLP."""
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
    inference_embedding: str = "typical"
    """Frame embedding used outside training (evaluation, viewer, renders): 'typical' (the state whose
    emission is closest on average to every training frame's: docs/design.md; chosen over 'mean' by
    both real captures, docs/results/canonical_dunr_h200 and canonical_flight2_h200), 'mean' (average
    of the training frames' embeddings), 'zero', or a training-frame index such as '12'."""
    colormap: Literal["iron", "inferno", "grey"] = "iron"
    """Thermal colormap of the `rgb` output outside training (ns-viewer, ns-render videos); the
    viewer has a control for it. `thermal` stays the scalar image."""
    loss_space: Literal["training", "original"] = "training"
    """Where the photometric loss compares render and frame: 'training' (the preprocessed frames the
    model renders) or 'original' (both taken back through the frame's inverse LUT, so that
    equalization shapes the gradients' reach but cannot amplify errors where it stretched the
    levels). The same for frames that were not preprocessed."""
    view_sh_degree: int = 0
    """Degree (0, 1 or 2) of a per-Gaussian view-dependent emission term (emissivity and reflected sky
    change with the view angle), the same at every capture time (`view_emission.py`). 0: none (helped a
    drone survey, cost a scene with vignetting, with the camera model on as well: docs/results/view_term_gpu,
    docs/results/view_defaults_h200; less since the camera model learns faster: docs/results/camera_rate_h200).
    On that survey it is what keeps a model with a larger Gaussian budget from losing held-out views
    (docs/results/growth): `wild-thermal` has a degree-2 term that waits for a large budget
    (`view_term_above_budget`).
    `--auto-stop.decide-view-term` lets each capture decide whether it stays (it drops a term that does
    the camera model's work: docs/results/view_share_h200)."""
    view_term_from_step: int = 0
    """With a view term (`view_sh_degree` > 0): the training step from which it takes part in renders.
    Until then the camera model (`camera_falloff`) and the scene fit alone, so that the camera's own
    radial response is the camera model's before the term can take it (with both learning from the
    first step the term took part of a scene's vignetting: docs/results/view_split_h200; delayed to step
    1,000 it took less, while the camera model's faster rate fixed it: docs/results/camera_rate_h200). With
    `--auto-stop.decide-view-term` the trial's renders with the term start here too. 0: from the start."""
    view_radial_penalty: float = 0.0
    """With a view term (`view_sh_degree` > 0): weight of a training loss on the part of the term that is
    radial about the image centre in the view being trained (the visible Gaussians' term values fitted by a
    gain and an offset fall-off in r^2, r^4 of their projected centres: `view_emission.radial_part`), so that
    the camera model (`camera_falloff`), not the scene, takes what every view shares radially, and the term
    keeps what follows surfaces. 0: no such loss (the term may take part of a camera's vignetting:
    docs/results/view_split_h200). At the weights tried so far it gave back only part of a generated
    scene's vignetting to the camera (docs/results/view_radial_penalty_h200): off by default."""
    view_term_above_budget: Optional[int] = None
    """With a view term (`view_sh_degree` > 0): the term takes part in renders only once the Gaussian budget
    (over every GPU: `max_gaussians`, or the one the held-back frames set, `--auto-stop.grow-budget`) is above
    this many; until then it is left out of every render and gets no gradient. A small model gained nothing from
    the term on either real capture, while a large model of a drone survey lost held-out views without it and
    held them with it (docs/results/growth, where the threshold comes from); a scene that never asks for a large
    model never pays for the term. None: the term takes part from the start.
    `--auto-stop.decide-view-term` replaces this rule where it is on."""
    camera_falloff: bool = False
    """Fit the camera's own radial fall-off (a gain and an offset growing towards the image corners,
    the same in every frame: `camera_falloff.py`) with the scene. It is rendered into every image
    compared with a recorded frame (training, the held-back scores, the evaluation protocols) and left
    out of the scene's renders (viewer, `ns-render`, exports), so vignetting is neither baked into the
    Gaussians nor shown to the user. `wild-thermal` fits it on every capture (four coefficients of a fixed
    radial shape: it fits itself flat where nothing vignettes; docs/results/radial_generated_h200) and
    adds an 8x8 flat-field map where the content crosses the sensor (`camera_pattern_min_motion`;
    docs/results/camera_flat_field); its ablations fit neither."""
    camera_flat_field: int = 0
    """With `camera_falloff`: cells per image side of a flat-field map fitted on top of the radial
    fall-off (a gain and an offset per cell, bilinear between cells, zero-mean: the camera's fixed
    pattern that is not radial; `camera_falloff.py`). 0: the radial fall-off alone. Without
    `camera_falloff` there is no camera model, and no map."""
    camera_pattern_min_motion: float = 0.0
    """Fit the flat-field map (as set above) only where the capture's content moves across the sensor by
    at least this much: the seed points' mean spread of image position over the frames that see them, in
    frame sizes (`data/content_motion.py`). Below it a pattern fixed to the sensor cannot be told from the
    content that sits at the same pixels in every frame, and a map takes scene content into it
    (docs/results/camera_flat_field); the radial fall-off, whose shape is fixed, does not and is fitted
    wherever `camera_falloff` asks. 0: the map as set, on any capture."""
    nonnegative_emission: bool = False
    """Render each Gaussian's emission (view term included) clamped at zero, as gsplat clamps a
    spherical-harmonic colour: radiance is never negative, so no Gaussian can subtract from what the
    Gaussians behind it emit. Off: the emission as learned, negative values included (clamping changed
    nothing beyond the seeds' spread on a real scene: docs/results/growth)."""
    heat_aware_ssim: bool = True
    """SSIM loss with constants scaled to each frame's contrast (off: plain SSIM, as 3DGS uses)."""
    graphed_loss: bool = True
    """On a GPU, replay the loss terms' forward and backward as CUDA graphs (one per frame size): the
    same kernels, one launch each way instead of dozens (docs/results/loss_graphs_h100). Training-space
    loss only; off: kernel by kernel."""
    graphed_background: bool = True
    """On a GPU, replay the background MLP's forward and backward in training as CUDA graphs (one per
    frame size), as `graphed_loss` does for the loss: the same kernels, less host time per step, a
    little more GPU memory for the graphs (docs/results/background_graphs_h100); off: kernel by kernel."""
    graphed_camera: bool = True
    """On a GPU, replay the camera model's response (`camera_falloff`, `camera_flat_field`) in training,
    forward and backward, as CUDA graphs (one per frame size), as `graphed_loss` does for the loss: the
    same kernels, one launch each way instead of a score of small ones. Off: kernel by kernel."""
    graphed_emission: bool = True
    """On a GPU, replay the emission MLP's forward and backward in training as CUDA graphs, recorded for a
    capacity of Gaussians (`graphed.PaddedRowCalls`): the Gaussians fill its first rows, so one recording
    serves the counts densification moves through between half its capacity and all of it (only the
    latest is kept; it holds the MLP's activations for every row): the same values up to float rounding,
    fewer launches. Off: kernel by kernel."""
    graphed_statistics: bool = True
    """On a GPU, replay each training step's densification statistics (the screen-space gradients and
    radii summed per Gaussian) as one CUDA graph, recorded again after each refinement: the same kernels
    and values, one launch instead of one per kernel. Off: kernel by kernel."""
    l1_lambda: float = 0.8
    """Weight of the L1 loss."""
    ssim_lambda: float = 0.2
    """Weight of the heat-aware SSIM loss (1 - SSIM)."""
    alpha_lambda: float = 0.01
    """Weight of the alpha regulariser against floaters in front of the background."""
    alpha_reg_tolerance: float = 0.02
    """Intensity difference (normalised units) under which a target pixel counts as 'explained by
    the background' for the alpha regulariser."""
    state_smoothness: float = 0.0
    """Weight of a penalty on each training frame's embedding's distance from the state its neighbours
    in capture time predict for it (`FrameStates.neighbour_residual`): the prediction the `time`
    protocol makes for a held-out frame, so the states stay predictable from their neighbours. 0: off."""
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
    """Densification never grows the model past this many Gaussians where the automatic stop does not
    set the budget from the held-back frames (`--auto-stop.grow-budget False`, or the stop off). The
    default is the knee of a budget sweep on DUNR (docs/results.md)."""
    few_view_prune_frames: int = 0
    """At each densification round, remove the Gaussians that this many training frames or fewer may draw (the
    `in_view` test, occlusion ignored; with `few_view_prune_nearer`, only those near a camera): fitted by a frame
    or two, such a Gaussian can take those frames' own level, which a view from elsewhere then sees. A model
    without a per-frame state (`wild-thermal-3dgs`) that grows on a drone survey puts the frames' level changes
    there (docs/results/growth). Across GPUs it stays off, and the run's decisions say so (each GPU holds a share
    of the Gaussians and renders every frame with the others: the counts are not kept per share). 0: no such
    pruning."""
    few_view_prune_nearer: float = 0.0
    """With `few_view_prune_frames`: only Gaussians whose nearest training camera is nearer than this times the
    median Gaussian's nearest camera are removed (floaters in front of a frame), so that the ground at the edge
    of a survey's coverage, seen by few frames from the usual distance, stays. 0: at any distance (near a
    camera only, a drone survey's stateless model still lost held-out views as it grew: docs/results/growth)."""
    few_view_prune_above_budget: Optional[int] = None
    """With `few_view_prune_frames`: the prune runs only while the Gaussian budget (over every GPU: `max_gaussians`,
    or the one the held-back frames set, `--auto-stop.grow-budget`) is above this many, as the view term waits for
    a large model (`view_term_above_budget`): a model that stays small leaves its densification as it is, one that
    grows large loses its few-view Gaussians. None: from the start."""
    emission_in_view_above: int = 1_000_000
    """Above this many Gaussians, training evaluates the emission MLP (and the view term) only for the
    Gaussians the camera can see (`in_view.py`): the same render, with memory and time that follow the
    frame rather than the whole site (large surveys). Below it, where a frame sees much of a small
    scene, the selection (a host sync per step) would save little. Training across GPUs always selects."""
    distributed: tyro.conf.Suppress[bool] = False
    """Set by the multi-GPU launcher (`training/distributed.py`): each rank of torch.distributed's
    process group holds every world-th Gaussian (and that share of `max_gaussians`) and renders through
    gsplat's distributed rasterization, all ranks together."""


class WildThermalModel(GreyColourAccessors, SplatfactoModel):
    """Splatfacto with scalar thermal emission, appearance embeddings and a background MLP."""

    config: WildThermalModelConfig

    # ------------------------------------------------------------------ setup
    def populate_modules(self):
        # Own version rather than super(): splatfacto's builds SH colour features with a hard-coded
        # .cuda(), a 3-channel SSIM and LPIPS (which downloads AlexNet weights).
        cfg = self.config
        refuse_unused_options(cfg)
        refuse_options_without_their_part(cfg)
        self.ranks = RankGroup.current() if cfg.distributed else RankGroup()
        # every rank builds the same initial model (one seed), then keeps its share of the Gaussians
        if self.ranks.split and (cfg.use_absgrad or cfg.camera_optimizer.mode != "off"):
            raise InputError(
                "training across GPUs needs --pipeline.model.use-absgrad False (gsplat's distributed "
                "rasterization has no absgrad) and --pipeline.model.camera-optimizer.mode off"
            )
        if cfg.few_view_prune_frames < 0 or cfg.few_view_prune_nearer < 0:
            raise InputError(
                f"few_view_prune_frames {cfg.few_view_prune_frames}, few_view_prune_nearer "
                f"{cfg.few_view_prune_nearer:g}: each must be 0 (off; at any distance) or more"
            )
        if cfg.few_view_prune_above_budget is not None and cfg.few_view_prune_above_budget < 0:
            raise InputError(
                f"few_view_prune_above_budget {cfg.few_view_prune_above_budget}: must be 0 or more (None: no rule)"
            )
        self.few_view_pruned = 0  # Gaussians the few-view prune removed (`_prune_few_view`), for `decisions`
        params = self.ranks.own_rows(initial_gaussians(self.seed_points, cfg, self.k_nearest_sklearn))
        self.gauss_params = nn.ParameterDict({k: Parameter(v) for k, v in params.items()})

        num_frames = max(self.num_train_data, 1)
        self.frame_embed = nn.Embedding(num_frames, cfg.frame_embed_dim)
        indices = self.kwargs.get("metadata", {}).get("frame_indices")
        # each training image's capture position (capture-order frame index): the photometric states' time axis
        self.frame_states = FrameStates(self.frame_embed, indices if indices is not None else range(num_frames))
        # `last_training_losses`
        self._last_training_losses: Tuple[Optional[Dict[str, Tensor]], Optional[int]] = (None, None)
        self._discard_statistics = False  # `discard_step_statistics`
        self._step_accepted: Optional[Tensor] = None  # `weigh_step_statistics`
        self._view_term = "on" if "view_sh" in self.gauss_params else "off"  # `use_view_term`, `try_view_term`
        self._view_term_waits = False  # for the Gaussian budget to pass `view_term_above_budget` (`_follow_budget`)
        self._view_term_by_trial = False  # the held-back frames' trial decides it instead (`try_view_term`)
        nn.init.zeros_(self.frame_embed.weight)
        self.emission_mlp = (
            EmissionMLP(cfg.gaussian_embed_dim, cfg.frame_embed_dim, cfg.emission_mlp_width, cfg.emission_mlp_layers)
            if cfg.use_emission_mlp
            else None
        )
        # its rows follow the Gaussian count, which moves on at every densification
        graphs = cfg.graphed_emission and self.emission_mlp is not None
        self.graphed_emission = PaddedRowCalls("emission MLP") if graphs else None
        if cfg.random_background and cfg.use_background_mlp:
            raise InputError("random_background needs use_background_mlp False: the background MLP models it")
        self._build_background(cfg.background_frame_coupling)
        # row 0 the gain's polynomial, row 1 the offset's (`camera_falloff.respond`); zero: no fall-off
        self.camera_falloff = Parameter(torch.zeros(2, FALLOFF_ORDER)) if cfg.camera_falloff else None
        self.falloff_why = "camera_falloff"
        if cfg.camera_flat_field < 0:
            raise InputError(f"camera_flat_field {cfg.camera_flat_field}: cells per image side, 0 (no map) or more")
        n = cfg.camera_flat_field
        fits_map, self.flat_field_why, self.flat_field_decided_by = self._flat_field_fitted()
        # [2, n, n]: row 0 the gain's cells, row 1 the offset's (`camera_falloff.flat_field_maps`); zero: flat
        self.camera_flat_field = Parameter(torch.zeros(2, n, n)) if fits_map else None
        self.camera_falloff_basis = CameraFrameDirections(derive=falloff_basis)  # per camera and size
        graphs = cfg.graphed_camera and self.camera_falloff is not None
        self.graphed_camera = GraphedCalls("camera model") if graphs else None
        self.camera_optimizer: CameraOptimizer = cfg.camera_optimizer.setup(
            num_cameras=self.num_train_data, device="cpu"
        )
        self.step = 0
        self.optimizers = {}  # set by splatfacto's step_cb once training starts
        self.crop_box = None
        self.background_color = torch.tensor([cfg.background_value] * 3)
        self.baked = BakedValues()  # outside training: `baked_emission`
        self.training_views = TrainingViews()
        self.resized_frames = ResizedFrames()  # the training frames at the warm-up's sizes: `_ground_truth`
        self.viewing_views = ViewingViews()  # outside training, with `captured`: `get_outputs`
        self.captured = CapturedCalls()  # outside training: `viewing_view_and_background`, `viewing_outputs`
        sequence = (self.kwargs.get("metadata") or {}).get("preprocessed")  # the training frames' LUTs
        use_luts = sequence is not None and cfg.loss_space == "original"
        self.thermal_loss = ThermalLoss(cfg, inverse_lut_table(sequence, self.frame_times) if use_luts else None)
        self.strategy = BudgetedDefaultStrategy.for_splatfacto(cfg, self.num_train_data, self.ranks.world)
        self.strategy_state = self.strategy.initialize_state(scene_scale=1.0)
        self._growth_ceiling: Optional[int] = None  # where a step ran out of GPU memory (`limit_growth`)
        self._follow_budget()  # the fixed budget's: a run whose held-back frames set it says so at its start
        self.viewer_controls = ThermalViewerControls(self.frame_times, cfg.colormap)
        """What the viewer's user chose (colormap, photometric state): read, never set, by the model."""

    def _build_background(self, coupling: str) -> None:
        """The background MLP (None where `use_background_mlp` is off) with the frame `coupling`, and the field that
        renders it."""
        cfg = self.config
        self.background_mlp = (
            BackgroundMLP(
                cfg.frame_embed_dim,
                coupling,
                width=cfg.background_mlp_width,
                hidden_layers=cfg.background_mlp_layers,
                init_value=cfg.background_value,
            )
            if cfg.use_background_mlp
            else None
        )
        self.background_field = ThermalBackground(self.background_mlp, cfg)

    def _map_left_by_motion(self) -> bool:
        """Whether the content-motion rule (not the config) left the flat-field map out."""
        return self.camera_flat_field is None and self.flat_field_decided_by == "data"

    def _flat_field_fitted(self) -> Tuple[bool, str, str]:
        """Whether the camera's flat-field map is fitted, why, and what decided it ('config', or 'data':
        the capture's content motion against `camera_pattern_min_motion`)."""
        cfg = self.config
        threshold = cfg.camera_pattern_min_motion
        if not cfg.camera_falloff or cfg.camera_flat_field == 0:
            return False, "camera_flat_field 0" if cfg.camera_falloff else "no camera model (camera_falloff)", "config"
        if threshold <= 0:
            return True, f"camera_flat_field {cfg.camera_flat_field}", "config"
        motion = (self.kwargs.get("metadata") or {}).get("content_motion")
        if motion is None:
            return False, "no seed point is seen in two frames: how far the content moves is unknown", "data"
        verdict = ">=" if motion >= threshold else "<: a fixed pattern is not told apart from the scene there"
        why = f"the content moves {motion:.2f} of the frame across the sensor ({verdict} {threshold:g})"
        return motion >= threshold, why, "data"

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
        if self.emission_mlp is not None:
            groups["emission_mlp"] = list(self.emission_mlp.parameters())
        if self.background_mlp is not None:
            groups["background_mlp"] = list(self.background_mlp.parameters())
        if self.camera_falloff is not None:
            groups["camera_falloff"] = [self.camera_falloff]
        if self.camera_flat_field is not None:
            groups["camera_flat_field"] = [self.camera_flat_field]
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
        viewer's capture time where its user chose one, else the canonical `inference_embedding`, which
        lags a training run by up to `frame_states.VIEWER_REFIT_STEPS` steps (`FrameStates.for_viewer`)."""
        t = self.viewer_controls.capture_time
        if t is not None:
            return self.frame_states.named(f"time:{t}", self.step)
        return self.frame_states.for_viewer(self.config.inference_embedding, self.step, self.typical_state_emission)

    @property
    def uses_frame_embedding(self) -> bool:
        """Whether renders depend on the frame embedding (through either MLP)."""
        return self.emission_mlp is not None or self.background_mlp is not None

    def embedding_at(self, t: float) -> Tensor:
        """The frame embedding [Df] at capture position `t` (`FrameStates.at`)."""
        return self.frame_states.at(t)

    def interpolate_embeddings(self, rows: Sequence[int]) -> None:
        """Fill the embeddings of training images held back from the gradient (`training/auto_stop.py`)
        from their neighbours' (`FrameStates.fill_from_neighbours`): every state then is the data's."""
        self.frame_states.fill_from_neighbours(rows)

    def inference_embedding(self) -> Tensor:
        """The canonical frame embedding [Df] (`inference_embedding`; the typical state by
        default), the same tensor until the embeddings change, so the baked emission keyed on it holds."""
        return self.frame_states.named(self.config.inference_embedding, self.step, self.typical_state_emission)

    def typical_state_emission(self) -> Optional[Emission]:
        """What the 'typical' canonical state matches (`frame_states.typical_state`): the emission of
        up to `TYPICAL_STATE_GAUSSIANS` Gaussians (a fixed draw) under a state, each weighted by its
        opacity (a faint Gaussian barely shows in a render). None without the emission MLP, and while
        the Gaussians are split across GPUs: each rank holds a share, and the photometric state must be
        one on every rank, so there the canonical state is the mean until one GPU loads the run."""
        if self.emission_mlp is None or self.num_points == 0 or self.ranks.split:
            return None
        g = torch.Generator(device="cpu").manual_seed(0)
        n = min(self.num_points, TYPICAL_STATE_GAUSSIANS)
        pick = torch.randperm(self.num_points, generator=g)[:n].to(self.device)
        base, embed = self.emission[pick].detach(), self.gauss_params["gauss_embed"][pick].detach()  # [n, 1], [n, Dg]
        weight = torch.sigmoid(self.opacities[pick].detach()).squeeze(-1)  # [n]
        return lambda state: self.emission_mlp(base, embed, state).squeeze(-1) * weight

    def gaussian_emission(self, frame_embed: Tensor, ids: Optional[Tensor] = None, slot: int = 0) -> Tensor:
        """Scalar emission of every (or the selected) Gaussian in the frame [N, 1]. Outside
        training and autograd the MLP's output is baked: computed once per (frame embedding,
        parameter state) and reused, so viewing costs what plain splatting costs. `slot`: the
        camera's place among a training step's cameras (`GraphedCalls`)."""
        if self.emission_mlp is None:
            return self.emission if ids is None else self.emission[ids]
        if not self.training and not torch.is_grad_enabled():
            emission = self.baked_emission(frame_embed)
            return emission if ids is None else emission[ids]
        base = self.emission if ids is None else self.emission[ids]
        embed = self.gauss_params["gauss_embed"]
        if self.graphed_emission is not None and ids is None and self.training and torch.is_grad_enabled():
            return self.graphed_emission(self.emission_mlp, (base, embed), (frame_embed,), slot=slot)
        return self.emission_mlp(base, embed if ids is None else embed[ids], frame_embed)

    def radiance(self, emission: Tensor) -> Tensor:
        """What Gaussians send toward the camera [N, C] from their emission, view term included
        [N, C]: clamped at zero with `nonnegative_emission` (every render and export goes through this)."""
        return emission.clamp_min(0.0) if self.config.nonnegative_emission else emission

    def baked_emission(self, frame_embed: Tensor) -> Tensor:
        """The emission MLP evaluated for every Gaussian under `frame_embed` [N, 1], kept until the
        embedding or any parameter it depends on changes (`BakedValues`). Evaluated `BAKE_ROWS`
        Gaussians at a time: the hidden activations of a model of hundreds of millions at once
        would need more memory than the model."""
        embed = self.gauss_params["gauss_embed"]
        tensors = (self.emission, embed, *self.baked.parameters_of(self.emission_mlp), frame_embed)

        def bake() -> Tensor:
            rows = range(0, embed.shape[0], BAKE_ROWS)
            parts = [
                self.emission_mlp(self.emission[i : i + BAKE_ROWS], embed[i : i + BAKE_ROWS], frame_embed) for i in rows
            ]
            return parts[0] if len(parts) == 1 else torch.cat(parts)

        return self.baked.get("emission", tensors, self.step, bake)

    def get_outputs(self, camera: Cameras, frame_embedding: Optional[Tensor] = None) -> Dict[str, Union[Tensor, List]]:
        """The render of `camera`: in training, at its training frame's state; otherwise at the
        photometric state whose `frame_embedding` [Df] the caller passes, else the viewer's
        (`viewer_embedding`)."""
        if not isinstance(camera, Cameras):
            raise TypeError(f"WildThermalModel.get_outputs needs a Cameras object, got {type(camera).__name__}")
        if self.training:
            assert camera.shape[0] == 1, "Only one camera at a time"
        cam_idx = self._fixed_pose_index(camera)
        frame_embed = self.frame_embedding(camera, frame_embedding)
        ids = None
        if self.crop_box is not None and not self.training:
            ids = self.crop_box.within(self.means).squeeze()
        # a render a user waits for: its fixed-shape pieces replayed as CUDA graphs (`rendering/captured.py`)
        viewing = not self.training and not torch.is_grad_enabled() and ids is None and not self.ranks.split
        if viewing:  # full resolution; its view matrix comes with the background (`viewing_view_and_background`)
            view = self.viewing_views.get(camera, self.device)
        else:
            view = self._posed_view(camera, cam_idx)
        W, H = view.width, view.height
        self.last_size = (H, W)
        with profiled_section("thermal/background"):  # named sections for python -m experiments.profile_step
            if viewing:
                viewmat, background = self.viewing_view_and_background(view, frame_embed)
            else:
                viewmat, background = view.viewmat, self._background(view, frame_embed, cam_idx)  # [H, W, 1]

        if self.num_points == 0 or (ids is not None and ids.sum() == 0):
            if self.training:
                raise RuntimeError(TRAINING_COLLAPSED)
            CONSOLE.log("[yellow]WildThermalModel: no Gaussians to render; returning the background only.")
            background = background.clone()  # outside training, a CUDA graph's buffer until its next replay
            return self._outputs(background, torch.zeros_like(background), background, None)

        camera_position = view.camera_to_world[0, :3, 3]  # [3]
        # the Gaussians are split across GPUs: every render is one of all ranks together (outside
        # training, the automatic stop's: every rank renders the same camera at the same state)
        split = self.ranks.split
        with profiled_section("thermal/emission"):
            if split and self.training:  # one channel per rank: each rank's camera sees these Gaussians at its state
                colors = self.emission_for_every_rank(frame_embed, cam_idx_of(camera), view)  # [N, W]
            elif self.training and self.num_points > self.config.emission_in_view_above:
                colors = self.emission_in_view(frame_embed, view.viewmat[0], view.K[0], W, H, camera_position)
            else:
                colors = self._emission(frame_embed, camera_position, ids)  # [N, 1]
            colors = self.radiance(colors)
        with profiled_section("thermal/rasterize"):
            if viewing:  # one camera, no autograd, every Gaussian
                activated = self.baked.get("activated", (self.scales, self.opacities), self.step, self.activated_splats)
                render, alpha = render_one_view(
                    self.means,
                    self.quats,
                    *activated,
                    colors,
                    viewmat,
                    view.K,
                    W,
                    H,
                    self.config.rasterize_mode,
                    self.config.rasterizer,
                )  # [1, H, W, 2], [1, H, W, 1]
            else:
                render, alpha = self._rasterize(colors, viewmat, view.K, W, H, ids)
                # [1, H, W, 1(+1)] ([1, H, W, W(+1)] split in training: this rank's channel is kept), [1, H, W, 1]
        if split and self.training:
            render = torch.cat(
                [render[..., self.ranks.rank : self.ranks.rank + 1], render[..., self.ranks.world :]], -1
            )
        self._count_for_densification()
        if viewing:
            return self.viewing_outputs(render, alpha, background)
        return self._composited_outputs(render, alpha, background, view, colors, 0)

    def get_training_outputs(self, cameras: Sequence[Cameras]) -> List[Dict[str, Union[Tensor, List]]]:
        """The training renders of several cameras of one size, each at its frame's state, in one
        rasterization (`ThermalPipelineConfig.cameras_per_step`): the step's fixed costs (gsplat's
        launches and sorting, the Python around them) are paid once for all of them. Each camera's
        view, background, emission and camera response as `get_outputs` makes them; the densification
        statistics count each camera a Gaussian is seen from, as gsplat's own. One camera is `get_outputs`."""
        if len(cameras) == 1:
            return [self.get_outputs(cameras[0])]
        if not self.training or self.ranks.split:
            raise RuntimeError("several cameras per render: training on one GPU only")
        views, backgrounds, colors = [], [], []
        for slot, camera in enumerate(cameras):  # a slot each: CUDA graphs replay per slot (`GraphedCalls`)
            cam_idx = self._fixed_pose_index(camera)
            frame_embed = self.frame_embedding(camera)
            view = self._posed_view(camera, cam_idx)
            with profiled_section("thermal/background"):
                backgrounds.append(self._background(view, frame_embed, cam_idx, slot))  # [H, W, 1]
            with profiled_section("thermal/emission"):
                # every Gaussian's, whatever the model's size (`emission_in_view_above` picks those of one camera)
                colors.append(self._emission(frame_embed, view.camera_to_world[0, :3, 3], slot=slot))  # [N, 1]
            views.append(view)
        W, H = views[0].width, views[0].height
        sizes = sorted({(view.width, view.height) for view in views})
        if len(sizes) > 1:
            raise ValueError(f"several cameras per render need frames of one size; this step's: {sizes}")
        self.last_size = (H, W)
        if self.num_points == 0:
            raise RuntimeError(TRAINING_COLLAPSED)
        colors = self.radiance(torch.stack(colors))  # [B, N, 1]
        with profiled_section("thermal/rasterize"):
            viewmats, Ks = torch.cat([view.viewmat for view in views]), torch.cat([view.K for view in views])
            render, alpha = self._rasterize(colors, viewmats, Ks, W, H, None)  # [B, H, W, 1(+1)], [B, H, W, 1]
        self._count_for_densification()
        return [
            self._composited_outputs(render, alpha, backgrounds[c], views[c], colors[c], c) for c in range(len(views))
        ]

    def _fixed_pose_index(self, camera: Cameras) -> Optional[int]:
        """The training image of a training camera whose pose is fixed (no pose optimizer), else None."""
        fixed_pose = (
            self.training
            and self.config.camera_optimizer.mode == "off"
            and camera.metadata
            and "cam_idx" in camera.metadata
        )
        return int(camera.metadata["cam_idx"]) if fixed_pose else None

    def _posed_view(self, camera: Cameras, cam_idx: Optional[int]) -> View:
        """The view of a render that is not a viewer's: in training at the step's resolution and pose
        (the pose optimizer's, where there is one)."""
        pose = lambda: self.camera_optimizer.apply_to_camera(camera) if self.training else camera.camera_to_worlds
        return self.training_views.get(camera, pose, self._get_downscale_factor(), self.device, cam_idx)

    def _background(self, view: View, frame_embed: Tensor, cam_idx: Optional[int], slot: int = 0) -> Tensor:
        """The background [H, W, 1] of a render at `view` and the state `frame_embed` [Df]; `slot`: the
        camera's place among a training step's cameras."""
        return self.background_field(
            view.K[0],
            view.camera_to_world[0],
            frame_embed,
            view.width,
            view.height,
            cam_idx,
            view.pinhole,
            training=self.training,
            step=self.step,
            slot=slot,
        )

    def _emission(
        self, frame_embed: Tensor, camera_position: Tensor, ids: Optional[Tensor] = None, slot: int = 0
    ) -> Tensor:
        """Every (or the selected) Gaussian's emission [N, 1] at `frame_embed` [Df], seen from
        `camera_position` [3] where the view term renders (`view_emission.py`); `slot`: the camera's
        place among a training step's cameras."""
        colors = self.gaussian_emission(frame_embed, ids, slot)  # [N, 1]
        if self.renders_view_term():
            means, view_sh = self.means, self.gauss_params["view_sh"]
            if ids is not None:
                means, view_sh = means[ids], view_sh[ids]
            colors = colors + view_term(means, view_sh, camera_position)
        return colors

    def _rasterize(
        self, colors: Tensor, viewmats: Tensor, Ks: Tensor, width: int, height: int, ids: Optional[Tensor]
    ) -> Tuple[Tensor, Tensor]:
        """gsplat's render [C, H, W, D(+1)] and alpha [C, H, W, 1] of every (or the selected) Gaussian
        with `colors` [N, D] or [C, N, D] in the C cameras `viewmats` [C, 4, 4], `Ks` [C, 3, 3]; its
        `info` kept for the densification after the step."""
        crop = lambda x: x if ids is None else x[ids]
        scales, opacities = self.activated_splats(ids)  # [N, 3], [N]
        with_depth = self.config.output_depth_during_training or not self.training
        if not self.ranks.split:  # one GPU: gsplat's kernels with the least host work around them
            render, alpha, self.info = rasterize_unpacked(
                crop(self.means),
                crop(self.quats),  # normalised by the projection
                scales,
                opacities,
                colors,
                viewmats,
                Ks,
                width,
                height,
                with_depth,
                self.strategy.absgrad,
                self.config.rasterize_mode,
                self.config.rasterizer,
            )
            return render, alpha
        render, alpha, self.info = rasterization(
            means=crop(self.means),
            quats=crop(self.quats),  # rasterization normalises internally
            scales=scales,
            opacities=opacities,
            colors=colors,
            viewmats=viewmats,
            Ks=Ks,
            width=width,
            height=height,
            packed=True,  # across GPUs only the visible splats travel (gsplat: memory per visible splat)
            near_plane=NEAR_PLANE,
            far_plane=FAR_PLANE,
            render_mode="RGB+ED" if with_depth else "RGB",
            sh_degree=None,
            sparse_grad=False,
            absgrad=self.strategy.absgrad,
            rasterize_mode=self.config.rasterize_mode,
            distributed=True,
            backend=self.config.rasterizer,
        )
        return render, alpha

    def _count_for_densification(self) -> None:
        """The training render's screen-space gradients enter the densification statistics after
        backward (no statistics from no-grad renders)."""
        if self.training and torch.is_grad_enabled():
            self.strategy.step_pre_backward(
                self.gauss_params, self.optimizers, self.strategy_state, self.step, self.info
            )

    def _composited_outputs(
        self, render: Tensor, alpha: Tensor, background: Tensor, view: View, colors: Tensor, c: int
    ) -> Dict[str, Union[Tensor, List]]:
        """`_outputs` of camera `c` of a render (gsplat's render [C, H, W, D(+1)], alpha [C, H, W, 1]) over
        its `background` [H, W, 1]: in training as its camera records it, with the view term's radial
        part where it is penalised; `colors` [N, D], the Gaussians' radiance in that camera."""
        if self.training and self.camera_falloff is not None:  # compared with a recorded frame
            emission, alpha, depth = camera_planes(render, alpha, c)
            thermal = self.recorded_render(emission, alpha, background, view.K[0], view.pinhole, slot=c)
        else:
            thermal, alpha, depth = composite(render, alpha, background, c)
        outputs = self._outputs(thermal, alpha, background, depth)
        if self.training and self.config.view_radial_penalty > 0 and self.renders_view_term() and not self.ranks.split:
            visible = self.info["radii"][c].reshape(self.num_points, -1).amax(-1) > 0  # [N]
            camera_position = view.camera_to_world[0, :3, 3]  # [3]
            outputs["view_radial"] = radial_part(
                view_term(self.means[visible], self.gauss_params["view_sh"][visible], camera_position),  # [M, 1]
                colors[visible].detach(),  # [M, 1]
                self.info["means2d"][c][visible],  # [M, 2]
                view.width,
                view.height,
            )
        return outputs

    def recorded_render(
        self,
        emission: Tensor,
        alpha: Tensor,
        background: Tensor,
        K: Tensor,
        pinhole: Tuple[float, float, float, float],
        slot: int = 0,
    ) -> Tensor:
        """A training render of a camera of intrinsics `K` [3, 3] (`pinhole`: its fx, fy, cx, cy on the host) as
        the camera records it: gsplat's `emission` [H, W, 1] (premultiplied) and `alpha` [H, W, 1] over the
        `background` [H, W, 1], through the fitted fall-off and flat-field map (`recorded_over_background`), the
        two replayed as one CUDA graph on a GPU (`graphed_camera`); `slot`: the camera's place among a training
        step's cameras (`GraphedCalls`)."""
        height, width = emission.shape[:2]
        basis = self.camera_falloff_basis(K, pinhole, width, height, 1)  # [H, W, K], kept
        inputs = (emission, alpha, background, self.camera_falloff, basis)
        if self.camera_flat_field is not None:
            inputs += (self.camera_flat_field,)
        if self.graphed_camera is not None and torch.is_grad_enabled():
            # the key: what besides the inputs' shapes picks the function, whether there is a map
            return self.graphed_camera(len(inputs) == 6, recorded_over_background, *inputs, slot=slot)
        return recorded_over_background(*inputs)

    def as_recorded(self, thermal: Tensor, camera: Cameras) -> Tensor:
        """A render `thermal` [H, W, 1] of `camera` (outside training: the scene) as the camera records
        it, with its fitted fall-off and flat-field map (`camera_falloff.respond`); unchanged without them.
        For every image compared with a recorded frame (`pipeline.photometric_state.render`)."""
        if self.camera_falloff is None:
            return thermal
        _, _, pinhole = host_sizes(camera)  # the camera's full resolution, as the render
        height, width = thermal.shape[:2]
        basis = self.camera_falloff_basis(intrinsics(camera)[0].to(thermal.device), pinhole, width, height, 1)
        flat_field = None if self.camera_flat_field is None else self.camera_flat_field.detach()
        return respond(thermal, self.camera_falloff.detach(), basis, flat_field)

    def activated_splats(self, ids: Optional[Tensor] = None) -> Tuple[Tensor, Tensor]:
        """gsplat's scales [N, 3] and opacities [N] of every (or the selected) Gaussian (outside training
        baked, as the emission: `get_outputs`)."""
        scales, opacities = (self.scales, self.opacities) if ids is None else (self.scales[ids], self.opacities[ids])
        return torch.exp(scales), torch.sigmoid(opacities).squeeze(-1)

    def viewing_view_and_background(self, view: View, frame_embed: Tensor) -> Tuple[Tensor, Tensor]:
        """gsplat's view matrix [1, 4, 4] and the background [H, W, 1] of a render outside training
        (`get_outputs`): one CUDA graph per camera size and intrinsics on a GPU, the baked background
        map (`ThermalBackground.baked_map`) one of its inputs, so a new state needs no new graph."""
        field = self.background_field
        key = ("view", view.width, view.height, view.pinhole)
        if self.background_mlp is None:  # a constant background
            prepare = lambda camera_to_world, K: (
                world_to_camera(camera_to_world),
                field(K[0], camera_to_world[0], None, view.width, view.height, training=False, step=self.step),
            )
            return self.captured(key, prepare, view.camera_to_world, view.K)

        def prepare(camera_to_world: Tensor, baked: Tensor, frame_dirs: Tensor) -> Tuple[Tensor, Tensor]:
            background = field.from_map(baked, frame_dirs, camera_to_world[0], view.width, view.height)
            return world_to_camera(camera_to_world), background

        baked = field.baked_map(frame_embed, self.step)
        frame_dirs = field.frame_directions(view.K[0], view.width, view.height, view.pinhole)
        return self.captured(key, prepare, view.camera_to_world, baked, frame_dirs)

    def viewing_outputs(self, render: Tensor, alpha: Tensor, background: Tensor) -> Dict[str, Tensor]:
        """`_outputs` of a render outside training from gsplat's render [1, H, W, 2] (emission, depth)
        and alpha [1, H, W, 1]: composited and coloured in one CUDA graph on a GPU, copied out of it
        in one piece (the outputs are views of it)."""
        colormap = self.viewer_controls.colormap

        def finish(render: Tensor, alpha: Tensor, background: Tensor) -> Tuple[Tensor]:
            thermal, alpha, depth = composite(render, alpha, background)
            return (torch.cat([thermal_rgb(thermal, colormap), thermal, alpha, background, depth], -1),)  # [H, W, 7]

        key = ("finish", tuple(render.shape), colormap)
        packed = self.captured(key, finish, render, alpha, background, copy_outputs=True)[0]
        return self._outputs(packed[..., 3:4], packed[..., 4:5], packed[..., 5:6], packed[..., 6:7], packed[..., :3])

    def emission_in_view(
        self, frame_embed: Tensor, viewmat: Tensor, K: Tensor, width: int, height: int, camera_position: Tensor
    ) -> Tensor:
        """The emission [N, 1] of the Gaussians the camera (gsplat's `viewmat` [4, 4], `K` [3, 3]) can
        see (`in_view`), zero for the others (which it does not draw)."""
        seen = in_view(self.means, self.scales, viewmat, K, width, height).nonzero().squeeze(-1)  # [M]
        values = self.gaussian_emission(frame_embed, seen)  # [M, 1]
        if self.renders_view_term():
            values = values + view_term(self.means[seen], self.gauss_params["view_sh"][seen], camera_position)
        return values.new_zeros(self.num_points, 1).index_copy(0, seen, values)

    def emission_for_every_rank(self, frame_embed: Tensor, cam_idx: int, view) -> Tensor:
        """This rank's Gaussians' emission [N, W] as every rank's camera of this step sees them (gsplat's
        distributed rasterization takes per-Gaussian colours only; each rank keeps its own channel):
        channel s at rank s's frame embedding, for the Gaussians rank s's camera can see."""
        mine = torch.cat(
            [
                torch.tensor([float(cam_idx)], device=self.device),
                view.camera_to_world[0, :3, 3].to(self.device),
                view.viewmat[0].reshape(-1),
                view.K[0].reshape(-1),
            ]
        )  # [29]: the training image, camera position, world-to-camera, intrinsics
        views = self.ranks.gather_stack(mine)  # [W, 29]
        channels = []
        for s in range(self.ranks.world):
            embed = frame_embed if s == self.ranks.rank else self.frame_embed.weight[views[s, 0].long()]
            viewmat, K = views[s, 4:20].reshape(4, 4), views[s, 20:29].reshape(3, 3)
            channels.append(self.emission_in_view(embed, viewmat, K, view.width, view.height, views[s, 1:4]))
        return torch.cat(channels, dim=-1)

    @torch.no_grad()
    def get_outputs_for_camera(
        self, camera: Cameras, obb_box=None, frame_embedding: Optional[Tensor] = None
    ) -> Dict[str, Tensor]:
        """Splatfacto's, at the state of `frame_embedding` (`get_outputs`), without its copy of a
        camera already on the model's device (a new Cameras object per frame, whose construction
        costs more host time than the splatting)."""
        self.set_crop(obb_box)
        return self.get_outputs(camera if camera.device == self.device else camera.to(self.device), frame_embedding)

    def _outputs(
        self, thermal: Tensor, alpha: Tensor, background: Tensor, depth: Optional[Tensor], rgb: Optional[Tensor] = None
    ) -> Dict:
        # `rgb` where the caller coloured it already (`viewing_outputs`); nothing reads rgb while training:
        # the render itself as grey, unclipped (views alone, no kernel); else the colormap (viewer, ns-render)
        if rgb is None and self.training:
            rgb = thermal.detach().expand(-1, -1, 3)  # [H, W, 3]
        elif rgb is None:
            rgb = thermal_rgb(thermal, self.viewer_controls.colormap)  # [H, W, 3]
        return {  # rgb first: the viewer shows the first output by default
            "rgb": rgb,
            "thermal": thermal,  # [H, W, 1], normalised dataset units (training space)
            "accumulation": alpha,
            "background": background,
            "depth": depth,
        }

    # ----------------------------------------------------------------- losses
    def _training_image(self, batch: Dict) -> Optional[int]:
        """The batch's training image while training (its frame checks are kept), else None."""
        return int(batch["image_idx"]) if self.training and "image_idx" in batch else None

    def _ground_truth(self, outputs: Dict, batch: Dict) -> Tuple[Tensor, Optional[Tensor]]:
        """The frame at the render's resolution and its contrast (`ThermalLoss.ground_truth`). A training
        step asks twice (its metrics, its loss): the first answer is kept in the step's `outputs`, so
        the frame is resized and checked once per step (and a training frame resized once per size of the
        resolution warm-up: `ResizedFrames`)."""
        kept = outputs.get(GROUND_TRUTH_KEY)
        if kept is not None:
            return kept
        frame = checked_thermal_image(batch)
        image = self._training_image(batch)
        if image is None:
            gt = self.get_gt_img(frame)
        else:
            gt = self.resized_frames.get(image, frame, self._get_downscale_factor(), self.get_gt_img)
        answer = self.thermal_loss.ground_truth(gt, outputs["thermal"], image, batch.get("image_idx"))
        if image is not None:  # a training step's outputs (a render outside training is scored once)
            outputs[GROUND_TRUTH_KEY] = answer
        return answer

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
        """The losses of one camera's render against its frame (`image`: its training image, None
        outside training); `slot`: the camera's place among a training step's cameras (`GraphedCalls`)."""
        with profiled_section("thermal/loss"):
            gt, contrast = self._ground_truth(outputs, batch)
            losses = self.thermal_loss(outputs, gt, contrast, image, slot)
        if "view_radial" in outputs:  # the view term's radial part (`view_radial_penalty`)
            losses["view_radial"] = self.config.view_radial_penalty * outputs["view_radial"]
        return losses

    def _step_losses(self, losses: Dict[str, Tensor]) -> Dict[str, Tensor]:
        """`losses` with the terms of the step rather than of a camera added (once, however many
        cameras the step trains): the states' smoothness and the camera optimizer's regulariser."""
        if self.config.state_smoothness > 0:
            # the embeddings are one copy per GPU whose gradients are summed: each rank adds its share
            share = self.config.state_smoothness / self.ranks.world
            losses["state_smoothness"] = share * self.frame_states.neighbour_residual()
        self.camera_optimizer.get_loss_dict(losses)
        return losses

    def get_training_metrics_and_losses(
        self, outputs: Sequence[Dict], batches: Sequence[Dict], metrics: bool = True
    ) -> Tuple[Dict[str, Tensor], Dict[str, Tensor]]:
        """The metrics and losses of a step of several cameras (`get_training_outputs`): each camera's
        as a step of its own, averaged over the cameras (the densification statistics scale each
        camera's share back by the camera count, as gsplat's), and the step's own terms once. The
        step's loss has no one training image: the divergence guard reads it against the recent
        steps' alone. `metrics` off: no metrics (an empty dict), for the steps no one logs."""
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

    # ------------------------------------------------- the trainer's interface (training/model_interface.py)
    def last_training_losses(self) -> Tuple[Optional[Dict[str, Tensor]], Optional[int]]:
        """The last training step's losses and its training image (the divergence guard's)."""
        return self._last_training_losses

    def decisions(self) -> List[Decision]:
        """The model's size and parts for this run, and why (`training/decisions.py` reports them):
        the budget and every part are the config's; GPU memory, where it stopped growth, is the data's."""
        cfg = self.config
        share = f" (this GPU's share of {self.ranks.world})" if self.ranks.split else ""
        budget = self.strategy.max_gaussians  # this GPU's, as densification applies it now (raises: the stop's entry)
        choice = f"{self.num_points:,} now{share}, at most {budget:,}"
        entries = [Decision("Gaussians", choice, f"max_gaussians {cfg.max_gaussians:,}", "config")]
        if self.strategy.memory_stopped_at is not None:
            why = f"GPU memory: growth stopped at {self.strategy.memory_stopped_at:,}{share}"
            entries.append(Decision("Gaussians", "capped by GPU memory", why, "data"))
        parts = (
            ("emission MLP", cfg.use_emission_mlp, "use_emission_mlp"),
            ("background MLP", cfg.use_background_mlp, "use_background_mlp"),
            ("heat-aware SSIM", cfg.heat_aware_ssim, "heat_aware_ssim"),
            ("alpha regulariser", cfg.alpha_lambda > 0, f"alpha_lambda {cfg.alpha_lambda:g}"),
        )
        entries += [Decision(part, "on" if on else "off", option, "config") for part, on, option in parts]
        if cfg.few_view_prune_frames > 0:
            nearer = (
                f", nearer than {cfg.few_view_prune_nearer:g} x the median" if cfg.few_view_prune_nearer > 0 else ""
            )
            why = f"few_view_prune_frames {cfg.few_view_prune_frames}{nearer}"
            if cfg.few_view_prune_above_budget is not None:
                threshold = cfg.few_view_prune_above_budget
                why += f"; few_view_prune_above_budget {threshold:,}, the budget {self.budget_over_gpus:,}"
            if self.few_view_prune_runs():
                choice = f"on: {self.few_view_pruned:,} removed so far"
            else:
                choice = "off across GPUs" if self.ranks.split else "waits for a larger Gaussian budget"
                choice += f" ({self.few_view_pruned:,} removed so far)" if self.few_view_pruned else ""
            entries.append(Decision("few-view prune", choice, why, "config"))
        view = f"view_sh_degree {cfg.view_sh_degree}"
        if self._view_term_follows_budget():
            threshold = cfg.view_term_above_budget
            view += f"; view_term_above_budget {threshold:,}, the Gaussian budget {self.budget_over_gpus:,}"
        on = cfg.view_sh_degree > 0 and not self._view_term_waits
        entries.append(Decision("view-dependent emission", "on" if on else "off", view, "config"))
        falloff = "off" if self.camera_falloff is None else f"on: {describe_falloff(self.camera_falloff)}"
        entries.append(Decision("camera fall-off", falloff, self.falloff_why, "config"))
        flat_field = "off" if self.camera_flat_field is None else f"on: {describe_flat_field(self.camera_flat_field)}"
        entries.append(Decision("camera flat-field map", flat_field, self.flat_field_why, self.flat_field_decided_by))
        return entries

    def has_view_term(self) -> bool:
        """Whether the model was built with a view-dependent emission term (`view_sh_degree` > 0)."""
        return "view_sh" in self.gauss_params

    def use_view_term(self, on: bool) -> None:
        """Whether the view term takes part in renders from now on. Off: its coefficients are zeroed
        and get no gradient, so the model renders as one built without it."""
        if not self.has_view_term():
            raise ValueError("this model has no view term (view_sh_degree 0)")
        if not on:
            with torch.no_grad():
                self.gauss_params["view_sh"].zero_()
        self._view_term = "on" if on else "off"

    def try_view_term(self) -> None:
        """Put the view term on trial until `use_view_term` decides (the automatic stop's rule:
        `training/view_probe.py`): training renders alternate between with the term (odd steps) and
        without it (even steps), so the Gaussians learn to render both ways; every render outside
        training leaves it out."""
        if not self.has_view_term():
            raise ValueError("this model has no view term (view_sh_degree 0)")
        # the trial decides it from now on, not the budget (its verdict too: `use_view_term`)
        self._view_term, self._view_term_waits, self._view_term_by_trial = "trial", False, True

    def renders_view_term(self) -> bool:
        """Whether a render now adds the view term (`use_view_term`, `try_view_term`; in training not
        before `view_term_from_step`; in no render while the budget is below `view_term_above_budget`)."""
        if self._view_term_waits or (self.training and self.step < self.config.view_term_from_step):
            return False
        if self._view_term == "trial":
            return self.training and self.step % 2 == 1
        return self._view_term == "on"

    @property
    def budget_over_gpus(self) -> int:
        """The Gaussian budget densification applies now, over every GPU (each holds its share of it)."""
        return self.strategy.max_gaussians * self.ranks.world

    def gaussian_budget(self) -> Tuple[int, int]:
        """(Gaussians now, `max_gaussians` as densification applies it) on this GPU."""
        return self.num_points, self.strategy.max_gaussians

    def start_budget(self, count: int) -> None:
        """Densification grows to `count` Gaussians at most from now on, in place of `max_gaussians`."""
        self.strategy.max_gaussians = count
        self._follow_budget()

    def raise_budget(self, count: int) -> None:
        """Densification may grow to `count` Gaussians from now on, never past a count at which a step
        ran out of GPU memory (`limit_growth`)."""
        ceiling = self._growth_ceiling
        self.strategy.max_gaussians = max(
            self.strategy.max_gaussians, count if ceiling is None else min(count, ceiling)
        )
        self._follow_budget()

    def _view_term_follows_budget(self) -> bool:
        """Whether the Gaussian budget decides the view term (`view_term_above_budget`, no trial)."""
        return self.config.view_term_above_budget is not None and self.has_view_term() and not self._view_term_by_trial

    def _follow_budget(self) -> None:
        """The view term waits while the Gaussian budget (over every GPU) is at or below
        `view_term_above_budget`, and takes part once it passes it (said on the console during a run)."""
        threshold = self.config.view_term_above_budget
        if not self._view_term_follows_budget():
            return
        waits = self.budget_over_gpus <= threshold
        if self._view_term_waits and not waits and self.step > 0 and self.ranks.rank == 0:
            CONSOLE.log(
                f"step {self.step}: the Gaussian budget passed {threshold:,}: the view-dependent emission "
                "term takes part from now on (view_term_above_budget)"
            )
        self._view_term_waits = waits

    def densifies(self, step: int) -> bool:
        """Whether gsplat's strategy still grows the model after `step` (it refines until `stop_split_at`)."""
        return step < self.strategy.refine_stop_iter

    def limit_growth(self, count: int) -> None:
        """Densification never grows past `count` Gaussians from now on (`max_gaussians` lowered)."""
        self.strategy.max_gaussians = min(self.strategy.max_gaussians, count)
        self._growth_ceiling = count if self._growth_ceiling is None else min(self._growth_ceiling, count)

    def discard_step_statistics(self) -> None:
        """This step's gradients stay out of the densification statistics (a rolled-back step)."""
        self._discard_statistics = True

    def weigh_step_statistics(self, accepted: Tensor) -> None:
        """This step's gradients enter the densification statistics where `accepted` ([] bool on the
        device: the divergence guard's verdict, read there, not waited for) is True."""
        self._step_accepted = accepted

    def optimizer_states_of(self, states: dict) -> dict:
        """The MLPs' Adam states of a checkpoint from before each MLP was one parameter (`PackedMLP`), packed."""
        for name in ("emission_mlp", "background_mlp"):
            mlp = getattr(self, name)
            if mlp is None or name not in states:
                continue
            parameters = list(mlp.parameters())
            count = 2 * len(mlp.net.shapes)  # the separate layers' weights and biases
            if len(states[name]["param_groups"][0]["params"]) == len(parameters) + count - 1:
                start = next(i for i, p in enumerate(parameters) if p is mlp.net.packed)  # the tensors before stay
                states = {**states, name: packed_adam_state(states[name], start, count)}
        return states

    def load_state_dict(self, state_dict, strict: bool = True, **kwargs):  # type: ignore[override]
        """Refuse a checkpoint of another config, with the reason (`refuse_mismatched_checkpoint`)."""
        if self.camera_falloff is not None and "camera_falloff" not in state_dict and self._map_left_by_motion():
            # a run of the rule before the fall-off was split from the map (the motion rule then decided the
            # camera model as a whole, and fitted nothing where it leaves the map out): it renders as it trained
            self.camera_falloff, self.graphed_camera = None, None
            self.falloff_why = "the checkpoint's: trained when the content-motion rule decided the whole camera model"
            CONSOLE.log(f"camera fall-off off: {self.falloff_why}")
        if self.background_mlp is not None and any(k.startswith("background_mlp.") for k in state_dict):
            trained_coupling = "affine" if "background_mlp.frame_affine.weight" in state_dict else "mlp"
            if trained_coupling != self.config.background_frame_coupling:
                if self.training:  # a resume: the optimizers already hold this config's background parameters
                    raise ValueError(
                        f"checkpoint's background MLP couples the frame as {trained_coupling!r}, this config as "
                        f"{self.config.background_frame_coupling!r}: resume it with "
                        f"--pipeline.model.background-frame-coupling {trained_coupling}"
                    )
                # to render: a run from before 'affine' became the default, whose config.yml does not name the
                # coupling (the field did not exist), renders with the background it trained
                self.config.background_frame_coupling = trained_coupling
                self._build_background(trained_coupling)
                self.background_mlp.to(self.frame_embed.weight.device)
                CONSOLE.log(f"background frame coupling {trained_coupling!r}: the checkpoint's")
        has_parts = (self.emission_mlp is not None, self.background_mlp is not None, self.camera_falloff is not None)
        has_parts += (self.camera_flat_field is not None,)
        refuse_mismatched_checkpoint(state_dict, *has_parts, tuple(self.frame_embed.weight.shape))
        loaded = super().load_state_dict(state_dict, strict=strict, **kwargs)
        if self._view_term_waits and bool(self.gauss_params["view_sh"].any()):
            # a run whose budget passed `view_term_above_budget` trained the term: render it (a resumed run's
            # automatic stop sets the budget it had reached, and the rule again, right after this)
            self._view_term_waits = False
        return loaded

    # densification statistics, torch's RNG (gsplat's splits draw from it) and the few-view prune's count are saved:
    # a resume continues the run, and its decisions count what the whole run pruned
    def get_extra_state(self) -> dict:
        state = {k: v for k, v in self.strategy_state.items() if v is not None}
        return {
            "strategy_state": state,
            "torch_rng_state": torch.get_rng_state(),
            "few_view_pruned": self.few_view_pruned,
        }

    def set_extra_state(self, state: dict) -> None:
        if not state:
            return
        for key, value in state.get("strategy_state", {}).items():
            self.strategy_state[key] = value.to(self.device) if isinstance(value, Tensor) else value
        if "torch_rng_state" in state:
            torch.set_rng_state(state["torch_rng_state"])
        self.few_view_pruned = state.get("few_view_pruned", 0)  # 0: a checkpoint from before the prune was counted

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
            self.strategy.step_post_backward(
                params=self.gauss_params,
                optimizers=self.optimizers,
                state=self.strategy_state,
                step=step,
                info=info,
                packed=self.ranks.split,
            )
            if self.few_view_prune_runs() and self.strategy.refines_at(step):
                self._prune_few_view(step)

    def few_view_prune_runs(self) -> bool:
        """Whether the few-view prune takes part at densification rounds now (`few_view_prune_frames`, on one GPU,
        with a Gaussian budget above `few_view_prune_above_budget` where that is set)."""
        cfg = self.config
        if cfg.few_view_prune_frames <= 0 or self.ranks.split:
            return False
        threshold = cfg.few_view_prune_above_budget
        return threshold is None or self.budget_over_gpus > threshold

    def _prune_few_view(self, step: int) -> None:
        """Remove the few-view Gaussians (`few_view_mask`) of the training frames rendered so far, each frame at the
        scale it last rendered at (the test is in the view's own pixels)."""
        views = {cam: view for (cam, _), view in self.training_views.kept.items()}
        if len(views) <= self.config.few_view_prune_frames:
            return  # too few frames rendered yet to tell a few-view Gaussian from any other
        poses = torch.cat([v.camera_to_world for v in views.values()])  # [F, 3, 4]
        viewmats = torch.cat(
            [world_to_camera(v.camera_to_world) if v.viewmat is None else v.viewmat for v in views.values()]
        )
        Ks = torch.cat([v.K for v in views.values()])  # [F, 3, 3]
        sizes = [(v.width, v.height) for v in views.values()]
        mask = few_view_mask(
            self.means.detach(),
            self.scales.detach(),
            viewmats,
            Ks,
            sizes,
            poses[:, :, 3],
            self.config.few_view_prune_frames,
            self.config.few_view_prune_nearer,
        )
        self.few_view_pruned += self.strategy.prune_where(
            self.gauss_params, self.optimizers, self.strategy_state, mask, step
        )

    @property
    def settled_step(self) -> int:
        """The first step past the schedule's start-up (`schedule.settled_step`): the automatic stop
        does not score before it."""
        return settled_step(self.config, self.strategy)

    def schedule_moves_loss(self, step: int) -> bool:
        """Whether the schedule itself moves the loss at `step` (`schedule.schedule_moves_loss`): the
        divergence guard takes a new baseline there rather than skipping each frame's jump as a spike."""
        return schedule_moves_loss(self.config, self.strategy, step)

    def get_image_metrics_and_images(self, outputs, batch) -> Tuple[Dict[str, float], Dict[str, Tensor]]:
        return image_metrics_and_images(outputs["thermal"], self._ground_truth(outputs, batch)[0], self.num_points)


def cam_idx_of(camera: Cameras) -> int:
    """The training image index a training camera carries (`metadata['cam_idx']`)."""
    return int(camera.metadata["cam_idx"])  # type: ignore[index]
