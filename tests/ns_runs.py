"""Runs through nerfstudio's own commands, in this process, as a user makes them: `ns-train` with the
method's defaults, then the commands that load its result."""

from __future__ import annotations

import json
import math

import torch

STEPS = 3
"""A first quick try's length: far inside the coarse-to-fine warm-up and before the stop's first check."""


def ns_train(args):
    """`ns-train ARGS` in this process: nerfstudio's own parser and train main."""
    import tyro
    from nerfstudio.configs.method_configs import AnnotatedBaseConfigUnion
    from nerfstudio.scripts.train import main

    config = tyro.cli(AnnotatedBaseConfigUnion, args=args)
    main(config)
    return config


def run_args(out, steps: int = STEPS, *extra: str) -> list:
    """`ns-train wild-thermal` options of a short run with the method's defaults; only where it writes
    differs, and `ns-eval` scores `half` and `oracle` without fitting an embedding per view
    (`eval_fit_steps`, a user option: on a CPU those fits would take most of the test's time)."""
    return [
        "wild-thermal",
        "--max-num-iterations",
        str(steps),
        "--vis",
        "tensorboard",
        "--output-dir",
        str(out),
        "--experiment-name",
        "x",
        "--timestamp",
        "run",
        "--pipeline.eval-fit-steps",
        "0",
        "--pipeline.datamanager.preprocessing-cache",
        str(out / "cache"),
        *extra,
    ]


def check_run_end_to_end(run, tmp_path, steps: int = STEPS) -> dict:
    """The run in folder `run` ended with its final checkpoint after the automatic stop's score;
    `ns-eval` scores it and `wild-thermal-render` renders from it. Returns the ns-eval results."""
    from nerfstudio.scripts.eval import ComputePSNR

    from thermal_wild_ns.rendering.radiometric_render import RenderInterpolated

    checkpoints = sorted((run / "nerfstudio_models").glob("step-*.ckpt"))
    assert [c.name for c in checkpoints] == [f"step-{steps - 1:09d}.ckpt"]
    state = torch.load(checkpoints[-1], map_location="cpu")
    means = state["pipeline"]["_model.gauss_params.means"]
    assert means.dtype == torch.float32 and means.shape[0] >= 4 and bool(torch.isfinite(means).all())
    record = json.loads((run / "auto_stop.json").read_text())
    assert record["last_step"] == steps - 1 and math.isfinite(record["final_psnr"])  # the stop's score ran
    assert not list((run / ".partial").glob("*"))  # nothing left half-written

    ComputePSNR(load_config=run / "config.yml", output_path=tmp_path / "eval.json").main()
    results = json.loads((tmp_path / "eval.json").read_text())["results"]
    assert results["views"] >= 1
    assert all(math.isfinite(results[f"psnr_{p}"]) for p in ("novel", "time", "aligned", "half", "oracle"))

    RenderInterpolated(
        load_config=run / "config.yml",
        output_path=tmp_path / "frames",
        interpolation_steps=1,
        output_format="images",
        radiometric="uint16",
    ).main()
    assert list((tmp_path / "frames").glob("*.jpg")) and list((tmp_path / "frames_radiometric").glob("*.png"))
    return results
