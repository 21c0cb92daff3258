"""Every place this plugin reaches into nerfstudio, gsplat, torchmetrics or torch internals, in
one module.

Each patch or adapter below says what upstream does, why the plugin needs something else, and the
upstream version it was checked against (`CHECKED`, verified when this module is imported). Nothing
here changes upstream behaviour when this module is imported: the subclasses are used by name, and
the callers apply each patch where a command or a method needs it. nerfstudio's command scripts
(`nerfstudio.scripts.*`) are imported inside the hooks of their commands, and the exporter through
`nerfstudio_exporter`: it imports open3d, which the light install leaves out, and neither is needed
to train. The CPU torchvision trap is handled apart, in `install/torchvision_shim.py`: it must act at
interpreter start, before anything imports torchvision (and so before this module could).
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import importlib
import os
import shutil
import sys
import types
from importlib import metadata
from pathlib import Path
from typing import Callable, Dict, List, Optional, Tuple

import numpy as np
import torch
import torchmetrics.image.lpip as lpip
from gsplat.cuda._wrapper import _FullyFusedProjection, _make_lazy_cuda_func, _make_lazy_cuda_obj, _RasterizeToPixels
from gsplat.strategy import DefaultStrategy
from nerfstudio.cameras.cameras import Cameras
from nerfstudio.data.datamanagers.full_images_datamanager import FullImageDatamanager, _undistort_image
from nerfstudio.engine.trainer import Trainer
from nerfstudio.utils import writer
from nerfstudio.utils.tensor_dataclass import TensorDataclass
from nerfstudio.viewer.viewer_elements import ViewerControl
from torch.profiler import record_function

from thermal_wild_ns.errors import EXPLAINERS, raised_reading_yaml

CHECKED = {"nerfstudio": "1.1.5", "gsplat": "1.4.0"}
"""The versions every patch here was written and tested against (pyproject.toml pins them)."""
SKIP_VERSION_CHECK = "THERMAL_WILD_NS_SKIP_VERSION_CHECK"
"""Set to 1 to try another nerfstudio/gsplat version at your own risk."""


def check_versions() -> None:
    """Fail with a clear message where nerfstudio or gsplat is not the version the patches below
    were checked against: they reach into internals that change between versions."""
    if os.environ.get(SKIP_VERSION_CHECK) == "1":
        return
    wrong = []
    for package, wanted in CHECKED.items():
        try:
            found = metadata.version(package)
        except metadata.PackageNotFoundError:
            found = "not installed"
        if found != wanted:
            wrong.append(f"{package} {found} (needs {wanted})")
    if wrong:
        raise ImportError(
            f"thermal_wild_ns needs {', '.join(f'{p}=={v}' for p, v in CHECKED.items())}; found {', '.join(wrong)}. "
            f"Install the pinned versions (pip install .), or set {SKIP_VERSION_CHECK}=1 to try anyway."
        )


check_versions()


# --------------------------------------------------------------------------- torch
def allow_nerfstudio_checkpoints() -> None:
    """torch >= 2.6: `torch.load` defaults to `weights_only=True`, and nerfstudio 1.1.5's loaders
    (ns-eval, ns-render, ns-viewer, ns-train --load-dir) call it without the argument on
    checkpoints that hold numpy scalars, so loading fails ("Unsupported global: numpy ... scalar").
    Instead of turning the safe loader off, allow-list exactly the numpy types such checkpoints
    contain. Checked on torch 2.11 and 2.13; idempotent. Applied when a pipeline of this plugin
    is built (every command that loads a checkpoint builds one first) and by the experiments."""

    add = getattr(torch.serialization, "add_safe_globals", None)
    if add is None:  # torch < 2.4 loads everything anyway
        return
    from numpy.core.multiarray import _reconstruct, scalar  # private numpy names, wanted only here

    dtypes = [type(np.dtype(t)) for t in ("float32", "float64", "int32", "int64", "uint8", "bool")]
    add([scalar, _reconstruct, np.dtype, np.ndarray, *dtypes])


def profiled_section(name: str):
    """torch's `record_function(name)` while a torch profiler records (the named `thermal/...` sections
    that `experiments.profile_step` and nerfstudio's `--logging.profiler pytorch` report), else a context
    that does nothing: a range dispatches two profiler operations on entering and leaving even with no
    profiler on, host time at every section of every training step. Whether one records is torch's
    private `torch._C._autograd._profiler_enabled` (checked against torch 2.11 and 2.13)."""
    if torch._C._autograd._profiler_enabled():
        return record_function(name)
    return contextlib.nullcontext()


def end_failed_capture() -> None:
    """Let CUDA's random generators draw again after a CUDA graph capture failed. torch's
    `CUDAGraph.capture_begin` puts the generators it records (the default one always) in capture mode,
    and only a `capture_end` that succeeds takes them out of it: after a failed capture every later
    random draw outside a capture raises "Offset increment outside graph capture encountered
    unexpectedly" (densification's split, in training). A capture that succeeds, of one small kernel
    on a side stream, takes them out. Checked against torch 2.11 (`CUDAGeneratorState::capturing_`,
    `CUDAGraph::capture_end`)."""
    side = torch.cuda.Stream()
    side.wait_stream(torch.cuda.current_stream())
    with torch.cuda.stream(side):
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph, stream=side, capture_error_mode="thread_local"):
            torch.zeros(1, device=side.device)
    torch.cuda.current_stream().wait_stream(side)


def fused_adam_ready(optimizer) -> bool:
    """Whether `fused_adam_step` can step this optimizer: a torch Adam built with fused=True and
    none of the options that function leaves out (amsgrad, maximize, capturable, differentiable)."""

    return type(optimizer) is torch.optim.Adam and all(
        group["fused"] and not (group["amsgrad"] or group["maximize"] or group["capturable"] or group["differentiable"])
        for group in optimizer.param_groups
    )


def fused_adam_step(optimizers, accepted: Optional[torch.Tensor] = None) -> None:
    """`step()` of every optimizer in `optimizers` (each `fused_adam_ready`), in one go: what torch's
    `Adam.step` does with fused=True (state created at the first step as `Adam._init_group` creates
    it, the step counts raised, then `torch._fused_adam_` per param group with the arguments
    `torch.optim.adam._fused_adam` gives it), without the Python around it: the profiler range,
    hooks, graph-capture checks and torch.compile guards of each `step()` call, one per optimizer
    and training step. The step counts of every parameter go up in one foreach kernel, and groups
    with the same settings (learning rate, betas, weight decay, eps) share one fused call.
    Checked against torch 2.11 (the GPU machines) and 2.13 (CPU): tests/test_upstream.py compares
    the parameters and optimizer states with `Optimizer.step`'s, bit for bit, and
    tests/test_resume.py a training run with nerfstudio's. `accepted` ([] bool on the device, the
    divergence guard's verdict): where False, nothing moves, step counts included (torch's
    `found_inf`, as a grad scaler's skipped step), decided on the device without a host sync."""

    work = []
    for optimizer in optimizers:
        for group in optimizer.param_groups:
            params = [p for p in group["params"] if p.grad is not None]
            if not params:
                continue
            states = []
            for p in params:
                state = optimizer.state[p]
                if len(state) == 0:
                    state["step"] = torch.zeros((), dtype=torch.float32, device=p.device)
                    state["exp_avg"] = torch.zeros_like(p, memory_format=torch.preserve_format)
                    state["exp_avg_sq"] = torch.zeros_like(p, memory_format=torch.preserve_format)
                states.append(state)
            work.append((group, params, states))
    if not work:
        return
    steps = [state["step"] for _, _, states in work for state in states]
    found_inf = None
    if accepted is None:
        torch._foreach_add_(steps, 1)
    else:  # the list form: the 0-dim tensor form waited for the GPU at every step (a host sync, torch 2.11)
        moved = accepted.float()  # [] 1 or 0
        torch._foreach_add_(steps, [moved] * len(steps))
        found_inf = 1.0 - moved  # [] 1 where the step is skipped
    # one fused call for the groups that share every setting (the kernel updates each tensor on its own, so
    # which call a tensor is in changes none of its numbers); a learning rate held as a tensor stays apart
    calls: Dict[tuple, Tuple[dict, list, list]] = {}
    for group, params, states in work:
        lr = group["lr"]
        key = (
            group.get("decoupled_weight_decay", False),
            lr if isinstance(lr, float) else id(group),
            *group["betas"],
            group["weight_decay"],
            group["eps"],
        )
        _, together, their_states = calls.setdefault(key, (group, [], []))
        together += params
        their_states += states
    for group, params, states in calls.values():
        beta1, beta2 = group["betas"]
        kernel = torch._fused_adamw_ if group.get("decoupled_weight_decay", False) else torch._fused_adam_
        kernel(
            params,
            [p.grad for p in params],
            [state["exp_avg"] for state in states],
            [state["exp_avg_sq"] for state in states],
            [],
            [state["step"] for state in states],
            amsgrad=False,
            lr=group["lr"],
            beta1=beta1,
            beta2=beta2,
            weight_decay=group["weight_decay"],
            eps=group["eps"],
            maximize=False,
            grad_scale=None,
            found_inf=found_inf,
        )


# --------------------------------------------------------------------------- gsplat
def gsplat_render_one_view(
    means: torch.Tensor,  # [N, 3]
    quats: torch.Tensor,  # [N, 4]
    scales: torch.Tensor,  # [N, 3]
    opacities: torch.Tensor,  # [N]
    colors: torch.Tensor,  # [N, 1]
    viewmat: torch.Tensor,  # [1, 4, 4]
    K: torch.Tensor,  # [1, 3, 3]
    width: int,
    height: int,
    near_plane: float,
    far_plane: float,
    antialiased: bool,
) -> Tuple[torch.Tensor, torch.Tensor]:
    """gsplat 1.4.0's `rasterization(means, quats, scales, opacities, colors, viewmat, K, width, height,
    near_plane, far_plane, packed=False, render_mode="RGB+ED", sh_degree=None, rasterize_mode=
    "antialiased" if antialiased else "classic")` of one camera, outside autograd: the four CUDA functions
    it calls, in its order, on the same inputs, without its argument checks, its metadata, its autograd
    wrappers and its copy of the opacities per camera. A render a user waits for (the viewer, ns-render)
    spends most of its time on the host; these are the same kernels. Returns its render [1, H, W, 2]
    (emission, expected depth) and alpha [1, H, W, 1]. Checked against gsplat 1.4.0 (`_wrapper.py`'s
    `fully_fused_projection`, `isect_tiles`, `isect_offset_encode`, `rasterize_to_pixels`, `rendering.py`'s
    `rasterization`); `tests/test_gpu_parity.py` compares the two on the GPU."""
    tile_size = 16
    radii, means2d, depths, conics, compensations = _make_lazy_cuda_func("fully_fused_projection_fwd")(
        means.contiguous(),
        None,  # covariances: from quats and scales
        quats.contiguous(),
        scales.contiguous(),
        viewmat.contiguous(),
        K.contiguous(),
        width,
        height,
        0.3,  # eps2d, gsplat's default
        near_plane,
        far_plane,
        0.0,  # radius clip, gsplat's default
        antialiased,  # compensations
        _make_lazy_cuda_obj("CameraModelType.PINHOLE"),
    )  # [1, N], [1, N, 2], [1, N], [1, N, 3], [1, N]
    opacities = opacities[None] * compensations if antialiased else opacities[None]  # [1, N]
    colors = torch.cat((colors[None], depths[..., None]), dim=-1)  # [1, N, 2]
    tile_width, tile_height = -(-width // tile_size), -(-height // tile_size)
    _, isect_ids, flatten_ids = _make_lazy_cuda_func("isect_tiles")(
        means2d, radii, depths, None, None, 1, tile_size, tile_width, tile_height, True, True
    )  # sorted, with radix sort's double buffer, as gsplat's `isect_tiles`
    offsets = _make_lazy_cuda_func("isect_offset_encode")(isect_ids, 1, tile_width, tile_height)  # [1, th, tw]
    render, alpha, _ = _make_lazy_cuda_func("rasterize_to_pixels_fwd")(
        means2d, conics, colors, opacities.contiguous(), None, None, width, height, tile_size, offsets, flatten_ids
    )  # [1, H, W, 2], [1, H, W, 1]
    return torch.cat((render[..., :-1], render[..., -1:] / alpha.clamp(min=1e-10)), dim=-1), alpha


GSPLAT_CHANNELS = frozenset((1, 2, 3, 4, 5, 8, 9, 16, 17, 32, 33, 64, 65, 128, 129, 256, 257, 512, 513))
"""The channel counts gsplat 1.4.0's rasterization kernels are built for (`rasterize_to_pixels` pads others)."""


def gsplat_training_rasterization(
    means: torch.Tensor,  # [N, 3]
    quats: torch.Tensor,  # [N, 4]
    scales: torch.Tensor,  # [N, 3]
    opacities: torch.Tensor,  # [N]
    colors: torch.Tensor,  # [N, D] or [C, N, D]
    viewmats: torch.Tensor,  # [C, 4, 4]
    Ks: torch.Tensor,  # [C, 3, 3]
    width: int,
    height: int,
    near_plane: float,
    far_plane: float,
    antialiased: bool,
    absgrad: bool,
    with_depth: bool,
) -> Tuple[torch.Tensor, torch.Tensor, Dict]:
    """gsplat 1.4.0's `rasterization(means, quats, scales, opacities, colors, viewmats, Ks, width, height,
    near_plane, far_plane, packed=False, sparse_grad=False, sh_degree=None, absgrad=absgrad, render_mode=
    "RGB+ED" if with_depth else "RGB", rasterize_mode="antialiased" if antialiased else "classic")` with
    autograd, for a training step on one GPU: its autograd functions and CUDA calls in its order, on the
    same inputs, without its argument checks, its wrappers' checks and copies of tensors already
    contiguous, and (one camera) its copy of the opacities, whose gradient is then the same values without
    the sum over one camera. The same kernels, so the same render, alpha, gradients and `meta` (the keys the
    densification reads); a training step spends most of its time on the host. Checked against gsplat
    1.4.0 (`rendering.py`'s `rasterization`, `_wrapper.py`'s `fully_fused_projection`, `isect_tiles`,
    `isect_offset_encode`, `rasterize_to_pixels`); `tests/test_gpu_parity.py` compares the two, gradients
    included. Returns the render [C, H, W, D(+1)], alpha [C, H, W, 1] and gsplat's `meta`."""
    C = viewmats.shape[0]
    channels = colors.shape[-1] + (1 if with_depth else 0)
    if channels not in GSPLAT_CHANNELS:
        raise ValueError(f"gsplat's kernels take {sorted(GSPLAT_CHANNELS)} channels, not {channels}")
    tile_size = 16
    radii, means2d, depths, conics, compensations = _FullyFusedProjection.apply(
        means.contiguous(),
        None,  # covariances: from quats and scales
        quats.contiguous(),
        scales.contiguous(),
        viewmats.contiguous(),
        Ks.contiguous(),
        width,
        height,
        0.3,  # eps2d, gsplat's default
        near_plane,
        far_plane,
        0.0,  # radius clip, gsplat's default
        antialiased,  # compensations
        "pinhole",
    )  # [C, N], [C, N, 2], [C, N], [C, N, 3], [C, N] or None
    opacities = opacities[None] if C == 1 else opacities.repeat(C, 1)  # [C, N]
    if compensations is not None:
        opacities = opacities * compensations
    if colors.dim() == 2:
        colors = colors.expand(C, -1, -1)  # [C, N, D]
    if with_depth:
        colors = torch.cat((colors, depths[..., None]), dim=-1)  # [C, N, D + 1]
    tile_width, tile_height = -(-width // tile_size), -(-height // tile_size)
    tiles_per_gauss, isect_ids, flatten_ids = _make_lazy_cuda_func("isect_tiles")(
        means2d, radii, depths, None, None, C, tile_size, tile_width, tile_height, True, True
    )  # sorted, with radix sort's double buffer, as gsplat's `isect_tiles`
    offsets = _make_lazy_cuda_func("isect_offset_encode")(isect_ids, C, tile_width, tile_height)  # [C, th, tw]
    render, alpha = _RasterizeToPixels.apply(
        means2d,
        conics,
        colors.contiguous(),
        opacities.contiguous(),
        None,  # backgrounds
        None,  # masks
        width,
        height,
        tile_size,
        offsets,
        flatten_ids,
        absgrad,
    )  # [C, H, W, channels], [C, H, W, 1]
    if with_depth:
        render = torch.cat((render[..., :-1], render[..., -1:] / alpha.clamp(min=1e-10)), dim=-1)
    meta = {
        "camera_ids": None,
        "gaussian_ids": None,
        "radii": radii,
        "means2d": means2d,
        "depths": depths,
        "conics": conics,
        "opacities": opacities,
        "tile_width": tile_width,
        "tile_height": tile_height,
        "tiles_per_gauss": tiles_per_gauss,
        "isect_ids": isect_ids,
        "flatten_ids": flatten_ids,
        "isect_offsets": offsets,
        "width": width,
        "height": height,
        "tile_size": tile_size,
        "n_cameras": C,
    }
    return render, alpha, meta


# --------------------------------------------------------------------------- command-line tools
def provide_ffmpeg() -> None:
    """nerfstudio 1.1.5's ns-render refuses to start without an `ffmpeg` on PATH and writes every
    output through it. Where the system has none, put the static ffmpeg of the imageio-ffmpeg
    wheel on this process's PATH (a link named `ffmpeg` in ~/.cache/thermal_wild_ns/bin, made
    atomically so concurrent processes never see half of it). Applied with the checkpoint
    allow-list, when a pipeline of this plugin is built."""
    if shutil.which("ffmpeg") is not None:
        return
    try:
        import imageio_ffmpeg  # optional: where it is missing, nerfstudio says ffmpeg is

        executable = Path(imageio_ffmpeg.get_ffmpeg_exe())
        folder = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "thermal_wild_ns" / "bin"
        folder.mkdir(parents=True, exist_ok=True)
        link = folder / "ffmpeg"
        if not link.exists() or link.resolve() != executable.resolve():
            tmp = folder / f".ffmpeg-{os.getpid()}"
            tmp.unlink(missing_ok=True)
            tmp.symlink_to(executable)
            tmp.replace(link)
    except (ImportError, OSError, RuntimeError):
        return  # no bundled ffmpeg or no writable cache: nerfstudio says what is missing
    os.environ["PATH"] = f"{folder}{os.pathsep}{os.environ.get('PATH', '')}"


def prepare_checkpoint_commands() -> None:
    """What nerfstudio's loading commands need from this plugin (see the two functions called)."""
    allow_nerfstudio_checkpoints()
    provide_ffmpeg()


@contextlib.contextmanager
def no_lpips_download():
    """Stock splatfacto (nerfstudio 1.1.5) builds torchmetrics' LPIPS in `populate_modules`, and its
    constructor downloads AlexNet weights: offline, the model cannot be built. While this context
    is open, the class is a stub that returns NaN (the experiments never read LPIPS). Checked with
    torchmetrics 1.4-1.9."""

    class NoLPIPS(torch.nn.Module):
        def __init__(self, *args, **kwargs):
            super().__init__()

        def forward(self, *args, **kwargs):
            return torch.tensor(float("nan"))

    original = lpip.LearnedPerceptualImagePatchSimilarity
    lpip.LearnedPerceptualImagePatchSimilarity = NoLPIPS
    try:
        yield
    finally:
        lpip.LearnedPerceptualImagePatchSimilarity = original


# --------------------------------------------------------------------------- nerfstudio adapters
def guard_optimizer_steps(optimizers, before_step: Callable[[list], bool]) -> None:
    """nerfstudio 1.1.5's `Trainer.train_iteration` steps every optimizer through
    `Optimizers.optimizer_scaler_step_some(grad_scaler, param_groups)` right after backward, with
    no hook in between. Wrap it on this instance: `before_step(param_groups)` runs first and the
    step happens only if it returns True (the divergence guard)."""
    step_some = optimizers.optimizer_scaler_step_some

    def guarded(grad_scaler, param_groups):
        if before_step(param_groups):
            step_some(grad_scaler, param_groups)

    optimizers.optimizer_scaler_step_some = guarded


def lighter_event_writes() -> None:
    """Two host costs of nerfstudio 1.1.5's event writes inside training steps, from now on in this process:

    - `Trainer.train` puts three running timings (the iteration's time, the ETA, rays per second) as
      scalar events at every step, and `writer.write_out_storage` hands each one to every event writer
      (tensorboard: an `add_scalar` each). They are written at the steps the losses are written
      (`--logging.steps-per-log`, which `writer.GLOBAL_BUFFER` holds), where the terminal's table prints
      them anyway; their running averages still take in every step, and every other event is written
      as before.
    - The losses and metrics it puts at those steps are the step's device tensors, and each writer
      reads each one back on its own (`Writer.write_scalar_dict`'s `float(scalar)`, tensorboard's
      `make_np`): a host sync per value and writer, and a warning per run for reading a tensor that
      requires grad. Every tensor of the events is read back first in one transfer per device and
      dtype (`host_event_values`), so the writers get Python floats of the same values.

    Installed once (each trainer's setup calls this)."""
    if getattr(writer.write_out_storage, "lighter_event_writes", False):
        return
    original = writer.write_out_storage
    per_step = {name.value for name in (writer.EventName.ITER_TRAIN_TIME, writer.EventName.ETA)}
    per_step.add(writer.EventName.TRAIN_RAYS_PER_SEC.value)

    def write_out_storage() -> None:
        every = writer.GLOBAL_BUFFER.get("steps_per_log")
        events = writer.EVENT_STORAGE
        if every:
            events[:] = [e for e in events if e["name"] not in per_step or e["step"] % every == 0]
        host_event_values(events)
        original()

    write_out_storage.lighter_event_writes = True  # type: ignore[attr-defined]
    writer.write_out_storage = write_out_storage


def host_event_values(events: List[dict]) -> None:
    """Replace every one-element tensor of nerfstudio's scalar and dictionary `events` (its
    `writer.EVENT_STORAGE` entries) by its value as a Python float, `float(tensor)`'s, read back in one
    transfer per device and dtype (the step's losses: one). A dictionary event gets a new dictionary:
    the trainer's own loss dict is left as it was."""
    one_value = lambda value: isinstance(value, torch.Tensor) and value.numel() == 1
    found: List[Tuple[dict, str]] = []  # (a dict, the key of a tensor there): the event's own or its new dictionary's
    for event in events:
        if event["write_type"] == writer.EventType.SCALAR and one_value(event["event"]):
            found.append((event, "event"))
        elif event["write_type"] == writer.EventType.DICT and any(map(one_value, event["event"].values())):
            event["event"] = values = dict(event["event"])
            found += [(values, key) for key, value in values.items() if one_value(value)]
    groups: Dict[Tuple[torch.device, torch.dtype], List[Tuple[dict, str]]] = {}
    for holder, key in found:
        groups.setdefault((holder[key].device, holder[key].dtype), []).append((holder, key))
    for places in groups.values():
        read = torch.stack([holder[key].detach().reshape(()) for holder, key in places]).tolist()
        for (holder, key), value in zip(places, read):
            holder[key] = float(value)


def replace_gaussians(pipeline, optimizers, values: Dict[str, torch.Tensor]) -> None:
    """Give the model `values` [N', ...] as its Gaussian parameters (the same keys as its `gauss_params`),
    with fresh Adam moments and densification statistics for them, every optimizer pointed at them
    (nerfstudio 1.1.5's optimizers hold the parameter tensors; splatfacto keeps its statistics in
    `strategy_state`, sized by the Gaussian count)."""
    model = pipeline.model
    for name, value in values.items():
        model.gauss_params[name] = torch.nn.Parameter(value)
        optimizers.optimizers[name].state.clear()
    repoint_optimizers(optimizers, pipeline.get_param_groups())
    for key, value in list(model.strategy_state.items()):
        if isinstance(value, torch.Tensor):
            model.strategy_state[key] = None


def repoint_optimizers(optimizers, param_groups: Dict[str, list]) -> None:
    """Point every optimizer at the model's current parameters, moving their state along.

    nerfstudio 1.1.5's splatfacto `load_state_dict` replaces each Gaussian parameter with a new
    tensor of the checkpoint's size, after the Trainer built its optimizers on the old ones: a
    resumed run would step orphaned tensors. nerfstudio keeps one param group per optimizer."""
    for name, optimizer in optimizers.optimizers.items():
        if name not in param_groups:
            continue
        params = optimizer.param_groups[0]["params"]
        for i, (old, new) in enumerate(zip(list(params), param_groups[name])):
            if old is not new:
                if old in optimizer.state:
                    optimizer.state[new] = optimizer.state.pop(old)
                params[i] = new
        optimizers.parameters[name] = param_groups[name]


class ViewerControlOnConnect(ViewerControl):
    """nerfstudio 1.1.5's `ViewerControl` is handed the viewer through its private `_setup` when
    the viewer starts; it has no public hook for a browser connecting. This subclass calls
    `on_connect(client)` for every browser that connects (to open the view through a camera)."""

    def __init__(self, on_connect):
        self.on_connect = on_connect

    def _setup(self, viewer) -> None:
        super()._setup(viewer)
        viewer.viser_server.on_client_connect(self.on_connect)

    def started_viewer(self):
        """The viewer this control was handed (`_setup`), or None before a viewer started."""
        return getattr(self, "viewer", None)


class DefaultStrategyWithHooks(DefaultStrategy):
    """gsplat 1.4.0's `DefaultStrategy` grows, prunes and accounts Gaussians in its private `_grow_gs`,
    `_prune_gs` and `_update_state`, with no public hook. This subclass calls `before_growth(params,
    state, step)` before gsplat grows (to leave candidates out), `prune_allowed(params, step)` before it
    prunes (False: no pruning this round) and `update_statistics(params, state, info, packed)` in place
    of `_update_state` (return False to let gsplat's own run), and keeps the allocator's cache across
    refinements (`step_post_backward`)."""

    def before_growth(self, params, state, step) -> None:
        pass

    def prune_allowed(self, params, step) -> bool:
        return True

    def _prune_gs(self, params, optimizers, state, step):
        if not self.prune_allowed(params, step):
            return 0
        return super()._prune_gs(params, optimizers, state, step)

    def update_statistics(self, params, state, info, packed: bool) -> bool:
        return False

    def _grow_gs(self, params, optimizers, state, step):
        self.before_growth(params, state, step)
        return super()._grow_gs(params, optimizers, state, step)

    def step_post_backward(self, params, optimizers, state, step, info, packed: bool = False):
        """gsplat's, without the `torch.cuda.empty_cache()` it calls after every refinement (every
        `refine_every` steps, most of a run): that hands every cached block back to the driver (a
        device-wide wait in each free) and the next step allocates them again. torch's allocator frees
        its cache by itself before a request would run out of memory, so the call saves no run."""
        empty_cache = torch.cuda.empty_cache
        torch.cuda.empty_cache = lambda: None  # gsplat's default.py looks it up at the call
        try:
            super().step_post_backward(params, optimizers, state, step, info, packed=packed)
        finally:
            torch.cuda.empty_cache = empty_cache

    def _update_state(self, params, state, info, packed: bool = False):
        if self.update_statistics(params, state, info, packed):
            return
        if "accepted" in info and not bool(info["accepted"]):  # gsplat's own sums: a host sync (packed renders)
            return
        super()._update_state(params, state, info, packed=packed)


class SingleChannelFullImageDatamanager(FullImageDatamanager):
    """nerfstudio 1.1.5's `FullImageDatamanager._load_images` (private) caches undistorted images;
    OpenCV's undistortion returns a 1-channel image as [H, W]. This subclass restores [H, W, 1].
    Its host cache (`cache_images='cpu'`, which it also forces above 500 training images) pins the
    images for copies to a GPU, which a torch without CUDA refuses: there the images stay where
    the model trains (its 'gpu' branch, which moves them to the datamanager's device)."""

    def _load_images(self, split, cache_images_device):
        if cache_images_device == "cpu" and not torch.cuda.is_available():
            cache_images_device = "gpu"  # to `self.device`: the CPU, unpinned
        images = super()._load_images(split, cache_images_device)
        for cache in images:
            if cache["image"].ndim == 2:
                cache["image"] = cache["image"][..., None]
        return images


def undistorted_as_cached(camera, image):
    """nerfstudio 1.1.5's `FullImageDatamanager` undistorts each image as it caches it, through its
    private `_undistort_image`, and gives its cameras the undistorted intrinsics. A frame the plugin
    reads from disk later (the raw frame behind a preprocessed or ground-truth image) must go the same
    way to line up with the cameras the model renders: this is that step, for one camera (shape [])
    and its frame [H, W] (float32), returned [H, W] (the frame itself where there is no distortion)."""

    if camera.distortion_params is None or torch.all(camera.distortion_params == 0):
        return image
    K = camera.get_intrinsics_matrices().numpy()
    _, undistorted, _ = _undistort_image(camera, camera.distortion_params.numpy(), {}, image[..., None], K)
    return np.asarray(undistorted).reshape(undistorted.shape[0], undistorted.shape[1])


def explain_config_load_error(error: BaseException, traceback) -> Optional[str]:
    """nerfstudio 1.1.5's `eval_setup` (ns-eval, ns-render, ns-viewer, ns-export) reads a run's config
    with `yaml.load(config_path.read_text())`: a damaged file fails there with a YAML error about
    "<unicode string>", (cut short at a line end) with the plugin's `IncompleteConfig`, or (cut
    inside a tag) with whatever the object it then names raises (`errors.raised_reading_yaml`), none
    naming the file. Where `error` rose inside `eval_setup`, the one-line explanation naming its
    `config_path` (a local of that function); None for any other error. One of `errors.EXPLAINERS`."""
    if not raised_reading_yaml(error, traceback):
        return None
    while traceback is not None:
        frame = traceback.tb_frame
        if frame.f_code.co_name == "eval_setup" and "config_path" in frame.f_locals:
            problem = " ".join(str(error).split())
            return (
                f"{frame.f_locals['config_path']}: the run's config is damaged or cut short ({problem}); "
                "restore it from a copy, or train the run again"
            )
        traceback = traceback.tb_next
    return None


def trainer_checkpoint_state(trainer, step: int) -> dict:
    """What nerfstudio 1.1.5's `Trainer.save_checkpoint` puts into a checkpoint (and its loaders
    read back): the plugin writes the same dictionary, but atomically (`pipeline/run_check.py`)."""
    pipeline = trainer.pipeline.module if hasattr(trainer.pipeline, "module") else trainer.pipeline
    return {
        "step": step,
        "pipeline": pipeline.state_dict(),
        "optimizers": {k: v.state_dict() for (k, v) in trainer.optimizers.optimizers.items()},
        "schedulers": {k: v.state_dict() for (k, v) in trainer.optimizers.schedulers.items()},
        "scalers": trainer.grad_scaler.state_dict(),
    }


@contextlib.contextmanager
def training_state_kept(model):
    """nerfstudio 1.1.5's splatfacto (and this plugin's model, which follows it) keeps its last
    render's `info` and `last_size` on the model for the densification after the training step
    (`step_post_backward`). A render in between (the automatic stop scoring its held-back frames)
    would replace them; while this context is open such renders may, and they are put back after."""
    kept = {name: getattr(model, name) for name in ("info", "last_size") if hasattr(model, name)}
    try:
        yield
    finally:
        for name, value in kept.items():
            setattr(model, name, value)


class TrainerAfterLoad(Trainer):
    """nerfstudio 1.1.5's `Trainer._load_checkpoint` (private) is the only place a resumed run's
    state arrives, and `Trainer._after_train` (private) saves the final checkpoint with no hook
    before it. This subclass hands the checkpoint's optimizer states to `optimizer_states_loaded(states)`
    before they load (`Optimizers.load_optimizers`, which `_load_checkpoint` calls), calls
    `after_checkpoint_load()` right after the load and `before_final_checkpoint()` right before the final
    checkpoint."""

    def optimizer_states_loaded(self, states: dict) -> dict:
        """The checkpoint's optimizer states (optimizer name -> its state dict) as they should load."""
        return states

    def after_checkpoint_load(self) -> None:
        pass

    def before_final_checkpoint(self) -> None:
        pass

    def _load_checkpoint(self) -> None:
        load = self.optimizers.load_optimizers
        self.optimizers.load_optimizers = lambda states: load(self.optimizer_states_loaded(states))
        try:
            super()._load_checkpoint()
        finally:
            del self.optimizers.load_optimizers  # the method again
        self.after_checkpoint_load()

    def _after_train(self) -> None:
        self.before_final_checkpoint()
        super()._after_train()


class _MissingOpen3d(types.ModuleType):
    """Stands in for open3d in nerfstudio's exporter module only: says what is missing when a point-cloud or mesh
    export reaches for it."""

    def __getattr__(self, name: str):
        if name.startswith("__"):  # what `inspect` and `hasattr` probe on every module
            raise AttributeError(name)
        raise ImportError(
            f"open3d.{name}: open3d is not installed (the light install leaves it out); nerfstudio's point-cloud and "
            "mesh exports need it: pip install open3d"
        )


def nerfstudio_exporter() -> types.ModuleType:
    """nerfstudio 1.1.5's `nerfstudio.scripts.exporter`, importable without open3d.

    The module imports open3d at its top for its point-cloud and mesh exports; the Gaussian-splat export (the only
    one this plugin extends) never uses it, and the light install has none. Where open3d does not import, that one
    import gets a stand-in that raises on use, and open3d stays absent for everyone else."""
    name = "nerfstudio.scripts.exporter"
    if name in sys.modules:
        return sys.modules[name]
    try:
        importlib.import_module("open3d")
    except (ImportError, OSError):  # OSError: open3d present but its system library (libusb) missing
        before = sys.modules.get("open3d", _MissingOpen3d)
        sys.modules["open3d"] = _MissingOpen3d("open3d")
        try:
            return importlib.import_module(name)
        finally:
            if before is _MissingOpen3d:
                del sys.modules["open3d"]
            else:
                sys.modules["open3d"] = before
    return importlib.import_module(name)


@contextlib.contextmanager
def gaussian_splat_export_hooks(
    on_pipeline: Callable, extra_properties: Callable[[dict], None], header_comments: Callable[[], list]
):
    """nerfstudio 1.1.5's `ExportGaussianSplat.main` loads the pipeline through the module-level
    `eval_setup` and writes the PLY through the static `write_ply(filename, count, map_to_tensors)`,
    neither of which can be extended. While this context is open: `on_pipeline(pipeline)` sees the
    loaded pipeline; `extra_properties(map_to_tensors)` may add vertex properties before writing;
    `header_comments()` lines are inserted after nerfstudio's "comment Vertical Axis: z" header
    line. The PLY is written under a temporary name and renamed into place."""
    ns_export = nerfstudio_exporter()

    original_setup, original_write = ns_export.eval_setup, ns_export.ExportGaussianSplat.write_ply

    def eval_setup(*args, **kwargs):
        result = original_setup(*args, **kwargs)
        on_pipeline(result[1])
        return result

    def write_ply(filename, count, map_to_tensors):
        extra_properties(map_to_tensors)
        partial = Path(filename).with_suffix(".partial.ply")
        original_write(str(partial), count, map_to_tensors)
        data = partial.read_bytes()
        anchor = b"comment Vertical Axis: z\n"
        if anchor not in data:
            raise RuntimeError(f"{partial}: nerfstudio's PLY header changed (no '{anchor.decode().strip()}' line)")
        comments = "".join(f"comment {line}\n" for line in header_comments()).encode()
        partial.write_bytes(data.replace(anchor, anchor + comments, 1))
        partial.replace(filename)  # never a half-written PLY under the final name

    with contextlib.ExitStack() as stack:
        ns_export.eval_setup = eval_setup
        stack.callback(setattr, ns_export, "eval_setup", original_setup)
        ns_export.ExportGaussianSplat.write_ply = staticmethod(write_ply)
        stack.callback(setattr, ns_export.ExportGaussianSplat, "write_ply", staticmethod(original_write))
        yield


@contextlib.contextmanager
def interpolation_over_one_pose():
    """nerfstudio 1.1.5's `ns-render interpolate` crashes inside numpy ("need at least one array to
    stack") where its pose source holds one camera (a small capture's one held-out view): there is
    no pair to interpolate between. While this context is open, such a path is that one pose, so
    the command renders it."""
    from nerfstudio.scripts import render as ns_render  # a command script: see the module docstring

    original = ns_render.get_interpolated_camera_path

    def interpolated(cameras, steps, order_poses):
        if len(cameras) > 1:
            return original(cameras, steps, order_poses)
        Ks = cameras.get_intrinsics_matrices()  # [1, 3, 3]
        return Cameras(
            fx=Ks[:, 0, 0],
            fy=Ks[:, 1, 1],
            cx=Ks[0, 0, 2],
            cy=Ks[0, 1, 2],
            camera_type=cameras.camera_type[0],
            camera_to_worlds=cameras.camera_to_worlds,
        )

    ns_render.get_interpolated_camera_path = interpolated
    try:
        yield
    finally:
        ns_render.get_interpolated_camera_path = original


@contextlib.contextmanager
def trajectory_render_hooks(per_trajectory: Callable):
    """nerfstudio 1.1.5's ns-render commands render a camera path in the module-level
    `_render_trajectory_video(pipeline, ...)`, calling `pipeline.model.get_outputs_for_camera` per
    frame, with no hook. While this context is open, each such call runs inside the context
    manager `per_trajectory(pipeline)`, which yields `(frame_embedding, on_outputs)`: every frame is
    rendered with `frame_embedding=` that embedding (where not None), and `on_outputs`, if not None,
    is called with every frame's outputs (the same renders as the video, not a second pass)."""
    from nerfstudio.scripts import render as ns_render  # a command script: see the module docstring

    original = ns_render._render_trajectory_video

    def trajectory(pipeline, *args, **kwargs):
        model = pipeline.model
        with per_trajectory(pipeline) as (frame_embedding, on_outputs):
            if frame_embedding is None and on_outputs is None:
                return original(pipeline, *args, **kwargs)
            render = model.get_outputs_for_camera
            at_state = {} if frame_embedding is None else {"frame_embedding": frame_embedding}

            def recording(*render_args, **render_kwargs):
                outputs = render(*render_args, **render_kwargs, **at_state)
                if on_outputs is not None:
                    on_outputs(outputs)
                return outputs

            model.get_outputs_for_camera = recording
            try:
                return original(pipeline, *args, **kwargs)
            finally:
                del model.get_outputs_for_camera  # back to the class's method

    ns_render._render_trajectory_video = trajectory
    try:
        yield
    finally:
        ns_render._render_trajectory_video = original


def camera_unit_slice(cameras: Cameras, i: int) -> Cameras:
    """`cameras[i : i + 1]` of a 1-D batch without nerfstudio 1.1.5's `TensorDataclass.__getitem__`, which builds
    the slice through `Cameras.__init__` (its field conversions, checks and broadcasts: host time in every frame of
    a camera path) to the same tensors: each tensor field is the view `field[i : i + 1]` (the same storage, offset
    and values), metadata without tensors deep-copied as there. Other batches and metadata holding tensors take
    nerfstudio's way (`tests/test_upstream.py` compares the two field by field)."""
    metadata = cameras.metadata
    sliced_inside = (torch.Tensor, dict, TensorDataclass)  # metadata values nerfstudio slices, not copies
    simple = metadata is None or not any(isinstance(v, sliced_inside) for v in metadata.values())
    if len(cameras.shape) != 1 or not 0 <= i < cameras.shape[0] or not simple:
        return TensorDataclass.__getitem__(cameras, slice(i, i + 1))
    sliced = copy.copy(cameras)
    for field in dataclasses.fields(cameras):
        value = getattr(cameras, field.name)
        if isinstance(value, torch.Tensor):
            object.__setattr__(sliced, field.name, value[i : i + 1])
    object.__setattr__(sliced, "metadata", copy.deepcopy(metadata))
    object.__setattr__(sliced, "_shape", torch.Size([1]))
    return sliced


@contextlib.contextmanager
def fast_camera_path_slices():
    """nerfstudio 1.1.5's ns-render loop (`_render_trajectory_video`) hands the model `cameras[i : i + 1]` of the
    path's batch for every frame. While this context is open, that unit slice of a `Cameras` batch is
    `camera_unit_slice`'s: the same camera, without the dataclass rebuilt per frame."""

    def getitem(self, indices):
        if isinstance(indices, slice) and indices.step is None and isinstance(indices.start, int):
            if indices.stop == indices.start + 1:
                return camera_unit_slice(self, indices.start)
        return TensorDataclass.__getitem__(self, indices)

    previous = Cameras.__dict__.get("__getitem__")  # none: Cameras inherits TensorDataclass's
    Cameras.__getitem__ = getitem
    try:
        yield
    finally:
        if previous is None:
            del Cameras.__getitem__
        else:
            Cameras.__getitem__ = previous


EXPLAINERS.append(explain_config_load_error)  # a damaged run config, as nerfstudio's loader meets it
