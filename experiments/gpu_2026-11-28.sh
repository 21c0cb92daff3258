#!/usr/bin/env bash
# Plans for the GPU after the Gaussian budget's default changed (2026-11-28: the held-back frames set it from
# 12,500; docs/results/grow_default_h200): issue 33's scene table with every method at today's defaults. One plan
# per device call on one warm machine, from the repository root, two GPUs (nvidia-h100-x2 or nvidia-h200-x2):
#     bash experiments/gpu_2026-11-28.sh install               # .devicebundle carried
#     GPUS=2 bash experiments/gpu_2026-11-28.sh ablations-generated   # nothing carried (generated scenes)
#     GPUS=2 bash experiments/gpu_2026-11-28.sh ablations-flight2     # .data/flight2 .data/cache carried
#     GPUS=2 bash experiments/gpu_2026-11-28.sh ablations-dunr        # .data/dunr .data/cache carried
# Results go to $OUT. The full method's runs at today's defaults are grow_default_h200's (start 12,500, the same
# protocols); the scene table: python -m experiments.full_vs_ablations (docs/results.md names its inputs).
set -uo pipefail
plan=${1:?plan: install, ablations-generated, ablations-flight2, ablations-dunr}
OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"
export PATH=/tmp/site/bin:$PATH PYTHONUNBUFFERED=1
ABLATIONS=(wild-thermal-emission-mlp wild-thermal-3dgs wild-thermal-3dgs-stab-bbhe)

case "$plan" in
  install)  # the bundle, as every device script installs it
    bash experiments/gpu_2026-11-26.sh install
    ;;
  ablations-generated)  # the three ablations on the demo and the five stress scenes, issue 16's protocol (5,000
    # steps asked, the 1/2-resolution warm-up, the stop on), 3 seeds, one bench per ablation (18 runs, nine at a
    # time on each GPU), one after another
    for method in "${ABLATIONS[@]}"; do
      test -d /tmp/site || exit 3
      PYTHONPATH=$PWD:/tmp/site timeout 190 python3 -m experiments.bench --output-dir "/tmp/gen-$method" \
        --scenes demo stress:clean stress:drift stress:ffc stress:outlier stress:vignetting --methods "$method" \
        --seeds 3 --steps 5000 --num-downscales 1 --eval-at 500 1000 2000 5000 --fps-frames 0 --runs-per-gpu 9 \
        --gpus "${GPUS:-2}" > "$OUT/generated-$method.log" 2>&1
      cp "/tmp/gen-$method/bench.json" "$OUT/generated-$method-bench.json"
    done
    ;;
  ablations-flight2|ablations-dunr)  # the three ablations on one real capture, 3 seeds each, the first 15,000
    # steps of the 30k schedule asked, the stop on (as ablations-* of gpu_2026-11-27.sh), nine runs over GPUS GPUs
    test -d /tmp/site || exit 3
    scene=${plan#ablations-}
    PYTHONPATH=$PWD:/tmp/site timeout 570 python3 -m experiments.bench --output-dir "/tmp/ablations-$scene" \
      --scenes "$PWD/.data/$scene" --cache-dir "$PWD/.data/cache" --seeds 3 --gpus "${GPUS:-2}" --runs-per-gpu 5 \
      --methods "${ABLATIONS[@]}" --fit-steps 20 --fps-frames 0 --steps 15000 --schedule 30000 --eval-at 5000 15000 \
      > "$OUT/$scene-ablations.log" 2>&1
    cp "/tmp/ablations-$scene/bench.json" "$OUT/$scene-ablations.json"
    ;;
  *) echo "unknown plan $plan" >&2; exit 2 ;;
esac
