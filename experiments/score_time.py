"""`python -m experiments.score_time RUN/config.yml ...`: how long scoring a trained run's held-out views takes
under every protocol (as `wild-thermal-demo` and the bench score them), with the scores and the held-out fits'
optimizer steps (each a render of up to `--fit-views` views and its backward), one JSON line per run (`seconds`
the scoring's, `setup_seconds` the run's loading before it); with
`--profile FILE.md`, where each run's scoring time goes (cProfile, per held-out view) appended to FILE.md.
Run as a script with two packages on the same checkpoints (the package of PYTHONPATH's tree is the one timed), to
see a change's cost and that its scores stay:

    PYTHONPATH=/tmp/tree-before python experiments/score_time.py RUN/config.yml ... > before.jsonl
    PYTHONPATH=$PWD python experiments/score_time.py RUN/config.yml ... > after.jsonl
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import json
import time
from pathlib import Path

import torch
from nerfstudio.utils.eval_utils import eval_setup

from experiments import device_name, python_profile_markdown, synchronize
from thermal_wild_ns._upstream import prepare_checkpoint_commands
from thermal_wild_ns.pipeline.evaluation import PROTOCOLS, evaluate


def main() -> None:
    parser = argparse.ArgumentParser(description="Time the scoring of trained runs under every protocol.")
    parser.add_argument("configs", type=Path, nargs="+", help="the runs' config.yml")
    parser.add_argument("--fit-steps", type=int, default=100, help="embedding fit steps of `half` and `oracle`")
    parser.add_argument("--fit-views", type=int, default=8, help="held-out views fitted together, one render a step")
    parser.add_argument(
        "--profile", type=Path, default=None, help="also profile each run's scoring (cProfile, per view) into this .md"
    )
    args = parser.parse_args()
    prepare_checkpoint_commands()
    fit_steps = [0]  # the held-out fits' optimizer steps (each a render of several views and its backward)
    adam_step = torch.optim.Adam.step

    def counted(self, *args, **kwargs):
        fit_steps[0] += 1
        return adam_step(self, *args, **kwargs)

    torch.optim.Adam.step = counted
    for config in args.configs:
        start = time.perf_counter()
        _, pipeline, _, _ = eval_setup(config, test_mode="test")
        setup_seconds = time.perf_counter() - start  # reading the run's data and checkpoint, as ns-eval does first
        fit_steps[0] = 0
        profiler = cProfile.Profile() if args.profile is not None else None
        start = time.perf_counter()
        with profiler or contextlib.nullcontext():
            scores = evaluate(pipeline, protocols=PROTOCOLS, fit_steps=args.fit_steps, fit_views=args.fit_views)
            synchronize()
        seconds = time.perf_counter() - start
        psnr = {k: v for k, v in scores.items() if k.startswith("psnr_")}
        views = len(scores["per_view"])
        record = {
            "config": str(config),
            "views": views,
            "fit_views": args.fit_views,
            "setup_seconds": round(setup_seconds, 2),
            "seconds": round(seconds, 2),
            "fit_steps": fit_steps[0],
        }
        record.update(psnr)
        print(json.dumps(record), flush=True)
        if profiler is not None:
            header = f"# Scoring {config} on {device_name()}: {seconds:.2f} s (profiled), {views} views\n\n"
            with open(args.profile, "a") as out:
                out.write(header + "Per held-out view, " + python_profile_markdown(profiler, views) + "\n")


if __name__ == "__main__":
    main()
