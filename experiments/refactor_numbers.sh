#!/usr/bin/env bash
# The numbers a refactor must not change, from the package tree at $1 (put first on PYTHONPATH) into $2:
# the CPU demo's metrics.json (its random generators seeded as ns-train seeds them: experiments/seeded_demo.py,
# so that trees from before the demo seeded itself compare too), and a 300-step DUNR run at 1/4 resolution
# (ns-train seeds it) scored by ns-eval.
#     bash experiments/refactor_numbers.sh /tmp/tree-before /tmp/numbers-before    # a git worktree of the old commit
#     bash experiments/refactor_numbers.sh "$PWD" /tmp/numbers-after
# Run from the repository root (its .venv); DUNR from ../shared/data/dunr.
set -euo pipefail
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
tree=$(cd "$1" && pwd); out=$2; mkdir -p "$out"; out=$(cd "$out" && pwd)
venv=${VENV:-$PWD/.venv}; dunr=${DUNR:-$(cd ../shared/data/dunr && pwd)}
cd "$tree"
export PYTHONPATH="$tree" OMP_NUM_THREADS=1
"$venv/bin/python" "$here/seeded_demo.py" --output-dir "$out/demo" > "$out/demo.log" 2>&1
"$venv/bin/ns-train" wild-thermal --output-dir "$out/runs" --experiment-name dunr --timestamp run --vis tensorboard \
  --max-num-iterations 300 --pipeline.datamanager.camera-res-scale-factor 0.25 thermal --data "$dunr" \
  --cache-dir "$out/cache" > "$out/dunr.log" 2>&1
"$venv/bin/ns-eval" --load-config "$out/runs/dunr/wild-thermal/run/config.yml" --output-path "$out/dunr_eval.json" \
  > "$out/eval.log" 2>&1
