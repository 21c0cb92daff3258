"""`python -m experiments.render_fps`: how fast a trained model renders, baked vs unbaked emission.

Loads a trained run from its config.yml (as ns-render and ns-viewer do) and renders its test
cameras, in five ways:
- `baked`: what ns-render does: the model's own rendering (background MLP included) with the
  emission MLP evaluated once for the fixed frame embedding and cached, of a camera sliced from the
  path's batch on the GPU per frame (`cameras[i : i + 1]`, nerfstudio's host work);
- `baked_fast_slices`: the same as `wild-thermal-render` slices (`_upstream.camera_unit_slice`: no
  per-frame rebuild of the camera dataclass);
- `baked_cameras_made`: the same with the slices made before the timing: the model's render path alone;
- `unbaked`: the same, with the emission MLP evaluated again for every frame;
- `splat_only`: gsplat's rasterization of the same Gaussians and baked emission alone, no model
  code around it (the floor).
Writes `fps.json` (frames per second per way, at the cameras' resolution, and the largest
difference between baked and unbaked renders) to `--output-dir` and prints it. With
`--profile-frames N` it also profiles N baked frames (host syncs by line, top operators by CPU
time, and cProfile's Python functions: where a frame's time goes beyond the splatting) into
`render_profile.md`.
"""

from __future__ import annotations

import cProfile
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Dict

import torch
import tyro

from experiments import device_name, gpu_kernel_microseconds, python_profile_markdown, synchronize


@dataclass
class FpsArgs:
    load_config: Path
    """config.yml of a trained run."""
    frames: int = 500
    """Frames rendered per way (cycling over the test cameras), after 20 warm-up frames."""
    output_dir: Path = Path("outputs/render_fps")
    profile_frames: int = 0
    """Baked frames to profile (0: none)."""


def _fps(render: Callable[[int], torch.Tensor], frames: int) -> float:
    for i in range(20):
        render(i)
    synchronize()
    start = time.perf_counter()
    for i in range(frames):
        render(i)
    synchronize()
    return frames / (time.perf_counter() - start)


def test_cameras(pipeline):
    """The pipeline's held-out cameras as ns-render holds a camera path: one batch on the model's device,
    from which it slices each frame's camera (`frame_camera`)."""
    return pipeline.datamanager.eval_dataset.cameras.to(pipeline.model.device)


def frame_camera(batch, i: int):
    """Frame `i`'s camera as ns-render hands it to the model: a new camera object, slice `i % n` of `batch`."""
    i %= len(batch)
    return batch[i : i + 1]


def measure_fps(pipeline, frames: int) -> Dict:
    """Frames per second over the pipeline's test cameras: `baked`, `baked_fast_slices`, `baked_cameras_made`,
    `unbaked` and `splat_only` for this plugin's models (the first three only for others), and the largest
    baked/unbaked difference."""

    from thermal_wild_ns._upstream import camera_unit_slice
    from thermal_wild_ns.model.camera_views import intrinsics
    from thermal_wild_ns.rendering import rasterization, world_to_camera
    from thermal_wild_ns.state_names import CANONICAL

    model = pipeline.model
    pipeline.eval()
    cameras = test_cameras(pipeline)
    count = len(cameras)
    width, height = int(cameras.width[0]), int(cameras.height[0])
    ours = hasattr(model, "gaussian_emission")
    has_mlp = ours and model.emission_mlp is not None

    def baked(i: int, camera=None) -> torch.Tensor:
        outputs = model.get_outputs_for_camera(frame_camera(cameras, i) if camera is None else camera)
        return outputs["thermal"] if ours else outputs["rgb"]

    made = [frame_camera(cameras, i) for i in range(count)]
    model_path = lambda i: baked(i, made[i % count])

    def unbaked(i: int) -> torch.Tensor:
        model.parts.emission.baked_values.slots.pop("emission", None)  # forget it: the MLP runs again for this frame
        return baked(i)

    fast_slices = lambda i: baked(i, camera_unit_slice(cameras, i % count))
    ways: Dict[str, Callable[[int], torch.Tensor]] = {
        "baked": baked,
        "baked_fast_slices": fast_slices,
        "baked_cameras_made": model_path,
    }
    result: Dict = {"resolution": f"{width}x{height}", "gaussians": int(model.num_points), "frames": frames}
    with torch.no_grad():
        # the cheap slices render what nerfstudio's slices do (0.0 expected: the same camera)
        result["max_abs_difference_fast_slices"] = max(
            float((fast_slices(i) - baked(i)).abs().max()) for i in range(count)
        )
        if has_mlp:
            ways["unbaked"] = unbaked
            result["max_abs_difference_baked_unbaked"] = max(
                float((unbaked(i) - baked(i)).abs().max()) for i in range(count)
            )
        if ours:
            splat = dict(
                means=model.means,
                quats=model.quats,
                scales=torch.exp(model.scales),
                opacities=torch.sigmoid(model.opacities).squeeze(-1),
                colors=model.gaussian_emission(model.state_embedding(CANONICAL)),
            )
            views = [(world_to_camera(c.camera_to_worlds), intrinsics(c)) for c in made]  # [1, 4, 4], [1, 3, 3]

            def splat_only(i: int) -> torch.Tensor:
                viewmat, K = views[i % len(views)]
                return rasterization(
                    **splat,
                    viewmats=viewmat,
                    Ks=K,
                    width=width,
                    height=height,
                    packed=False,
                    backend=model.config.rasterizer,
                )[0]

            ways["splat_only"] = splat_only
        result["fps"] = {name: round(_fps(fn, frames), 1) for name, fn in ways.items()}
    return result


def profile_baked(pipeline, frames: int) -> str:
    """Markdown: host syncs per frame by line, and the top operators by CPU time, of `frames` baked renders."""
    import collections
    import warnings

    from torch.profiler import ProfilerActivity, profile

    model = pipeline.model
    cameras = test_cameras(pipeline)
    render = lambda i: model.get_outputs_for_camera(frame_camera(cameras, i))
    syncs: Dict[str, int] = collections.Counter()
    with torch.no_grad():
        for i in range(5):
            render(i)
        if torch.cuda.is_available():
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                torch.cuda.set_sync_debug_mode("warn")
                for i in range(5):
                    render(i)
                torch.cuda.set_sync_debug_mode(0)
            for w in caught:
                if "synchroniz" in str(w.message):
                    syncs[f"{w.filename}:{w.lineno}"] += 1
        activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if torch.cuda.is_available() else [])
        with profile(activities=activities) as prof:
            for i in range(frames):
                render(i)
            synchronize()
    gpu_ms = gpu_kernel_microseconds(prof) / 1000 / frames if torch.cuda.is_available() else 0.0
    lines = [f"GPU kernels and copies: {gpu_ms:.3f} ms per baked frame", ""]
    lines += ["Host syncs per baked frame:", ""] + [f"- {n / 5:.1f} x {k}" for k, n in syncs.most_common()]
    lines += ["", "| operator | calls/frame | self CPU ms/frame |", "| --- | --- | --- |"]
    events = sorted(prof.key_averages(), key=lambda e: e.self_cpu_time_total, reverse=True)[:30]
    lines += [f"| {e.key[:70]} | {e.count / frames:.1f} | {e.self_cpu_time_total / 1e3 / frames:.3f} |" for e in events]
    python = cProfile.Profile()
    with torch.no_grad():
        python.enable()
        for i in range(frames):
            render(i)
        synchronize()
        python.disable()
    lines += ["", "Host time by Python function (cProfile, per baked frame):", ""]
    lines.append(python_profile_markdown(python, frames))
    return "\n".join(lines) + "\n"


def measure(args: FpsArgs) -> Dict:
    from nerfstudio.utils.eval_utils import eval_setup

    from thermal_wild_ns._upstream import prepare_checkpoint_commands

    prepare_checkpoint_commands()  # stock splatfacto's run too, whose pipeline is nerfstudio's
    _, pipeline, _, _ = eval_setup(args.load_config, test_mode="test")
    result = {
        "config": str(args.load_config),
        "device": device_name(),
        "torch": torch.__version__,
        **measure_fps(pipeline, args.frames),
    }
    args.output_dir.mkdir(parents=True, exist_ok=True)
    if args.profile_frames > 0:
        (args.output_dir / "render_profile.md").write_text(profile_baked(pipeline, args.profile_frames))
    (args.output_dir / "fps.json").write_text(json.dumps(result, indent=1))
    print(json.dumps(result, indent=1))
    return result


def entrypoint():
    measure(tyro.cli(FpsArgs))


if __name__ == "__main__":
    entrypoint()
