"""Score one trained run with the cheap protocols (no fitting), as JSON: the same checkpoint scored
by two versions of the package (PYTHONPATH=TREE) must give the same numbers when a change claims
to change none.

    PYTHONPATH=/path/to/tree python -m experiments.score_checkpoint RUN/config.yml
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from nerfstudio.utils.eval_utils import eval_setup

from thermal_wild_ns._upstream import prepare_checkpoint_commands
from thermal_wild_ns.pipeline.evaluation import evaluate


def main() -> None:
    prepare_checkpoint_commands()
    _, pipeline, _, _ = eval_setup(Path(sys.argv[1]), test_mode="test")
    scores = evaluate(pipeline, protocols=("novel", "time", "aligned"))
    print(json.dumps({k: v for k, v in scores.items() if not isinstance(v, (list, dict))}, sort_keys=True))


if __name__ == "__main__":
    main()
