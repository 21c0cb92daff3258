"""`python -m experiments.view_verdict`: what the view term's trial (`--auto-stop.decide-view-term`,
`thermal_wild_ns/training/view_probe.py`) decides on each scene and seed, without training on past it.

Each run is the bench's (`experiments.bench`: the same config, schedule and seed) with a view term on
trial; it stops at the scored check where the trial decides (`--view-trial-checks`), and records the
verdict: the held-back score without the term and with it, and the radial share of what it adds to training
views (`ViewTermVerdict`). A cheap check of the
rule against scenes whose answer the GPU runs know (the generated vignetting scene loses with the term,
`stress:view` gains: docs/results/view_defaults_h200, docs/results/view_trial_gpu). Writes `verdicts.json`
to `--output-dir`.

    python -m experiments.view_verdict --scenes stress:vignetting stress:view --seeds 3 --output-dir /tmp/verdicts
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import List, Optional, Tuple

import tyro

from experiments import train_with_hooks
from experiments.bench import BenchArgs, setup_trainer, trainer_config
from experiments.scenes import scene_name
from thermal_wild_ns.progress import track
from thermal_wild_ns.training.held_back import held_back_score


@dataclass
class VerdictArgs:
    scenes: Tuple[str, ...] = ("stress:vignetting", "stress:view")
    """'demo', 'stress:FAULT' or dataset folders (as in python -m experiments.bench)."""
    seeds: int = 3
    seed: int = 0
    """The first seed."""
    steps: int = 5000
    """The schedule asked for (the bench's generated-scene protocol: 5,000 steps, one downscale)."""
    num_downscales: Optional[int] = 1
    """The warm-up's downscales (1: the generated-scene protocol); None: the method's own, as the bench's
    real-capture runs."""
    view_sh_degree: int = 2
    view_trial_checks: int = 1
    """The scored check at which the trial decides (`auto_stop.view_trial_checks`)."""
    output_dir: Path = Path("outputs/view_verdict")
    cache_dir: Optional[Path] = None
    """Where a real capture's triangulation is cached (as the bench's `--cache-dir`)."""


class _Decided(Exception):
    """Raised after the step whose check decided the view term: the run has nothing left to show."""


def verdict_of(scene: str, seed: int, args: VerdictArgs) -> dict:
    bench = BenchArgs(
        scenes=(scene,),
        methods=("wild-thermal",),
        steps=args.steps,
        num_downscales=args.num_downscales,
        set=(
            f"pipeline.model.view_sh_degree={args.view_sh_degree}",
            "auto_stop.decide_view_term=True",
            f"auto_stop.view_trial_checks={args.view_trial_checks}",
        ),
        output_dir=args.output_dir,
        cache_dir=args.cache_dir,
    )
    config = trainer_config("wild-thermal", scene, bench, args.output_dir / "runs" / scene_name(scene), seed)
    trainer = setup_trainer(config)
    run = trainer.auto_stop

    def after_step(step: int) -> None:
        if run.view_verdict is not None:
            raise _Decided

    try:
        train_with_hooks(trainer, args.steps, after_step)
    except _Decided:
        pass
    verdict = None if run.view_verdict is None else run.view_verdict.as_record()
    return dict(scene=scene_name(scene), seed=seed, verdict=verdict, scores=_scores_both_ways(trainer))


def _scores_both_ways(trainer) -> dict:
    """Where the trial kept the term: the held-back score without it and with it (PSNR, dB) at the
    frames' own states and at the canonical state, each with the trial's fit (gain, offset and radial
    fall-off) and with gain and offset alone (the `aligned` protocol's); {} where it went (zeroed)."""
    model, pipeline = trainer.pipeline.model, trainer.pipeline
    if not model.renders_view_term():
        return {}
    held = pipeline.datamanager.held_back
    scores = {}
    for term in ("without", "with"):
        if term == "without":
            model.try_view_term()  # renders outside training leave the term out, as on trial
        else:
            model.use_view_term(True)
        for canonical in (False, True):
            for radial in (True, False):
                key = f"{'canonical' if canonical else 'own'}-{'radial' if radial else 'plain'}-{term}"
                scores[key] = held_back_score(pipeline, held, radial=radial, canonical=canonical)
    return scores


def main(args: VerdictArgs) -> List[dict]:
    args.output_dir.mkdir(parents=True, exist_ok=True)
    jobs = [(scene, args.seed + k) for scene in args.scenes for k in range(args.seeds)]
    results = []
    for scene, seed in track(jobs, "view-term trials"):
        results.append(verdict_of(scene, seed, args))
        (args.output_dir / "verdicts.json").write_text(
            json.dumps(dict(args={k: str(v) for k, v in dataclasses.asdict(args).items()}, runs=results), indent=1)
        )
    for r in results:
        v = r["verdict"]
        if v is None:
            print(f"{r['scene']} seed {r['seed']}: no verdict")
            continue
        print(
            f"{r['scene']} seed {r['seed']}: step {v['step']}, held-back {v['without']:.2f} -> {v['with_term']:.2f} "
            f"dB: {'kept' if v['kept'] else 'off'}"
        )
        s = r["scores"]
        for way in ("own-radial", "own-plain", "canonical-radial", "canonical-plain"):
            if f"{way}-with" in s:
                print(f"    {way}: {s[f'{way}-without']:.2f} -> {s[f'{way}-with']:.2f}")
    return results


if __name__ == "__main__":
    main(tyro.cli(VerdictArgs))
