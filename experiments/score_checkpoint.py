"""Score one trained run with the cheap protocols (no fitting), as JSON: the same checkpoint scored
by two versions of the package (PYTHONPATH=TREE) must give the same numbers when a change claims
to change none.

    PYTHONPATH=/path/to/tree python -m experiments.score_checkpoint RUN/config.yml [--canonical typical]

`--canonical` renders the novel views at another canonical state than the run's own
(`canonical_embedding`: 'mean' or 'typical'), to compare them on one checkpoint.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from nerfstudio.utils.eval_utils import eval_setup

from thermal_wild_ns._upstream import prepare_checkpoint_commands
from thermal_wild_ns.pipeline.evaluation import evaluate


def main() -> None:
    parser = argparse.ArgumentParser(description="Score a trained run with the cheap protocols.")
    parser.add_argument("config", type=Path, help="the run's config.yml")
    parser.add_argument("--canonical", help="the canonical state to render novel views at (default: the run's)")
    parser.add_argument(
        "--protocols", nargs="+", default=["novel", "time", "aligned"], help="which cheap protocols (default: all)"
    )
    args = parser.parse_args()
    prepare_checkpoint_commands()
    _, pipeline, _, _ = eval_setup(args.config, test_mode="test")
    if args.canonical:
        pipeline.model.config.canonical_embedding = args.canonical
    scores = evaluate(pipeline, protocols=tuple(args.protocols))
    print(json.dumps({k: v for k, v in scores.items() if not isinstance(v, (list, dict))}, sort_keys=True))


if __name__ == "__main__":
    main()
