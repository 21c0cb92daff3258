"""torch's internals: its checkpoint loader's allow-list, the profiler's named sections, a failed CUDA graph
capture, fused Adam (the package's docstring says how each patch is kept)."""

from __future__ import annotations

import contextlib
from typing import Dict, Optional, Tuple

import numpy as np
import torch
from torch.profiler import record_function


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
