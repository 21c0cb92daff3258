#!/usr/bin/env bash
# Issue 34's speed runs: bash experiments/gpu_render_speed.sh PLAN, from the repository root on
# the GPU machine, one plan per device call on one warm machine: `install` with `.devicebundle` carried,
# then `fps` with `.data/dunr` and `.data/cache` carried (and `.before`, a copy of an earlier
# tree, to time both in one call: `mkdir .before && git archive REV thermal_wild_ns experiments | tar -x -C .before`).
#   install   the bundle
#   fps       DUNR trained 6,000 steps of the 30k schedule (one seed, experiments.bench), then
#             experiments.render_fps on that run: the carried code's model, and `.before`'s where carried;
#             then the GPU tests (tests/test_gpu_parity.py)
#   step-graphs  the GPU tests, then experiments.profile_step on DUNR (step 1,500 of the 30k schedule)
#             with the boolean setting SETTING (default pipeline.model.graphed_loss: the loss run kernel by
#             kernel or replayed as CUDA graphs) False and True in turn, ROUNDS times (default 2):
#             profile-{eager,graphed}-ROUND.md, steps.jsonl
#   step-graphs-accuracy  DUNR, 3 seeds, the first 3,000 steps of the 30k schedule (experiments.bench),
#             with SETTING False, then True: accuracy-NAME-{False,True}-bench.{json,md}, NAME the setting's
#             last part
set -uo pipefail
plan=${1:?plan: install, fps, step-graphs, step-graphs-accuracy}
setting=${SETTING:-pipeline.model.graphed_loss}
OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"
export PATH=/tmp/site/bin:$PATH PYTHONUNBUFFERED=1
case "$plan" in
  install)
    source .devicebundle/setup.sh > "$OUT/bundle_setup.log" 2>&1
    tail -2 "$OUT/bundle_setup.log"
    ;;
  fps)
    PYTHONPATH=$PWD:/tmp/site timeout 300 python3 -m experiments.bench --output-dir /tmp/rs --scenes "$PWD/.data/dunr" \
      --cache-dir "$PWD/.data/cache" --methods wild-thermal --seeds 1 --steps 6000 --schedule 30000 --eval-at 6000 \
      --fps-frames 0 > "$OUT/train.log" 2>&1
    config=$(python3 -c "import json; print(json.load(open('/tmp/rs/bench.json'))['runs'][0]['config'])")
    # before and after in turn, three times (fps_rounds.jsonl): the machine's pace drifts within a call.
    # `python -m` puts the working directory first on the path, so each runs from its own tree
    for round in 1 2 3; do
      for code in before after; do
        tree=$PWD; [ "$code" = before ] && tree=$PWD/.before
        [ -d "$tree/thermal_wild_ns" ] || continue
        profile=0; [ "$round" = 1 ] && profile=200
        (cd "$tree" && PYTHONPATH=/tmp/site timeout 120 python3 -m experiments.render_fps --load-config "$config" \
          --frames 1000 --profile-frames $profile --output-dir "/tmp/fps-$code-$round" > "/tmp/fps-$code-$round.log" 2>&1 || tail -5 "/tmp/fps-$code-$round.log")
        python3 -c "import json, sys; r = {'code': '$code', 'round': $round, **json.load(open(sys.argv[1]))}
open(sys.argv[2], 'a').write(json.dumps(r) + '\n'); print('$code', $round, r['fps'])" "/tmp/fps-$code-$round/fps.json" "$OUT/fps_rounds.jsonl"
        [ "$round" = 1 ] && cp "/tmp/fps-$code-1/render_profile.md" "$OUT/render_profile-$code.md"
      done
    done
    PYTHONPATH=$PWD:/tmp/site timeout 120 python3 -m pytest -q -p no:cacheprovider tests/test_gpu_parity.py \
      > "$OUT/gpu_tests.log" 2>&1; tail -3 "$OUT/gpu_tests.log"
    ;;
  step-graphs)
    PYTHONPATH=$PWD:/tmp/site timeout 120 python3 -m pytest -q -p no:cacheprovider tests/test_gpu_parity.py \
      > "$OUT/gpu_tests.log" 2>&1; tail -3 "$OUT/gpu_tests.log"
    for round in $(seq "${ROUNDS:-2}"); do
      for loss in eager graphed; do
        graphed=False; [ "$loss" = graphed ] && graphed=True
        PYTHONPATH=$PWD:/tmp/site timeout 150 python3 -m experiments.profile_step --scene "$PWD/.data/dunr" \
          --cache-dir "$PWD/.data/cache" --set "$setting=$graphed" \
          --output-dir "/tmp/prof-$loss-$round" > "/tmp/prof-$loss-$round.log" 2>&1 || tail -5 "/tmp/prof-$loss-$round.log"
        cp "/tmp/prof-$loss-$round/profile.md" "$OUT/profile-$loss-$round.md"
        python3 -c "import json, sys; r = {'loss': '$loss', 'round': $round, **json.load(open(sys.argv[1]))}
open(sys.argv[2], 'a').write(json.dumps(r) + '\n')" "/tmp/prof-$loss-$round/profile.json" "$OUT/steps.jsonl"
        echo "$loss $round: $(grep -E 'ms/step' "$OUT/profile-$loss-$round.md")"
      done
    done
    ;;
  step-graphs-accuracy)
    for g in False True; do
      PYTHONPATH=$PWD:/tmp/site timeout 280 python3 -m experiments.bench --output-dir /tmp/acc-$g --scenes "$PWD/.data/dunr" \
        --cache-dir "$PWD/.data/cache" --methods wild-thermal --seeds 3 --steps 3000 --schedule 30000 --eval-at 3000 \
        --fps-frames 0 --set "$setting=$g" > /tmp/acc-$g.log 2>&1 || tail -5 /tmp/acc-$g.log
      cp /tmp/acc-$g/bench.json "$OUT/accuracy-${setting##*.}-$g-bench.json"
      cp /tmp/acc-$g/bench.md "$OUT/accuracy-${setting##*.}-$g-bench.md"
      grep -E "^\| wild" /tmp/acc-$g/bench.md | head -3
    done
    ;;
esac
