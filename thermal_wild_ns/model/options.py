"""The options of the thermal model (`WildThermalModelConfig` in `wild_thermal.py` adds its target): every
field's docstring is its `--help`. Flat, as splatfacto's, so that `--pipeline.model.NAME` and the runs' config.yml
files keep their names."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, Literal, Optional, Tuple

import tyro
from nerfstudio.models.splatfacto import SplatfactoModelConfig

from thermal_wild_ns.rendering import Backend


@dataclass
class ThermalModelOptions(SplatfactoModelConfig):
    """Thermal splatting: scalar emission, appearance embeddings, background MLP."""

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
    canonical_embedding: Literal["typical", "mean"] = "typical"
    """The frame embedding of the `canonical` state, which novel views, the viewer and the exports render with:
    'typical' (the state whose emission is closest on average to every training frame's: docs/design.md; chosen
    over 'mean' by both real captures, docs/results/canonical_dunr_h200 and canonical_flight2_h200) or 'mean' (the
    average of the training frames' embeddings). A training frame's own state is `frame:N`, any capture time's
    `time:T` (`wild-thermal-render --photometric-state`)."""
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


PART_EVIDENCE: Dict[str, str] = {
    "use_emission_mlp": "the full method leads its ablations without it (wild-thermal-3dgs and its preprocessed "
    "variants) in `time` and `aligned` on DUNR and flight2 (docs/results/table_today_h200)",
    "use_background_mlp": "neutral on DUNR and flight2, within the seeds' spread (docs/results/parts_dunr_h200, "
    "docs/results/parts_flight2_h200); the generated demo and drift scenes lose `time` and `aligned` without it "
    "(docs/results/background_mlp_cpu)",
    "heat_aware_ssim": "the paper's loss; neutral on DUNR and flight2, within the seeds' spread "
    "(docs/results/parts_dunr_h200, docs/results/parts_flight2_h200)",
    "alpha_lambda": "the paper's regulariser; neutral on DUNR and flight2, within the seeds' spread "
    "(docs/results/parts_dunr_h200, docs/results/parts_flight2_h200); on the generated demo a `novel` gain whose "
    "ranges overlap (docs/results/alpha_regulariser_cpu)",
}
"""What the default of each switchable part of the model rests on: the committed runs (folders under docs/results)
that a run's report cites when it says why the part is on or off."""
