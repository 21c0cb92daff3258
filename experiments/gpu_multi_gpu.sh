#!/usr/bin/env bash
# Issue 35's GPU runs (one scene across GPUs; how big a survey fits on one):
#     bash experiments/gpu_multi_gpu.sh PLAN
# from the repository root on the GPU machine, one plan per device call on one warm machine: `install`
# first, with `.devicebundle` carried (bash ../shared/device/prepare.sh plyfile). Nothing else is carried:
# the surveys are generated there. The code is the carried tree's (PYTHONPATH), the dependencies the bundle's.
#   install       the bundle
#   cost-one      one GPU: survey_cost over 250 and 1000 frames (Gaussian counts until memory runs out)
#   cost-4000     one GPU: the same over 4000 frames; cost-all: 250, 1000 and 4000; cost-1000: 1000
#                 (GROWTH_STEPS=N: then N steps of unbounded growth from the largest count that fitted;
#                 GAUSSIANS="N ...": only those counts)
#   two-vs-one    a 2-GPU host (install first): multi_gpu_cost on the 1,000-frame survey with 1 GPU, then
#                 2 GPUs, up to 2x the count one H200 held (192M; it failed at 256M)
#   quality-one   a 2-GPU host: the 250-frame survey trained 2000 steps through the launcher on 1 GPU,
#                 3 seeds (two at a time), scored with the cheap protocols (experiments.score_checkpoint)
#   quality-two   the same on 2 GPUs per run; both plans: SEEDS="1 2" only those seeds, TAG=-x a suffix on
#                 their files, FRAMES=N an N-frame survey instead of 250, SCORE=later train only (at 1,000
#                 frames scoring takes minutes: train every run first, then quality-score)
#   quality-score score every run the quality plans trained on this machine (/tmp/q) that has no score
#                 yet, all at once, spread over the two GPUs; PROTOCOLS="novel" only those (scoring all three
#                 at 1,000 frames outlasts a call: docs/results/multi_gpu); PROFILE=1 a cProfile of each
#                 (score-RUN.prof)
#   large-two     a 2-GPU host: the 1,000-frame survey trained on 2 GPUs at a count one of its GPUs does not
#                 hold (256M on H200s, 192M on H100s), 600 steps, held-back frames scored on the way, and its
#                 checkpoint; then that checkpoint scored on one GPU (experiments.score_checkpoint)
#   stop-two      a 2-GPU host: the 250-frame survey through the launcher with its defaults (automatic stop,
#                 divergence guard) to its stop, scored on one GPU
set -uo pipefail
plan=${1:?plan: install, cost-one, cost-4000, cost-all, cost-1000, two-vs-one, quality-one, quality-two, large-two, stop-two, quality-score}
OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"
export PYTHONPATH=$PWD:/tmp/site PATH=/tmp/site/bin:$PATH PYTHONUNBUFFERED=1
counts=(${GAUSSIANS:-1000000 4000000 16000000 64000000 128000000 192000000 256000000 320000000 384000000})
score() {  # score RUN GPU: experiments.score_checkpoint on /tmp/q/RUN (a quality plan's run), on that GPU
  local config=/tmp/q/$1/survey/wild-thermal/run/config.yml
  # the limit: under a call's 600 s; the 1,000-frame survey's 125 held-out views take minutes
  local profile=(); [ -n "${PROFILE:-}" ] && profile=(-m cProfile -o "$OUT/score-$1.prof")  # where its seconds go
  CUDA_VISIBLE_DEVICES=$2 timeout 500 python3 "${profile[@]}" -m experiments.score_checkpoint "$config" --protocols ${PROTOCOLS:-novel time aligned} \
    2> "$OUT/score-$1.log" | tail -1 > "$OUT/score-$1.json" && touch "/tmp/q/$1/scored"  # its last line: the scores
}
survey() {  # survey FRAMES: generate the synthetic survey once (every core)
  python3 -c "from pathlib import Path; from thermal_wild_ns.data.survey_scene import *; generate_survey_scene(Path('/tmp/survey_$1'), SurveySceneConfig(num_frames=$1))" > "$OUT/generate_$1.log" 2>&1
}

case "$plan" in
  install)
    source .devicebundle/setup.sh > "$OUT/bundle_setup.log" 2>&1
    tail -2 "$OUT/bundle_setup.log"
    ;;
  cost-one|cost-4000|cost-all|cost-1000)
    frames=(250 1000); [ "$plan" = cost-4000 ] && frames=(4000); [ "$plan" = cost-all ] && frames=(250 1000 4000)
    [ "$plan" = cost-1000 ] && frames=(1000)
    timeout 560 python3 -m experiments.survey_cost --frames "${frames[@]}" --gaussians "${counts[@]}" \
      --growth-steps "${GROWTH_STEPS:-0}" --output-dir "/tmp/$plan" > "$OUT/$plan.log" 2>&1
    cp /tmp/$plan/cost.json "$OUT/$plan.json"; cp /tmp/$plan/cost.md "$OUT/$plan.md"; tail -25 "$OUT/$plan.log"
    ;;
  two-vs-one)
    survey 1000
    mkdir -p /tmp/mgc && ln -sfn /tmp/survey_1000 /tmp/mgc/survey_1000
    # the 2-GPU sweep stops below twice what one GPU held: a rank that ran out of memory would leave
    # the other waiting in a collective until the command's time limit
    both=(4000000 16000000 64000000 192000000)
    CUDA_VISIBLE_DEVICES=0 timeout 200 torchrun --standalone --nproc-per-node 1 -m experiments.multi_gpu_cost \
      --frames 1000 --gaussians "${both[@]}" 256000000 --output-dir /tmp/mgc > "$OUT/one.log" 2>&1
    timeout 300 torchrun --standalone --nproc-per-node 2 -m experiments.multi_gpu_cost \
      --frames 1000 --gaussians "${both[@]}" 256000000 320000000 384000000 --output-dir /tmp/mgc > "$OUT/two.log" 2>&1
    cp /tmp/mgc/multi_gpu_cost_*.json "$OUT/"; grep -h '^{"gaussians' "$OUT/one.log" "$OUT/two.log"
    ;;
  large-two)
    survey 1000
    mkdir -p /tmp/mgl && ln -sfn /tmp/survey_1000 /tmp/mgl/survey_1000
    gib=$(nvidia-smi --query-gpu=memory.total --format=csv,noheader,nounits | head -1)
    count=192000000; [ "$gib" -gt 100000 ] && count=256000000
    timeout 420 torchrun --standalone --nproc-per-node 2 -m experiments.multi_gpu_cost --frames 1000 \
      --gaussians 4000000 --steps 5 --train-at $count --train-steps 600 --score-every 200 \
      --output-dir /tmp/mgl > "$OUT/large-two.log" 2>&1
    cp /tmp/mgl/multi_gpu_train_2.json "$OUT/"; tail -n 30 "$OUT/large-two.log"
    CUDA_VISIBLE_DEVICES=0 timeout 150 python3 -m experiments.score_checkpoint /tmp/mgl/runs/survey_1000/wild-thermal/cost/config.yml \
      > "$OUT/score-large-one-gpu.json" 2> "$OUT/score-large-one-gpu.log"
    cat "$OUT/score-large-one-gpu.json"; nvidia-smi --query-gpu=name,memory.total --format=csv > "$OUT/gpus.csv"
    ;;
  stop-two)
    survey 250
    timeout 450 torchrun --standalone --nproc-per-node 2 -m thermal_wild_ns.multi_gpu wild-thermal \
      --output-dir /tmp/stop --experiment-name survey --timestamp run --pipeline.model.max-gaussians 1000000 \
      --max-num-iterations "${STOP_STEPS:-30000}" --vis tensorboard \
      --pipeline.datamanager.preprocessing-cache /tmp/stop/cache \
      thermal-demo-data --data /tmp/survey_250 --scene survey --survey-frames 250 > "$OUT/stop-two.log" 2>&1
    cp /tmp/stop/survey/wild-thermal/run/auto_stop.json "$OUT/stop-two-auto_stop.json"
    cp /tmp/stop/survey/wild-thermal/run/events.out.tfevents.* "$OUT/"  # the Gaussian count, loss and PSNR per step
    timeout 90 python3 -m experiments.score_checkpoint /tmp/stop/survey/wild-thermal/run/config.yml \
      > "$OUT/score-stop-two.json" 2> "$OUT/score-stop-two.log"
    grep -i "stops\|kept\|skipped\|rolled" "$OUT/stop-two.log" | tail -5; cat "$OUT/score-stop-two.json"
    ;;
  quality-one|quality-two)
    frames=${FRAMES:-250}; survey "$frames"
    tag=${TAG:-}  # a suffix of the run's files, to keep the runs of an earlier commit apart
    train() {  # train GPUS SEED CUDA_VISIBLE_DEVICES
      CUDA_VISIBLE_DEVICES=$3 timeout 240 torchrun --standalone --nproc-per-node "$1" -m thermal_wild_ns.multi_gpu \
        wild-thermal --output-dir "/tmp/q/gpus$1$tag-seed$2" --experiment-name survey --timestamp run \
        --max-num-iterations 2000 --machine.seed "$2" --pipeline.datamanager.train-order-seed "$2" \
        --pipeline.model.max-gaussians 1000000 --pipeline.datamanager.preprocessing-cache /tmp/q/cache \
        thermal-demo-data --data "/tmp/survey_$frames" --scene survey --survey-frames "$frames" > "$OUT/train-gpus$1$tag-seed$2.log" 2>&1
      [ "${SCORE:-}" = later ] && { tail -n2 "$OUT/train-gpus$1$tag-seed$2.log"; return; }
      score "gpus$1$tag-seed$2" 0
    }
    if [ "$plan" = quality-one ] && [ -n "${SEEDS:-}" ]; then  # only those seeds, each on GPU 0
      for seed in $SEEDS; do train 1 $seed 0; done
    elif [ "$plan" = quality-one ]; then  # one GPU each, two at a time
      train 1 1 0 & train 1 2 1 & wait
      train 1 3 0
    else
      for seed in ${SEEDS:-1 2 3}; do train 2 $seed 0,1; done
    fi
    tail -n1 "$OUT"/score-*.json
    ;;
  quality-score)
    gpu=0; n=0
    for run in /tmp/q/gpus*-seed*; do
      [ -e "$run/scored" ] && continue
      score "$(basename "$run")" $gpu &
      n=$((n + 1)); gpu=$((n % 2))
    done
    wait; tail -n1 "$OUT"/score-*.json
    ;;
esac
