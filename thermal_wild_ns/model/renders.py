"""A thermal render in each of its modes, chosen once per call (`render_mode`): a training step's (one GPU,
any number of cameras), a training step's across GPUs, a render a user waits for (viewer, ns-render: CUDA
graphs around gsplat), and any other render outside training (cropped, under autograd, across GPUs). Each reads
as its story: the camera's view, the background at the frame's state, the Gaussians' radiance, gsplat, the
compositing. The parts (`RenderParts`) are the model's, built once; what changes per call (`Scene`) is passed."""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Callable, Dict, List, NamedTuple, Optional, Sequence, Tuple

import torch
from nerfstudio.cameras.cameras import Cameras
from torch import Tensor

from thermal_wild_ns._upstream import profiled_section
from thermal_wild_ns.model.background import ThermalBackground
from thermal_wild_ns.model.bake import BakedValues
from thermal_wild_ns.model.camera_response import CameraResponse
from thermal_wild_ns.model.camera_views import TrainingViews, View, ViewingViews
from thermal_wild_ns.model.compositing import (
    background_only,
    coloured_outputs,
    composite,
    over_background,
    rendered_outputs,
    unpacked_outputs,
)
from thermal_wild_ns.model.emission import GaussianEmission
from thermal_wild_ns.model.view_emission import visible_radial_part
from thermal_wild_ns.pipeline.ranks import RankGroup
from thermal_wild_ns.rendering import activated, rasterize_gaussians, render_one_view, resolve_backend
from thermal_wild_ns.rendering.backend import FAR_PLANE, NEAR_PLANE
from thermal_wild_ns.rendering.captured import CapturedCalls
from thermal_wild_ns.rendering.splat_weights import splat_weights

TRAINING_COLLAPSED = (
    "All Gaussians have been pruned: training collapsed. Lower cull_alpha_thresh or check the data (constant or "
    "NaN frames)."
)


class RenderMode(enum.Enum):
    TRAINING = "a training step's render on one GPU"
    SPLIT_TRAINING = "a training step's render with the Gaussians split across GPUs"
    VIEWING = "a render a user waits for: outside training and autograd, every Gaussian, one GPU"
    CROPPED = "outside training and autograd otherwise: within a crop box, or with the Gaussians across GPUs"
    FITTING = "outside training under autograd: a fit through the render"


def render_mode(training: bool, grad: bool, cropped: bool, split: bool) -> RenderMode:
    if training:
        return RenderMode.SPLIT_TRAINING if split else RenderMode.TRAINING
    if grad:
        return RenderMode.FITTING
    return RenderMode.CROPPED if cropped or split else RenderMode.VIEWING


class Scene(NamedTuple):
    """What a render reads of the model that moves between calls."""

    params: Dict[str, Tensor]  # the Gaussians' parameters (`gauss_params`)
    falloff: Optional[Tensor]  # [2, K] the camera's fitted fall-off (None: no camera model)
    flat_field: Optional[Tensor]  # [2, n, n] its flat-field map (None: none)
    step: int
    view_term: bool  # whether the render adds the view term (the growth policy's answer)
    downscale: int  # the training resolution's (the schedule's warm-up)
    pose: Callable[[Cameras], Tensor]  # a training camera's pose [1, 3, 4] (the pose optimizer's)
    embeddings: Tensor  # [F, Df] the training frames' embeddings
    colormap: str  # the `rgb` output's outside training


@dataclass
class RenderParts:
    """The model's rendering parts, built once."""

    config: object  # the model's config
    ranks: RankGroup
    emission: GaussianEmission
    background: ThermalBackground
    camera: CameraResponse
    training_views: TrainingViews
    viewing_views: ViewingViews
    captured: CapturedCalls  # outside training: the view and background, and the finish, as CUDA graphs
    baked: BakedValues  # outside training: the activated scales and opacities

    @classmethod
    def of(cls, config, ranks: RankGroup, emission_mlp, background_mlp, falloff: bool) -> "RenderParts":
        """The parts of a model of `config` with these MLPs (None: none) and a camera fall-off or not."""
        return cls(
            config,
            ranks,
            GaussianEmission(emission_mlp, config.graphed_emission, config.nonnegative_emission),
            ThermalBackground(background_mlp, config),
            CameraResponse(graphed=config.graphed_camera and falloff),
            TrainingViews(),
            ViewingViews(),
            CapturedCalls(),
            BakedValues(),
        )


Rendered = Tuple[List[Dict], Optional[Dict]]
"""Each camera's outputs, and gsplat's `info` of a training render (None outside training)."""


# ---------------------------------------------------------------------------------------------- training
@dataclass
class TrainingRender:
    """A training step's render on one GPU: its cameras [B] of one size, each at its frame's embedding [Df], in
    one rasterization (the step's fixed costs paid once); gsplat's `info` for the densification statistics."""

    parts: RenderParts

    def render_cameras(self, scene: Scene, cameras: Sequence[Cameras], embeds: Sequence[Tensor], ids=None) -> Rendered:
        parts, params, cfg = self.parts, scene.params, self.parts.config
        views = [training_view(parts, scene, camera) for camera in cameras]
        backgrounds, colors = [], []
        for slot, (camera, view, embed) in enumerate(zip(cameras, views, embeds)):  # slots: graphs replay per slot
            K, camera_to_world, W, H = view.K[0], view.camera_to_world[0], view.width, view.height
            with profiled_section("thermal/background"):  # named sections for python -m experiments.profile_step
                cam_idx = fixed_pose_index(camera, parts.config)
                backgrounds.append(parts.background.training(K, camera_to_world, embed, W, H, cam_idx, slot))
            with profiled_section("thermal/emission"):
                position = camera_to_world[:3, 3]  # [3]
                if len(views) == 1 and params["means"].shape[0] > parts.config.emission_in_view_above:
                    viewmat = view.viewmat[0]  # a large scene: the Gaussians this camera sees
                    colors.append(
                        parts.emission.radiance_in_view(params, embed, viewmat, K, W, H, position, scene.view_term)
                    )
                else:
                    colors.append(parts.emission.training_radiance(params, embed, position, scene.view_term, slot))
        sizes = sorted({(view.width, view.height) for view in views})
        if len(sizes) > 1:
            raise ValueError(f"several cameras per render need frames of one size; this step's: {sizes}")
        if params["means"].shape[0] == 0:
            raise RuntimeError(TRAINING_COLLAPSED)
        viewmats, Ks = torch.cat([view.viewmat for view in views]), torch.cat([view.K for view in views])
        stacked = colors[0] if len(colors) == 1 else torch.stack(colors)  # [N, 1] or [B, N, 1]
        with profiled_section("thermal/rasterize"):
            args = (cfg.output_depth_during_training, cfg.use_absgrad, cfg.rasterize_mode, cfg.rasterizer, False)
            render, alpha, info = rasterize_gaussians(params, stacked, viewmats, Ks, *sizes[0], None, *args)
        falloff, flat_field = scene.falloff, scene.flat_field
        outputs = [
            parts.camera.outputs(falloff, flat_field, render, alpha, backgrounds[c], view.K[0], view.pinhole, c)
            for c, view in enumerate(views)
        ]  # each camera as it records
        if parts.config.view_radial_penalty > 0 and scene.view_term:
            means, coefficients = params["means"], params["view_sh"]
            for c, view in enumerate(views):
                position, size = view.camera_to_world[0, :3, 3], (view.width, view.height)
                outputs[c]["view_radial"] = visible_radial_part(means, coefficients, info, colors[c], position, size, c)
        return outputs, info


@dataclass
class SplitTrainingRender:
    """A training step's render with the Gaussians split across GPUs: every GPU renders its share in every GPU's
    camera (gsplat's distributed rasterization, all together), each camera at its frame's embedding, and keeps
    its own camera's channel."""

    parts: RenderParts

    def render_cameras(self, scene: Scene, cameras: Sequence[Cameras], embeds: Sequence[Tensor], ids=None) -> Rendered:
        parts, params, ranks, cfg = self.parts, scene.params, self.parts.ranks, self.parts.config
        (camera,), (embed,) = cameras, embeds
        view = training_view(parts, scene, camera)
        K, camera_to_world = view.K[0], view.camera_to_world[0]
        cam_idx = fixed_pose_index(camera, parts.config)
        background = parts.background.training(K, camera_to_world, embed, view.width, view.height, cam_idx)
        if params["means"].shape[0] == 0:
            raise RuntimeError(TRAINING_COLLAPSED)
        mine = torch.cat(
            [
                torch.tensor([float(camera.metadata["cam_idx"])], device=K.device),
                camera_to_world[:3, 3],
                view.viewmat[0].reshape(-1),
                K.reshape(-1),
            ]
        )  # [29]: the training image, camera position, world-to-camera, intrinsics
        views = ranks.gather_stack(mine)  # [W, 29]
        channel_embeds = torch.stack(
            [embed if s == ranks.rank else scene.embeddings[views[s, 0].long()] for s in range(ranks.world)]
        )  # [W, Df]
        W, H = view.width, view.height
        colors = parts.emission.radiance_per_rank(params, channel_embeds, views, W, H, scene.view_term)  # [N, W]
        args = (cfg.output_depth_during_training, cfg.use_absgrad, cfg.rasterize_mode, cfg.rasterizer, True)
        render, alpha, info = rasterize_gaussians(params, colors, view.viewmat, view.K, W, H, None, *args)
        render = torch.cat([render[..., ranks.rank : ranks.rank + 1], render[..., ranks.world :]], -1)  # [1, H, W, *]
        falloff, flat_field = scene.falloff, scene.flat_field
        return [parts.camera.outputs(falloff, flat_field, render, alpha, background, K, view.pinhole, 0)], info


def training_view(parts: RenderParts, scene: Scene, camera: Cameras) -> View:
    """`camera` as a training step renders it: at the step's resolution, posed by the pose optimizer (kept for a
    training camera whose pose is fixed)."""
    device = scene.params["means"].device
    fixed = fixed_pose_index(camera, parts.config)
    return parts.training_views.get(camera, lambda: scene.pose(camera), scene.downscale, device, fixed)


# ---------------------------------------------------------------------------------------------- outside training
@dataclass
class ViewingRender:
    """A render a user waits for (viewer, ns-render, exports) at the camera's full resolution: its fixed-shape
    pieces replayed as CUDA graphs (`rendering/captured.py`), gsplat's rasterization between them through its
    CUDA functions directly."""

    parts: RenderParts

    def render_cameras(self, scene: Scene, cameras: Sequence[Cameras], embeds: Sequence[Tensor], ids=None) -> Rendered:
        parts, params = self.parts, scene.params
        (camera,), (embed,) = cameras, embeds
        view = parts.viewing_views.get(camera, embed.device)
        viewmat, background = parts.background.viewing(view, embed, scene.step, parts.captured)  # [1, 4, 4], [H, W, 1]
        if params["means"].shape[0] == 0:
            return [background_only(background, scene.colormap)], None
        position = view.camera_to_world[0, :3, 3]  # [3]
        colors = parts.emission.rendered_radiance(params, embed, scene.step, position, scene.view_term)
        scales, opacities = parts.baked.get(
            "activated", (params["scales"], params["opacities"]), scene.step, lambda: activated(params)
        )
        render, alpha = render_one_view(
            params["means"],
            params["quats"],
            scales,
            opacities,
            colors,
            viewmat,
            view.K,
            view.width,
            view.height,
            parts.config.rasterize_mode,
            parts.config.rasterizer,
        )  # [1, H, W, 2], [1, H, W, 1]
        colormap = scene.colormap

        def finish(render: Tensor, alpha: Tensor, background: Tensor) -> Tuple[Tensor]:
            thermal, alpha, depth = composite(render, alpha, background)
            return (coloured_outputs(thermal, alpha, background, depth, colormap),)  # [H, W, 7]

        key = ("finish", tuple(render.shape), colormap)
        return [unpacked_outputs(parts.captured(key, finish, render, alpha, background, copy_outputs=True)[0])], None


@dataclass
class CroppedRender:
    """A render outside training and autograd that is not a viewer's: within a crop box (`ids` [N] bool), or with
    the Gaussians split across GPUs (every GPU renders the same camera at the same state), at the camera's full
    resolution, the emission and background baked."""

    parts: RenderParts

    def render_cameras(self, scene: Scene, cameras: Sequence[Cameras], embeds: Sequence[Tensor], ids=None) -> Rendered:
        parts, params = self.parts, scene.params
        (camera,), (embed,) = cameras, embeds
        view = full_view(parts, camera, embed.device)
        K, camera_to_world, W, H = view.K[0], view.camera_to_world[0], view.width, view.height
        background = parts.background.rendered(K, camera_to_world, embed, W, H, view.pinhole, scene.step)
        render = alpha = None  # nothing to render: no Gaussian, or none in the crop box
        if drawn(params, ids):
            position = camera_to_world[:3, 3]  # [3]
            colors = parts.emission.rendered_radiance(params, embed, scene.step, position, scene.view_term, ids)
            render, alpha = rasterized_with_depth(parts, params, colors, view, ids)
        return [rendered_outputs(render, alpha, background, scene.colormap)], None


@dataclass
class FittingRender:
    """A render outside training under autograd (a fit through the render, such as a state fitted to a frame): the
    emission MLP and the background MLP themselves, at the camera's full resolution."""

    parts: RenderParts

    def render_cameras(self, scene: Scene, cameras: Sequence[Cameras], embeds: Sequence[Tensor], ids=None) -> Rendered:
        parts, params = self.parts, scene.params
        (camera,), (embed,) = cameras, embeds
        view = full_view(parts, camera, embed.device)
        K, camera_to_world, W, H = view.K[0], view.camera_to_world[0], view.width, view.height
        background = parts.background.exact(K, camera_to_world, embed, W, H)
        render = alpha = None  # nothing to render: no Gaussian, or none in the crop box
        if drawn(params, ids):
            colors = parts.emission.exact_radiance(params, embed, camera_to_world[:3, 3], scene.view_term, ids)
            render, alpha = rasterized_with_depth(parts, params, colors, view, ids)
        return [rendered_outputs(render, alpha, background, scene.colormap)], None

    def fixed_views(self, scene: Scene, cameras: Sequence[Cameras], ids: Optional[Tensor] = None) -> FixedViews:
        """`render_cameras`' thermal images of `cameras` [B] (one size) as one function of their frame embeddings
        [B, Df] -> [B, H, W, 1], for fits that move the states alone (the geometry fixed). Whatever does not
        depend on the states is made once, and every call is one pass for all the views: the emission MLP once
        for every state (on a GPU, for the Gaussians each camera can see), the background MLP once over every
        view's directions (encoded once), the Gaussians on the pure-torch rasterizer through each camera's splat
        weights (`rendering.splat_weights`: computed once, each render after a sparse product: the same render and
        gradients), with gsplat's kernels in one rasterization of every camera; with the Gaussians split across
        GPUs, a camera at a time."""
        parts, params, cfg = self.parts, scene.params, self.parts.config
        device = params["means"].device
        if parts.ranks.split or not drawn(params, ids):
            return lambda embeds: torch.stack(
                [self.render_cameras(scene, [c], [e], ids)[0][0]["thermal"] for c, e in zip(cameras, embeds)]
            )
        views = [full_view(parts, camera, device) for camera in cameras]
        sizes = sorted({(view.width, view.height) for view in views})
        if len(sizes) > 1:
            raise ValueError(f"a fit of several views needs views of one size; these: {sizes}")
        W, H = sizes[0]
        viewmats, Ks = torch.cat([v.viewmat for v in views]), torch.cat([v.K for v in views])  # [B, 4, 4], [B, 3, 3]
        camera_to_worlds = torch.cat([v.camera_to_world for v in views])  # [B, 3, 4]
        positions = camera_to_worlds[:, :3, 3]  # [B, 3]
        backgrounds = parts.background.exact_views(Ks, camera_to_worlds, W, H)
        if resolve_backend(cfg.rasterizer, device) == "torch":
            crop = lambda x: x if ids is None else x[ids]
            scales, opacities = activated(params, ids)  # [N, 3], [N]
            means, quats = crop(params["means"]), crop(params["quats"])
            weights = [
                splat_weights(
                    means, quats, scales, opacities, v.viewmat, v.K, W, H, NEAR_PLANE, FAR_PLANE, cfg.rasterize_mode
                )
                for v in views
            ]
            alphas = torch.cat([w.alpha for w in weights])  # [B, H, W, 1]
            rasterized = lambda colors: (torch.cat([w.render(c)[..., :1] for w, c in zip(weights, colors)]), alphas)
            # on a CPU the emission one state at a time: a view's MLP activations stay in the cache (in one call for
            # all of them a fit's step was slower), where a GPU's step pays for each call's launches
            radiances = lambda embeds: torch.cat(
                [
                    parts.emission.exact_radiances(params, e[None], p[None], scene.view_term, ids)
                    for e, p in zip(embeds, positions)
                ]
            )  # [B, N, 1]
        else:
            radiances = parts.emission.seen_radiances(params, viewmats, Ks, W, H, positions, scene.view_term, ids)
            args = (False, cfg.use_absgrad, cfg.rasterize_mode, cfg.rasterizer, False)  # no depth
            rasterized = lambda colors: rasterize_gaussians(params, colors, viewmats, Ks, W, H, ids, *args)[:2]

        def render(embeds: Tensor) -> Tensor:
            emission, alphas = rasterized(radiances(embeds))  # [B, H, W, 1] premultiplied, [B, H, W, 1]
            return over_background(emission, alphas, backgrounds(embeds))  # [B, H, W, 1]

        return render


FixedViews = Callable[[Tensor], Tensor]
"""Several cameras' thermal renders [B, H, W, 1] as a function of their frame embeddings [B, Df]
(`FittingRender.fixed_views`)."""


def render_modes(parts: RenderParts) -> Dict[RenderMode, object]:
    """Each mode's render over the model's `parts` (`render_mode` picks one per call)."""
    return {
        RenderMode.TRAINING: TrainingRender(parts),
        RenderMode.SPLIT_TRAINING: SplitTrainingRender(parts),
        RenderMode.VIEWING: ViewingRender(parts),
        RenderMode.CROPPED: CroppedRender(parts),
        RenderMode.FITTING: FittingRender(parts),
    }


# ---------------------------------------------------------------------------------------------- shared
def full_view(parts: RenderParts, camera: Cameras, device) -> View:
    """The view of a camera outside training, at its full resolution."""
    return parts.training_views.get(camera, lambda: camera.camera_to_worlds, 1, device, None)


def drawn(params: Dict[str, Tensor], ids: Optional[Tensor]) -> bool:
    """Whether there is a Gaussian to draw: any at all, and any in the crop box (`ids` [N] bool) where there is one."""
    return params["means"].shape[0] > 0 and (ids is None or bool(ids.sum() > 0))


def rasterized_with_depth(parts: RenderParts, params: Dict[str, Tensor], colors: Tensor, view: View, ids):
    """The render [1, H, W, D + 1] (expected depth last) and alpha [1, H, W, 1] of one view, the model's settings."""
    cfg = parts.config
    args = (True, cfg.use_absgrad, cfg.rasterize_mode, cfg.rasterizer, parts.ranks.split)  # with depth
    render, alpha, _ = rasterize_gaussians(params, colors, view.viewmat, view.K, view.width, view.height, ids, *args)
    return render, alpha


def fixed_pose_index(camera: Cameras, config) -> Optional[int]:
    """The training image of a training camera whose pose is fixed (no pose optimizer), else None."""
    fixed = config.camera_optimizer.mode == "off" and camera.metadata and "cam_idx" in camera.metadata
    return int(camera.metadata["cam_idx"]) if fixed else None
