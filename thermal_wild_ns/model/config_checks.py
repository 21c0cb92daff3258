"""What a thermal model's config refuses, with the reason, rather than doing nothing or something
else silently: options it inherits from splatfacto and nerfstudio but does not use (hidden from
`--help` by `tyro.conf.Suppress` in the config), and checkpoints of another config."""

from __future__ import annotations

from typing import Tuple

from thermal_wild_ns.errors import InputError

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


def refuse_unused_options(config) -> None:
    """An `InputError` naming any option of `UNUSED_OPTIONS` set away from its default (a config
    file edited by hand, or written for splatfacto): it would do nothing."""
    defaults = type(config)()
    changed = [name for name in UNUSED_OPTIONS if getattr(config, name) != getattr(defaults, name)]
    if changed:
        raise InputError(
            "wild-thermal does not use "
            + "; ".join(f"{name} (set to {getattr(config, name)!r}: {UNUSED_OPTIONS[name]})" for name in changed)
            + ". Remove it from the config"
        )


def refuse_options_without_their_part(config) -> None:
    """An `InputError` where an option weighs a part the config leaves out (it would do nothing)."""
    view_options = {
        "view_radial_penalty": (config.view_radial_penalty, "penalises the view term", "the penalty at 0"),
        "view_term_from_step": (config.view_term_from_step, "delays the view term", "it at 0"),
    }
    # `view_term_above_budget` is the full method's default: without a view term it simply has nothing to hold back
    if config.view_term_above_budget is not None and config.view_term_above_budget < 0:
        raise InputError(f"view_term_above_budget {config.view_term_above_budget}: must be 0 or more (None: no rule)")
    for name, (value, what, default) in view_options.items():
        if value < 0:
            raise InputError(f"{name} {value:g}: must be 0 or more")
        if value > 0 and config.view_sh_degree == 0:
            raise InputError(
                f"{name} {value:g} {what}, but view_sh_degree is 0 (no view term): "
                f"set --pipeline.model.view-sh-degree 1 or 2, or leave {default}"
            )


def refuse_options_across_gpus(config, split: bool) -> None:
    """An `InputError` where an option cannot work with the Gaussians split across GPUs (`split`), or with the
    background the config asks for."""
    if split and (config.use_absgrad or config.camera_optimizer.mode != "off"):
        raise InputError(
            "training across GPUs needs --pipeline.model.use-absgrad False (gsplat's distributed "
            "rasterization has no absgrad) and --pipeline.model.camera-optimizer.mode off"
        )
    if config.random_background and config.use_background_mlp:
        raise InputError("random_background needs use_background_mlp False: the background MLP models it")


def refuse_mismatched_checkpoint(
    state_dict: dict,
    emission_mlp: bool,
    background_mlp: bool,
    camera_falloff: bool,
    camera_flat_field: bool,
    frame_embed_shape: Tuple[int, int],
) -> None:
    """A ValueError where a checkpoint's `state_dict` does not fit a model with (or without) the
    emission and background MLPs, the camera's fall-off and flat-field map and frame embeddings of `frame_embed_shape`,
    before nerfstudio's loader falls back to a non-strict load that would silently drop a part."""
    parts = {
        "emission MLP (use_emission_mlp)": ("emission_mlp.", emission_mlp),
        "per-Gaussian embeddings (use_emission_mlp)": ("gauss_params.gauss_embed", emission_mlp),
        "background MLP (use_background_mlp)": ("background_mlp.", background_mlp),
        "camera fall-off (camera_falloff)": ("camera_falloff", camera_falloff),
        "camera flat-field map (camera_flat_field)": ("camera_flat_field", camera_flat_field),
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
    if frames is not None and tuple(frames.shape) != tuple(frame_embed_shape):
        raise ValueError(
            f"checkpoint has {frames.shape[0]} frame embeddings of size {frames.shape[1]}, this config "
            f"{frame_embed_shape[0]} of size {frame_embed_shape[1]}: it was trained on other data or settings"
        )
