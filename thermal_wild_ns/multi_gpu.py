"""Train one scene across the GPUs of one host, launched by PyTorch's standard launcher:

    torchrun --nproc-per-node 2 -m thermal_wild_ns.multi_gpu wild-thermal [ns-train's options]

Every option is ns-train's. torchrun starts one process per GPU; each holds every N-th Gaussian and
trains one image per step, through gsplat's distributed rasterization (`training/distributed.py`).
What changes from a one-GPU run (the first four printed at start):
- each step trains N images (one per GPU): the same steps see N times the images;
- every Adam is set for N images per step as gsplat's multi-GPU trainer sets it (learning rate x
  sqrt(N), eps / sqrt(N), betas 1 - N(1 - beta)) from the settings given, which are one image's;
  without it two GPUs ended with fewer Gaussians and lower `novel` scores than one
  (docs/results/multi_gpu);
- no evaluation images or viewer during training;
- densification statistics without absgrad (gsplat's distributed rasterization has none): the
  growth threshold is scaled to the plain gradient (splatfacto's absgrad default 0.0008 -> 0.0002);
- the divergence guard and the automatic stop decide once for all GPUs (a step one GPU must skip,
  every GPU skips); a step that runs out of GPU memory stops the run rather than rolling back.
The run folder holds one config.yml and checkpoints that load on one GPU (ns-viewer, ns-render,
ns-eval, wild-thermal-export). On a CPU (tests) the processes use the gloo backend and the pure-torch
rasterizer's distributed mode.
"""

from __future__ import annotations

import copy
import dataclasses
import os

import torch
import torch.distributed as dist
import tyro
from nerfstudio.configs.method_configs import AnnotatedBaseConfigUnion
from nerfstudio.engine.trainer import TrainerConfig
from nerfstudio.utils.rich_utils import CONSOLE

from thermal_wild_ns.model.wild_thermal import WildThermalModelConfig
from thermal_wild_ns.pipeline.datamanager import ThermalDatamanagerConfig
from thermal_wild_ns.pipeline.ranks import RankGroup
from thermal_wild_ns.training.distributed import DistributedTrainerConfig
from thermal_wild_ns.training.optimizers import FusedAdamOptimizerConfig
from thermal_wild_ns.training.trainer import GuardedTrainerConfig, seeded_trainer

PLAIN_GRADIENT_SCALE = 0.25
"""Growth threshold on the plain 2D gradient over the one on absgrad (3DGS's 0.0002 over splatfacto's 0.0008)."""


def multi_gpu_config(config: TrainerConfig, gpus: int) -> DistributedTrainerConfig:
    """`config` (a thermal method's, as ns-train parsed it) set up for training across `gpus` GPUs;
    says what it changed. Refuses methods it cannot split (not this plugin's thermal model)."""
    model, datamanager = config.pipeline.model, config.pipeline.datamanager
    if not (
        isinstance(config, GuardedTrainerConfig)
        and isinstance(model, WildThermalModelConfig)
        and isinstance(datamanager, ThermalDatamanagerConfig)
    ):
        raise SystemExit(f"{config.method_name}: only this plugin's thermal methods train across GPUs")
    split = _copied_as(DistributedTrainerConfig, config)
    changes = ["one image per GPU per step", "no evaluation during training"]
    for name, group in split.optimizers.items():
        if not isinstance(group["optimizer"], FusedAdamOptimizerConfig):
            raise SystemExit(
                f"{config.method_name}: optimizer {name!r} is not the plugin's Adam;"
                f" cannot set it for {gpus} images per step"
            )
        group["optimizer"] = group["optimizer"].for_images(gpus)
    changes.append(
        f"every Adam set for {gpus} images per step (lr x sqrt {gpus}, eps / sqrt {gpus}, betas 1 - {gpus}(1 - beta))"
        if gpus > 1
        else "Adam as given (one image per step)"
    )
    model, datamanager = split.pipeline.model, split.pipeline.datamanager
    model.distributed = datamanager.distributed = True
    if model.use_absgrad:
        model.use_absgrad = False
        model.densify_grad_thresh *= PLAIN_GRADIENT_SCALE
        changes.append(f"growth on the plain gradient, densify_grad_thresh {model.densify_grad_thresh:g}")
    split.steps_per_eval_image = split.steps_per_eval_batch = split.steps_per_eval_all_images = 0
    split.vis = "tensorboard"
    split.viewer.quit_on_train_completion = True
    CONSOLE.log("Training across GPUs: " + "; ".join(changes))
    return split


def one_gpu_config(config: DistributedTrainerConfig) -> GuardedTrainerConfig:
    """The config a one-GPU command loads the run with (its config.yml): the same model and data,
    not split (its densification and Adam settings kept: what trained, and a resumed run goes on as this
    one did)."""
    single = _copied_as(GuardedTrainerConfig, config)
    single.pipeline.model.distributed = single.pipeline.datamanager.distributed = False
    return single


def _copied_as(kind, config: GuardedTrainerConfig):
    """A deep copy of `config`'s settings as a `kind` (its trainer: `_target` is the class's own)."""
    names = [f.name for f in dataclasses.fields(GuardedTrainerConfig) if f.name != "_target"]
    return kind(**{name: copy.deepcopy(getattr(config, name)) for name in names})


def join_process_group(device_type: str) -> RankGroup:
    """This process's rank in torchrun's process group (NCCL between GPUs, gloo on CPUs)."""
    if "RANK" not in os.environ:
        raise SystemExit("launch with torchrun: torchrun --nproc-per-node N -m thermal_wild_ns.multi_gpu METHOD ...")
    if device_type == "cuda":
        # before CUDA starts: a split model's densification and renders allocate blocks of changing
        # size, which the default allocator's fixed segments leave reserved but unusable (out of memory
        # with much of the GPU free: docs/results/multi_gpu); a user's own setting wins
        os.environ.setdefault("PYTORCH_CUDA_ALLOC_CONF", "expandable_segments:True")
        local, gpus = int(os.environ["LOCAL_RANK"]), torch.cuda.device_count()
        if local >= gpus:
            raise SystemExit(f"--nproc-per-node asks for more processes than this host has GPUs ({gpus})")
        torch.cuda.set_device(local)
    dist.init_process_group("nccl" if device_type == "cuda" else "gloo")
    return RankGroup.current()


def main(config: TrainerConfig) -> None:
    ranks = join_process_group(config.machine.device_type)
    try:
        split = multi_gpu_config(config, ranks.world)
        split.set_timestamp()
        stamp = [split.timestamp]
        dist.broadcast_object_list(stamp, src=0)  # one run folder for every rank
        split.timestamp = stamp[0]
        if ranks.rank == 0:
            single = one_gpu_config(split)
            single.timestamp = split.timestamp
            single.save_config()
        dist.barrier()
        split.logging.local_writer.enable = ranks.rank == 0  # one progress table, not one per GPU
        # rank 0 sets up alone first: it generates, preprocesses and caches what the others then read
        if ranks.rank != 0:
            dist.barrier()
        trainer = seeded_trainer(split, local_rank=int(os.environ.get("LOCAL_RANK", 0)))
        if ranks.rank == 0:
            dist.barrier()
        trainer.train()
    finally:
        dist.destroy_process_group()


def entrypoint() -> None:
    main(tyro.cli(AnnotatedBaseConfigUnion, description=__doc__))


if __name__ == "__main__":
    entrypoint()
