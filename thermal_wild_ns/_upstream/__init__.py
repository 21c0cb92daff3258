"""Every place this plugin reaches into nerfstudio, gsplat, torchmetrics or torch internals, in
one package, a module for each upstream part that changes together: `versions` (what every patch was
checked against, checked first), `torch_internals`, `gsplat_calls`, `training` (nerfstudio's trainer, strategy and
datamanager) and `commands` (nerfstudio's command scripts).

Each patch or adapter says what upstream does, why the plugin needs something else, and the
upstream version it was checked against (`CHECKED`, verified when this package is imported). Nothing
here changes upstream behaviour when it is imported: the subclasses are used by name, and
the callers apply each patch where a command or a method needs it. nerfstudio's command scripts
(`nerfstudio.scripts.*`) are imported inside the hooks of their commands, and the exporter through
`nerfstudio_exporter`: it imports open3d, which the light install leaves out, and neither is needed
to train. The CPU torchvision trap is handled apart, in `install/torchvision_shim.py`: it must act at
interpreter start, before anything imports torchvision (and so before this package could).
"""

from thermal_wild_ns._upstream.versions import (  # checked before any patch loads
    CHECKED,
    SKIP_VERSION_CHECK,
    check_versions,
)

# isort: split
from thermal_wild_ns._upstream.commands import (
    ViewerControlOnConnect,
    camera_unit_slice,
    explain_config_load_error,
    fast_camera_path_slices,
    gaussian_splat_export_hooks,
    interpolation_over_one_pose,
    nerfstudio_exporter,
    no_lpips_download,
    prepare_checkpoint_commands,
    provide_ffmpeg,
    trajectory_render_hooks,
)
from thermal_wild_ns._upstream.gsplat_calls import (
    GSPLAT_CHANNELS,
    gsplat_render_one_view,
    gsplat_training_rasterization,
)
from thermal_wild_ns._upstream.torch_internals import (
    allow_nerfstudio_checkpoints,
    end_failed_capture,
    fused_adam_ready,
    fused_adam_step,
    profiled_section,
)
from thermal_wild_ns._upstream.training import (
    DefaultStrategyWithHooks,
    SingleChannelFullImageDatamanager,
    TrainerAfterLoad,
    guard_optimizer_steps,
    host_event_values,
    lighter_event_writes,
    replace_gaussians,
    repoint_optimizers,
    trainer_checkpoint_state,
    training_state_kept,
    undistorted_as_cached,
)

__all__ = [
    "CHECKED",
    "SKIP_VERSION_CHECK",
    "check_versions",
    "allow_nerfstudio_checkpoints",
    "profiled_section",
    "end_failed_capture",
    "fused_adam_ready",
    "fused_adam_step",
    "gsplat_render_one_view",
    "GSPLAT_CHANNELS",
    "gsplat_training_rasterization",
    "guard_optimizer_steps",
    "lighter_event_writes",
    "host_event_values",
    "replace_gaussians",
    "repoint_optimizers",
    "DefaultStrategyWithHooks",
    "SingleChannelFullImageDatamanager",
    "undistorted_as_cached",
    "trainer_checkpoint_state",
    "training_state_kept",
    "TrainerAfterLoad",
    "provide_ffmpeg",
    "prepare_checkpoint_commands",
    "no_lpips_download",
    "ViewerControlOnConnect",
    "explain_config_load_error",
    "nerfstudio_exporter",
    "gaussian_splat_export_hooks",
    "interpolation_over_one_pose",
    "trajectory_render_hooks",
    "camera_unit_slice",
    "fast_camera_path_slices",
]
