"""nerfstudio's training internals: the trainer, its optimizers and event writer, splatfacto's strategy, the
datamanager (the package's docstring says how each patch is kept)."""

from __future__ import annotations

import contextlib
from typing import Callable, Dict, List, Tuple

import numpy as np
import torch
from gsplat.strategy import DefaultStrategy
from nerfstudio.data.datamanagers.full_images_datamanager import FullImageDatamanager, _undistort_image
from nerfstudio.engine.trainer import Trainer
from nerfstudio.utils import writer


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
