#!/usr/bin/env bash
# Since 2026-11-29 the repository and the bundle exceed the 64 MiB a call carries: install with the two calls of
# `experiments/gpu_2026-11-29.sh` (install, install-extra; its header) in place of `install` here, and carry one
# capture's own triangulation cache (.data/cache/triangulation-*), not the whole .data/cache.
# The GPU runs of 2026-11-27 and the plans left for the next sessions (issues 33 and 34; each plan's comment says
# what it asks), one plan per device call on one warm machine, from the repository root:
#     bash experiments/gpu_2026-11-27.sh install                 # .devicebundle carried
#     bash experiments/gpu_2026-11-27.sh lut-blend-flight2       # .data/flight2 .data/cache .baseline carried
#     bash experiments/gpu_2026-11-27.sh lut-blend-dunr          # .data/dunr .data/cache .baseline carried
#     bash experiments/gpu_2026-11-27.sh schedule-dunr           # .data/dunr .data/cache carried
#     bash experiments/gpu_2026-11-27.sh step-guard-dunr         # the same
#     bash experiments/gpu_2026-11-27.sh falloff-flight2         # .data/flight2 .data/cache carried
#     bash experiments/gpu_2026-11-27.sh falloff-dunr            # .data/dunr .data/cache carried
#     bash experiments/gpu_2026-11-27.sh trial-vignetting        # nothing carried (a generated scene)
#     bash experiments/gpu_2026-11-27.sh log-writes-dunr         # .data/dunr .data/cache .baseline carried
#     bash experiments/gpu_2026-11-27.sh falloff-vignetting      # nothing carried
#     bash experiments/gpu_2026-11-27.sh flat-field-flight2      # .data/flight2 .data/cache carried
#     bash experiments/gpu_2026-11-27.sh flat-field-dunr         # .data/dunr .data/cache carried
#     bash experiments/gpu_2026-11-27.sh flat-field-generated    # nothing carried
#     bash experiments/gpu_2026-11-27.sh flat-field-decay        # .data/flight2 .data/cache carried
#     bash experiments/gpu_2026-11-27.sh guard-device-dunr       # .data/dunr .data/cache .baseline carried
#     bash experiments/gpu_2026-11-27.sh canonical-flight2       # .data/flight2 .data/cache carried
#     bash experiments/gpu_2026-11-27.sh canonical-dunr          # .data/dunr .data/cache carried
#     bash experiments/gpu_2026-11-27.sh parts-flight2           # .data/flight2 .data/cache carried
#     bash experiments/gpu_2026-11-27.sh parts-dunr              # .data/dunr .data/cache carried
#     bash experiments/gpu_2026-11-27.sh defaults-flight2        # .data/flight2 .data/cache carried
#     bash experiments/gpu_2026-11-27.sh growth-camera-flight2   # .data/flight2 .data/cache carried
#     bash experiments/gpu_2026-11-27.sh splatfacto-30k-flight2  # two GPUs (nvidia-h200-x2); .data/flight2 .data/cache
#     bash experiments/gpu_2026-11-27.sh splatfacto-30k-dunr     # the same with .data/dunr
#     bash experiments/gpu_2026-11-27.sh ablations-flight2       # .data/flight2 .data/cache carried
#     bash experiments/gpu_2026-11-27.sh ablations-dunr          # .data/dunr .data/cache carried
#     bash experiments/gpu_2026-11-27.sh view-camera-flight2     # .data/flight2 .data/cache carried
#     bash experiments/gpu_2026-11-27.sh view-camera-dunr        # .data/dunr .data/cache carried
#     bash experiments/gpu_2026-11-27.sh gpu-tests               # nothing carried: the tests that need CUDA
#     bash experiments/gpu_2026-11-27.sh camera-cost-dunr        # .data/dunr .data/cache carried
#     bash experiments/gpu_2026-11-27.sh survey-camera           # nothing carried (a generated scene)
#     bash experiments/gpu_2026-11-27.sh budget-camera-flight2   # .data/flight2 .data/cache carried
#     bash experiments/gpu_2026-11-27.sh budget-camera-dunr      # .data/dunr .data/cache carried
#     bash experiments/gpu_2026-11-27.sh camera-graph-dunr       # .data/dunr .data/cache carried
#     bash experiments/gpu_2026-11-27.sh smoothness-flight2      # .data/flight2 .data/cache carried
#     bash experiments/gpu_2026-11-27.sh smoothness-dunr         # .data/dunr .data/cache carried
#     bash experiments/gpu_2026-11-27.sh preprocessing-dunr      # .data/dunr .data/cache carried
#     bash experiments/gpu_2026-11-27.sh budget-raw-flight2      # .data/flight2 .data/cache carried
#     bash experiments/gpu_2026-11-27.sh radial-generated        # .devicebundle carried (it installs)
#     bash experiments/gpu_2026-11-27.sh growth-raw-flight2      # .data/flight2 .data/cache carried
#     bash experiments/gpu_2026-11-27.sh growth-view-flight2     # .data/flight2 .data/cache carried
#     bash experiments/gpu_2026-11-27.sh time-blend-generated    # .devicebundle carried (it installs)
#     bash experiments/gpu_2026-11-27.sh emission-rate-flight2   # .data/flight2 .data/cache carried
#     bash experiments/gpu_2026-11-27.sh emission-rate-dunr      # .data/dunr .data/cache carried
#     bash experiments/gpu_2026-11-27.sh ttq-dunr                # two GPUs (nvidia-h100-x2); .data/dunr .data/cache
#     bash experiments/gpu_2026-11-27.sh ttq-flight2             # the same with .data/flight2
#     VARIANT=smoothness GPUS=2 bash experiments/gpu_2026-11-27.sh state-generated  # .devicebundle carried (it installs)
#     VARIANT=cap GPUS=2 bash experiments/gpu_2026-11-27.sh state-generated         # the same
#     VARIANT=default GPUS=2 bash experiments/gpu_2026-11-27.sh state-generated     # the same
#     VARIANT=grow GPUS=2 bash experiments/gpu_2026-11-27.sh state-generated        # the same
#     VARIANT=grow12500 GPUS=1 bash experiments/gpu_2026-11-27.sh state-generated   # the same
#     VARIANT=fixed GPUS=1 bash experiments/gpu_2026-11-27.sh state-generated       # the same
#     bash experiments/gpu_2026-11-27.sh grow-small-flight2      # .data/flight2 .data/cache carried
#     bash experiments/gpu_2026-11-27.sh grow-small-dunr         # .data/dunr .data/cache carried
# `.baseline` holds the package of the commit before a change (git archive BASELINE thermal_wild_ns experiments
# | tar -x -C .baseline). Results go to $OUT. Each lut-blend plan trains the full method with its defaults (3 seeds side by side,
# 15,000 of the 30k schedule, the automatic stop on), then scores every run's final checkpoint with the
# `time` protocol by this tree's package and by the baseline's (experiments.score_checkpoint): the same
# Gaussians and embeddings, two ways of predicting a held-out frame's LUT.
set -uo pipefail
plan=${1:?plan: install, lut-blend-flight2, lut-blend-dunr, schedule-dunr, step-guard-dunr, falloff-flight2, falloff-dunr, trial-vignetting, log-writes-dunr, falloff-vignetting, flat-field-flight2, flat-field-dunr, flat-field-generated, flat-field-decay, guard-device-dunr, canonical-flight2, canonical-dunr, parts-flight2, parts-dunr, defaults-flight2, growth-camera-flight2, splatfacto-30k-flight2, splatfacto-30k-dunr, ablations-flight2, ablations-dunr, view-camera-flight2, view-camera-dunr, gpu-tests, camera-cost-dunr, survey-camera, budget-camera-flight2, budget-camera-dunr, camera-graph-dunr, smoothness-flight2, smoothness-dunr, preprocessing-dunr, budget-raw-flight2, radial-generated, growth-raw-flight2, growth-view-flight2, time-blend-generated, emission-rate-flight2, emission-rate-dunr, ttq-dunr, ttq-flight2, state-generated, grow-small-flight2, grow-small-dunr}
OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"
export PATH=/tmp/site/bin:$PATH PYTHONUNBUFFERED=1

camera_model() {  # none, radial or map8: the --set values of that camera model, fitted whatever the capture's content
  # motion, as the plans before ab57046 ran them (wild-thermal's default since: the map where the content moves
  # enough, so each variant is spelled out whole)
  local fitted="pipeline.model.camera_falloff=True pipeline.model.camera_pattern_min_motion=0.0"
  case $1 in
    none) echo "pipeline.model.camera_falloff=False pipeline.model.camera_flat_field=0" ;;
    radial) echo "$fitted pipeline.model.camera_flat_field=0" ;;
    map8) echo "$fitted pipeline.model.camera_flat_field=8" ;;
  esac
}

one_at_a_time() {  # SCENE PREFIX SETTING...: the full method with its defaults and with each setting alone on
  # .data/SCENE, 3 seeds each, every run side by side, the first 15,000 steps of the 30k schedule asked, the automatic
  # stop on; each bench's results to $OUT/PREFIX-NAME.json, NAME the setting's name (`default`: the defaults)
  local scene=$1 prefix=$2 setting name names=()
  shift 2
  for setting in default "$@"; do
    set_args=(); [ "$setting" != default ] && set_args=(--set "$setting")
    name=${setting%%=*}; name=${name##*.}; names+=("$name")
    PYTHONPATH=$PWD:/tmp/site timeout 560 python3 -m experiments.bench --output-dir "/tmp/$prefix-$name" \
      --scenes "$PWD/.data/$scene" --cache-dir "$PWD/.data/cache" --methods wild-thermal --seeds 3 --runs-per-gpu 3 \
      --fit-steps 20 --fps-frames 0 --steps 15000 --schedule 30000 --eval-at 5000 15000 "${set_args[@]}" \
      > "$OUT/$prefix-$name.log" 2>&1 &
  done
  wait
  for name in "${names[@]}"; do cp "/tmp/$prefix-$name/bench.json" "$OUT/$prefix-$name.json"; done
}

case "$plan" in
  install)  # the bundle, as every device script installs it
    bash experiments/gpu_2026-11-26.sh install
    ;;
  lut-blend-flight2|lut-blend-dunr)
    scene=${plan#lut-blend-}
    PYTHONPATH=$PWD:/tmp/site timeout 400 python3 -m experiments.bench --output-dir "/tmp/$scene" \
      --scenes "$PWD/.data/$scene" --cache-dir "$PWD/.data/cache" --methods wild-thermal --seeds 3 --runs-per-gpu 3 \
      --fit-steps 20 --fps-frames 0 --steps 15000 --schedule 30000 --eval-at 2000 5000 10000 15000 \
      > "$OUT/$scene-bench.log" 2>&1 || tail -5 "$OUT/$scene-bench.log"
    cp "/tmp/$scene/bench.json" "$OUT/$scene-bench.json"; cp "/tmp/$scene/bench.md" "$OUT/$scene-bench.md"
    for config in $(python3 -c "import json; [print(r['config']) for r in json.load(open('/tmp/$scene/bench.json'))['runs']]"); do
      for code in after before; do
        tree=$PWD; [ "$code" = before ] && tree=$PWD/.baseline
        scores=$(cd "$tree" && PYTHONPATH=$tree:/tmp/site timeout 100 python3 -m experiments.score_checkpoint "$config" \
          --protocols time 2>/dev/null | tail -1)
        echo "{\"code\": \"$code\", \"config\": \"$config\", \"scores\": ${scores:-null}}" | tee -a "$OUT/$scene-time.jsonl"
      done
    done
    ;;
  schedule-dunr)  # issue 34: where a default DUNR run's seconds go (experiments.schedule_profile), seeds 0-2 one after another
    for seed in 0 1 2; do
      PYTHONPATH=$PWD:/tmp/site timeout 180 python3 -m experiments.schedule_profile --scene "$PWD/.data/dunr" \
        --cache-dir "$PWD/.data/cache" --seed $seed --output-dir "/tmp/schedule/seed$seed" > "$OUT/schedule-seed$seed.log" 2>&1
      cp "/tmp/schedule/seed$seed/schedule.json" "$OUT/schedule-seed$seed.json"
      sed -n '/^# /,$p' "$OUT/schedule-seed$seed.log" | head -12
    done
    ;;
  step-guard-dunr)  # issue 34: the first 3,000 steps with and without the divergence guard (its host sync per step)
    for seed in 0 1 2; do
      for guard in True False; do
        PYTHONPATH=$PWD:/tmp/site timeout 100 python3 -m experiments.schedule_profile --scene "$PWD/.data/dunr" \
          --cache-dir "$PWD/.data/cache" --seed $seed --steps 3000 --set guard.enabled=$guard \
          --output-dir "/tmp/guard/$guard-seed$seed" > "$OUT/guard-$guard-seed$seed.log" 2>&1
        cp "/tmp/guard/$guard-seed$seed/schedule.json" "$OUT/guard-$guard-seed$seed.json"
        grep "ms/step" "$OUT/guard-$guard-seed$seed.log"
      done
    done
    ;;
  falloff-flight2|falloff-dunr)  # issue 33: the camera's fall-off fitted (camera_falloff) or not, 3 seeds each,
    # both benches at once on the GPU (6 runs side by side: their timings are shared, their scores are not)
    scene=${plan#falloff-}
    for falloff in False True; do
      PYTHONPATH=$PWD:/tmp/site timeout 520 python3 -m experiments.bench --output-dir "/tmp/falloff-$falloff" \
        --scenes "$PWD/.data/$scene" --cache-dir "$PWD/.data/cache" --methods wild-thermal --seeds 3 --runs-per-gpu 3 \
        --fit-steps 20 --fps-frames 0 --steps 15000 --schedule 30000 --eval-at 5000 15000 \
        --set $(camera_model $([ $falloff = True ] && echo radial || echo none)) > "$OUT/$scene-falloff-$falloff.log" 2>&1 &
    done
    wait
    for falloff in False True; do
      cp "/tmp/falloff-$falloff/bench.json" "$OUT/$scene-falloff-$falloff.json"
      grep -A3 "^PSNR / SSIM, \`\(novel\|time\|aligned\)\`" "/tmp/falloff-$falloff/bench.md" | grep wild
    done
    ;;
  trial-vignetting)  # issue 33: the view-term rule on the vignetting scene (where it kept the term wrongly,
    # docs/results/view_trial_gpu) with the camera's fall-off fitted, 3 seeds; the synthetic protocol of
    # gpu_2026-11-26.sh trial-synthetic
    PYTHONPATH=$PWD:/tmp/site timeout 560 python3 -m experiments.bench --output-dir /tmp/trial-vignetting \
      --scenes stress:vignetting --methods wild-thermal --seeds 3 --runs-per-gpu 3 --steps 5000 --num-downscales 1 \
      --eval-at 1000 2000 5000 --fps-frames 0 --fit-steps 20 \
      --set pipeline.model.view_sh_degree=2 auto_stop.decide_view_term=True $(camera_model radial) \
      > "$OUT/trial-vignetting.log" 2>&1
    cp /tmp/trial-vignetting/bench.json "$OUT/trial-vignetting-bench.json"
    cp /tmp/trial-vignetting/bench.md "$OUT/trial-vignetting-bench.md"
    ;;
  log-writes-dunr|guard-device-dunr)  # issue 34: the first 3,000 steps of a default DUNR run, the code before
    # (.baseline) and after, in turn, seeds 0-2 (experiments.schedule_profile): the per-step timing scalars thinned to
    # the log steps (.baseline: 5e1816a), the divergence guard's verdict on the device (.baseline: 7b2b9b9)
    root=$PWD
    for seed in 0 1 2; do
      for code in before after; do
        tree=$root; [ "$code" = before ] && tree=$root/.baseline
        (cd "$tree" && PYTHONPATH=$tree:/tmp/site timeout 100 python3 -m experiments.schedule_profile --scene "$root/.data/dunr" \
          --cache-dir "$root/.data/cache" --seed $seed --steps 3000 --output-dir "/tmp/logw/$code-seed$seed" \
          > "/tmp/logw-$code-seed$seed.log" 2>&1)
        python3 -c "import json, sys; d = json.load(open(sys.argv[1])); d.pop('windows'); d['code'] = sys.argv[2]; print(json.dumps(d))" \
          "/tmp/logw/$code-seed$seed/schedule.json" $code | tee -a "$OUT/$plan.jsonl" | cut -c1-200
      done
    done
    ;;
  falloff-vignetting)  # issue 33: the vignetting scene without the view term, with the camera's fall-off fitted or not,
    # 3 seeds each, both side by side (the trial-vignetting plan's protocol)
    for falloff in False True; do
      PYTHONPATH=$PWD:/tmp/site timeout 560 python3 -m experiments.bench --output-dir "/tmp/vignetting-$falloff" \
        --scenes stress:vignetting --methods wild-thermal --seeds 3 --runs-per-gpu 3 --steps 5000 --num-downscales 1 \
        --eval-at 1000 2000 5000 --fps-frames 0 --fit-steps 20 --set $(camera_model $([ $falloff = True ] && echo radial || echo none)) \
        > "$OUT/vignetting-falloff-$falloff.log" 2>&1 &
    done
    wait
    for falloff in False True; do cp "/tmp/vignetting-$falloff/bench.json" "$OUT/vignetting-falloff-$falloff.json"; done
    ;;
  flat-field-flight2|flat-field-dunr)  # issue 33: no camera model, the radial fall-off, the fall-off and an 8x8 flat-field
    # map, 3 seeds each, all nine runs side by side (their timings are shared, their scores are not)
    scene=${plan#flat-field-}
    for variant in none radial map8; do
      set_args=$(camera_model $variant)
      PYTHONPATH=$PWD:/tmp/site timeout 580 python3 -m experiments.bench --output-dir "/tmp/ff-$variant" \
        --scenes "$PWD/.data/$scene" --cache-dir "$PWD/.data/cache" --methods wild-thermal --seeds 3 --runs-per-gpu 3 \
        --fit-steps 20 --fps-frames 0 --steps 15000 --schedule 30000 --eval-at 5000 15000 \
        --set $set_args > "$OUT/$scene-$variant.log" 2>&1 &
    done
    wait
    for variant in none radial map8; do
      cp "/tmp/ff-$variant/bench.json" "$OUT/$scene-$variant.json"
      grep -A3 "^PSNR / SSIM, \`\(novel\|time\|aligned\)\`" "/tmp/ff-$variant/bench.md" | grep wild
    done
    ;;
  flat-field-generated)  # issue 33: the generated scenes without a camera model and with the fall-off and an 8x8
    # flat-field map, 3 seeds each (the protocol of gpu_2026-11-24.sh generated), both benches side by side
    for variant in none map8; do
      set_args=$(camera_model $variant)
      PYTHONPATH=$PWD:/tmp/site timeout 550 python3 -m experiments.bench --output-dir "/tmp/gen-$variant" \
        --scenes demo stress:clean stress:drift stress:ffc stress:outlier --methods wild-thermal --seeds 3 \
        --steps 5000 --num-downscales 1 --eval-at 1000 2000 5000 --fps-frames 0 --fit-steps 20 --runs-per-gpu 5 \
        --set $set_args > "$OUT/generated-$variant.log" 2>&1 &
    done
    wait
    for variant in none map8; do cp "/tmp/gen-$variant/bench.json" "$OUT/generated-$variant.json"; done
    ;;
  flat-field-decay)  # issue 33: the 8x8 flat-field map with its cells decayed towards a flat field (Adam's L2 weight
    # decay, 0.1 and 1.0): flight2 and the two generated scenes where the plain map cost `aligned` most, 3 seeds each,
    # the four benches side by side (18 runs; timings shared)
    for decay in 0.1 1.0; do
      map="$(camera_model map8) optimizers.camera_flat_field.optimizer.weight_decay=$decay"
      PYTHONPATH=$PWD:/tmp/site timeout 470 python3 -m experiments.bench --output-dir "/tmp/decay-flight2-$decay" \
        --scenes "$PWD/.data/flight2" --cache-dir "$PWD/.data/cache" --methods wild-thermal --seeds 3 --runs-per-gpu 3 \
        --fit-steps 20 --fps-frames 0 --steps 15000 --schedule 30000 --eval-at 5000 15000 \
        --set $map > "$OUT/decay-flight2-$decay.log" 2>&1 &
      PYTHONPATH=$PWD:/tmp/site timeout 470 python3 -m experiments.bench --output-dir "/tmp/decay-generated-$decay" \
        --scenes stress:clean stress:drift --methods wild-thermal --seeds 3 --steps 5000 --num-downscales 1 \
        --eval-at 1000 2000 5000 --fps-frames 0 --fit-steps 20 --runs-per-gpu 6 \
        --set $map > "$OUT/decay-generated-$decay.log" 2>&1 &
    done
    wait
    for decay in 0.1 1.0; do
      for part in flight2 generated; do cp "/tmp/decay-$part-$decay/bench.json" "$OUT/decay-$part-$decay.json"; done
    done
    ;;
  canonical-flight2|canonical-dunr)  # issue 33: the canonical state (inference_embedding) mean against typical on a
    # real capture: the full method's defaults, 3 seeds side by side, each final checkpoint's novel views scored at both
    scene=${plan#canonical-}
    PYTHONPATH=$PWD:/tmp/site timeout 420 python3 -m experiments.bench --output-dir /tmp/canonical \
      --scenes "$PWD/.data/$scene" --cache-dir "$PWD/.data/cache" --methods wild-thermal --seeds 3 --runs-per-gpu 3 \
      --fit-steps 20 --fps-frames 0 --steps 15000 --schedule 30000 --eval-at 5000 15000 > "$OUT/canonical-bench.log" 2>&1
    cp /tmp/canonical/bench.json "$OUT/canonical-bench.json"
    for config in $(python3 -c "import json; [print(r['config']) for r in json.load(open('/tmp/canonical/bench.json'))['runs']]"); do
      for state in mean typical; do
        scores=$(PYTHONPATH=$PWD:/tmp/site timeout 100 python3 -m experiments.score_checkpoint "$config" \
          --protocols novel aligned --canonical $state 2>/dev/null | tail -1)
        echo "{\"canonical\": \"$state\", \"config\": \"$config\", \"scores\": ${scores:-null}}" | tee -a "$OUT/canonical.jsonl"
      done
    done
    ;;
  parts-flight2|parts-dunr)  # issue 33: the full method's parts one at a time on a real capture: no background MLP,
    # plain SSIM, no alpha regulariser, and the defaults, 3 seeds each, side by side (12 runs; timings shared)
    one_at_a_time ${plan#parts-} parts pipeline.model.use_background_mlp=False pipeline.model.heat_aware_ssim=False \
      pipeline.model.alpha_lambda=0.0
    ;;
  defaults-flight2)  # issue 33: the defaults so far chosen on DUNR alone, each changed on flight2: no preprocessing
    # (flight2's contrast spread turns it on), the loss in the frames' original levels, the emission clamped at zero;
    # and the defaults, 3 seeds each, side by side (12 runs; timings shared)
    one_at_a_time flight2 defaults pipeline.datamanager.preprocessing.variant=none pipeline.model.loss_space=original \
      pipeline.model.nonnegative_emission=True
    ;;
  growth-camera-flight2)  # issue 33's growth question with the camera model: does a fixed sensor pattern left to the
    # Gaussians make the model worse as it grows? The full method (its default camera model on flight2) and the 3DGS
    # variant given the same camera model, at a 1M budget, the first 10k steps of the 30k schedule, no stop (the
    # growth-* plans of gpu_2026-11-26.sh, whose rows are without it), 3 seeds each, the two benches side by side
    camera=$(camera_model map8)  # flight2's content motion turns it on under the default rule as well
    for method in wild-thermal wild-thermal-3dgs; do
      PYTHONPATH=$PWD:/tmp/site timeout 570 python3 -m experiments.bench --output-dir "/tmp/growth-$method" \
        --scenes "$PWD/.data/flight2" --cache-dir "$PWD/.data/cache" --methods $method --seeds 3 --runs-per-gpu 3 \
        --fit-steps 20 --fps-frames 0 --max-gaussians 1000000 --steps 10000 --schedule 30000 --eval-at 2000 5000 10000 \
        --no-auto-stop --set $camera > "$OUT/growth-$method.log" 2>&1 &
    done
    wait
    for method in wild-thermal wild-thermal-3dgs; do
      tag=${method#wild-thermal}; cp "/tmp/growth-$method/bench.json" "$OUT/flight2-1m${tag}-camera-bench.json"
    done
    ;;
  splatfacto-30k-flight2|splatfacto-30k-dunr)  # issue 33's table: stock splatfacto's whole 30k schedule, 3 seeds, on
    # a machine with two GPUs (two runs on the first, one on the second); a run still training at 480 s is recorded
    # as failed with its step, leaving its scoring time inside the call's 600 s (else the bench is killed unwritten)
    scene=${plan#splatfacto-30k-}
    PYTHONPATH=$PWD:/tmp/site timeout 580 python3 -m experiments.bench --output-dir /tmp/splatfacto \
      --scenes "$PWD/.data/$scene" --cache-dir "$PWD/.data/cache" --methods splatfacto --seeds 3 --gpus 2 \
      --runs-per-gpu 2 --fit-steps 20 --fps-frames 0 --steps 30000 --eval-at 5000 10000 20000 30000 \
      --time-limit 480 > "$OUT/$scene-splatfacto-30k.log" 2>&1
    cp /tmp/splatfacto/bench.json "$OUT/$scene-splatfacto-30k.json"
    grep -A3 "^PSNR / SSIM, \`\(novel\|aligned\)\`" /tmp/splatfacto/bench.md | grep splatfacto
    ;;
  ablations-flight2|ablations-dunr)  # issue 33's table: the full method's ablations (the paper's rows, no camera
    # model) with their defaults, 3 seeds each, every run side by side (9 runs; timings shared); the full method's own
    # rows are parts-* `default`
    scene=${plan#ablations-}
    PYTHONPATH=$PWD:/tmp/site timeout 570 python3 -m experiments.bench --output-dir /tmp/ablations \
      --scenes "$PWD/.data/$scene" --cache-dir "$PWD/.data/cache" --seeds 3 --runs-per-gpu 9 \
      --methods wild-thermal-emission-mlp wild-thermal-3dgs wild-thermal-3dgs-stab-bbhe \
      --fit-steps 20 --fps-frames 0 --steps 15000 --schedule 30000 --eval-at 5000 15000 > "$OUT/$scene-ablations.log" 2>&1
    cp /tmp/ablations/bench.json "$OUT/$scene-ablations.json"
    ;;
  view-camera-flight2|view-camera-dunr)  # issue 33: does a capture still gain from a view term once the camera's
    # fixed pattern is modelled? (Before the camera model flight2 gained from it, and on the vignetting scene the
    # term mimicked the camera's fall-off.) The defaults (camera model on for both captures) and a degree-2 view
    # term, 3 seeds each, side by side
    one_at_a_time ${plan#view-camera-} view pipeline.model.view_sh_degree=2
    ;;
  preprocessing-dunr)  # issue 33: flight2 gained 2.7 dB `novel` and 1.6 `aligned` without preprocessing (defaults-flight2),
    # where the rule turns it on; DUNR, the other capture the rule turns it on for, with today's defaults (the camera
    # model on), without preprocessing, and with state_smoothness 0.1, 3 seeds each, side by side (9 runs)
    one_at_a_time dunr preprocessing pipeline.datamanager.preprocessing.variant=none pipeline.model.state_smoothness=0.1
    ;;
  budget-raw-flight2)  # issue 33: the Gaussian budget on flight2 without preprocessing (what preprocessing-dunr and
    # defaults-flight2 point to): grow_budget and a 300k cap, 3 seeds each, side by side (6 runs; the 100k defaults
    # without preprocessing are defaults-flight2's `variant` runs); results to $OUT/budget-raw-NAME.json
    for setting in auto_stop.grow_budget=True pipeline.model.max_gaussians=300000; do
      name=${setting%%=*}; name=${name##*.}
      PYTHONPATH=$PWD:/tmp/site timeout 560 python3 -m experiments.bench --output-dir "/tmp/budget-raw-$name" \
        --scenes "$PWD/.data/flight2" --cache-dir "$PWD/.data/cache" --methods wild-thermal --seeds 3 --runs-per-gpu 3 \
        --fit-steps 20 --fps-frames 0 --steps 15000 --schedule 30000 --eval-at 5000 15000 \
        --set pipeline.datamanager.preprocessing.variant=none "$setting" > "$OUT/budget-raw-$name.log" 2>&1 &
    done
    wait
    for name in grow_budget max_gaussians; do cp "/tmp/budget-raw-$name/bench.json" "$OUT/budget-raw-$name.json"; done
    ;;
  growth-raw-flight2)  # issue 33's growth item with today's defaults (raw frames, the camera model by the motion
    # rule): the full method and the 3DGS variant (given the full method's camera model, as growth-camera-flight2)
    # with a 1M budget and the automatic stop on, so each run records its held-back score at every check along its
    # growth; 3 seeds each, side by side (6 runs); a run still training at 470 s is recorded as failed
    for method in wild-thermal wild-thermal-3dgs; do
      extra=(); [ $method = wild-thermal-3dgs ] && extra=(--set $(camera_model map8))
      PYTHONPATH=$PWD:/tmp/site timeout 570 python3 -m experiments.bench --output-dir "/tmp/growth-raw-$method" \
        --scenes "$PWD/.data/flight2" --cache-dir "$PWD/.data/cache" --methods $method --seeds 3 --runs-per-gpu 3 \
        --fit-steps 20 --fps-frames 0 --steps 15000 --schedule 30000 --eval-at 2000 5000 10000 15000 \
        --max-gaussians 1000000 --time-limit 470 "${extra[@]}" > "$OUT/growth-raw-$method.log" 2>&1 &
    done
    wait
    for method in wild-thermal wild-thermal-3dgs; do cp "/tmp/growth-raw-$method/bench.json" "$OUT/growth-raw-$method.json"; done
    ;;
  grow-small-flight2|grow-small-dunr)  # issue 33's "budget the scene sets": on the generated scenes a 10k cap beat
    # what the 100k default lets them grow to (docs/results/state_generated_h100); grow_budget started at 100k only
    # ever raised it (docs/results/grow_budget, the rule before 2026-11-28). The defaults and a start at 12,500 that
    # doubles where the held-back frames plateau at it, while each raise still brings a new best (up to 1M), 3 seeds
    # each, side by side (6 runs), the stop on; results to $OUT/grow-small-NAME.json
    scene=${plan#grow-small-}
    for name in default grow; do
      # `default` is the fixed 100k, as the defaults were when this ran (the held-back frames set the budget since)
      set_args=(--set auto_stop.grow_budget=False)
      [ $name = grow ] && set_args=(--max-gaussians 12500 --set auto_stop.grow_budget=True)
      PYTHONPATH=$PWD:/tmp/site timeout 570 python3 -m experiments.bench --output-dir "/tmp/grow-small-$name" \
        --scenes "$PWD/.data/$scene" --cache-dir "$PWD/.data/cache" --methods wild-thermal --seeds 3 --runs-per-gpu 3 \
        --fit-steps 20 --fps-frames 0 --steps 15000 --schedule 30000 --eval-at 2000 5000 10000 15000 "${set_args[@]}" \
        > "$OUT/grow-small-$name.log" 2>&1 &
    done
    wait
    for name in default grow; do cp "/tmp/grow-small-$name/bench.json" "$OUT/grow-small-$name.json"; done
    ;;
  growth-view-flight2)  # issue 33's growth item: the full method with raw frames fell 0.79 dB `novel` from 100k to
    # ~350k Gaussians (growth-raw-flight2); before the camera model the view term held it as it grew. The same
    # 1M runs with view_sh_degree=2, and the 100k default with it, 3 seeds each, side by side (6 runs), the stop on
    for budget in 100000 1000000; do
      PYTHONPATH=$PWD:/tmp/site timeout 570 python3 -m experiments.bench --output-dir "/tmp/growth-view-$budget" \
        --scenes "$PWD/.data/flight2" --cache-dir "$PWD/.data/cache" --methods wild-thermal --seeds 3 --runs-per-gpu 3 \
        --fit-steps 20 --fps-frames 0 --steps 15000 --schedule 30000 --eval-at 2000 5000 10000 15000 \
        --max-gaussians $budget --time-limit 470 --set pipeline.model.view_sh_degree=2 \
        > "$OUT/growth-view-$budget.log" 2>&1 &
    done
    wait
    for budget in 100000 1000000; do cp "/tmp/growth-view-$budget/bench.json" "$OUT/growth-view-$budget.json"; done
    ;;
  time-blend-generated)  # issue 33's moonshot: on the flat-field scene (generated_h200, radial_generated_h200) one
    # held-out frame on a linear ramp of the sensor's offset (frame 16, neighbours 15 and 17) scores 27-34 dB `time`
    # against 39.5 `oracle`; a CPU run (800 steps) showed neither that nor a difference. The full method with its
    # defaults on the flat-field and drift scenes (issue 16's protocol, 3 seeds, 6 runs side by side), then every
    # run's `time` scored with blended embeddings and with blended renders (experiments.time_blend); needs .devicebundle
    source .devicebundle/setup.sh > "$OUT/bundle_setup.log" 2>&1
    PYTHONPATH=$PWD:/tmp/site timeout 400 python3 -m experiments.bench --output-dir /tmp/time-blend \
      --scenes stress:ffc stress:drift --methods wild-thermal --seeds 3 --steps 5000 --num-downscales 1 \
      --eval-at 500 1000 2000 5000 --fps-frames 0 --runs-per-gpu 6 > "$OUT/time-blend-bench.log" 2>&1
    cp /tmp/time-blend/bench.json "$OUT/time-blend-bench.json"
    configs=$(python3 -c "import json; [print(r['config']) for r in json.load(open('/tmp/time-blend/bench.json'))['runs']]")
    PYTHONPATH=$PWD:/tmp/site timeout 170 python3 -m experiments.time_blend $configs --output "$OUT/time-blend.json"
    ;;
  emission-rate-flight2|emission-rate-dunr)  # issue 33: the emission's learning rate (3DGS's colour rate times the DC
    # term's 0.2821, chosen on the generated scenes: docs/results/full_settings_gpu) is the one accuracy default cited
    # on no real capture; the defaults and 3DGS's own rate (2.5e-3), 3 seeds each, side by side (6 runs)
    one_at_a_time ${plan#emission-rate-} emission-rate optimizers.emission.optimizer.lr=0.0025
    ;;
  ttq-dunr|ttq-flight2)  # issue 34's time to quality: the full method (its default schedule, the stop on) and stock
    # splatfacto (its whole 30k schedule) in one bench run, one run at a time on each of two GPUs (clean timings:
    # nvidia-h100-x2), seeds SEED and SEED+1 (default 0; a second call for seed 2: SEED=2 SEEDS=1 GPUS=2, each method
    # alone on one GPU);
    # the bench's chart marks where each method first reaches splatfacto's final score
    scene=${plan#ttq-}
    PYTHONPATH=$PWD:/tmp/site timeout 585 python3 -m experiments.bench --output-dir "/tmp/ttq-$scene" \
      --scenes "$PWD/.data/$scene" --cache-dir "$PWD/.data/cache" --methods wild-thermal splatfacto \
      --seeds ${SEEDS:-2} --seed ${SEED:-0} --gpus ${GPUS:-2} --runs-per-gpu 1 --fit-steps 20 --fps-frames 0 \
      --steps 30000 --eval-at 1000 2000 5000 10000 20000 30000 --time-limit 500 > "$OUT/ttq-$scene.log" 2>&1
    for f in bench.json bench.md speed_accuracy.png; do cp "/tmp/ttq-$scene/$f" "$OUT/ttq-$scene-seed${SEED:-0}-$f"; done
    ;;
  radial-generated)  # issue 33: the generated scenes with the radial fall-off forced on and no map (the motion rule
    # turns the whole camera model off on them; docs/results/camera_radial_cpu), 3 seeds, the protocol of
    # gpu_2026-11-24.sh generated (beside docs/results/generated_h200's defaults); needs .devicebundle
    source .devicebundle/setup.sh > "$OUT/bundle_setup.log" 2>&1
    PYTHONPATH=$PWD:/tmp/site timeout 580 python3 -m experiments.bench --output-dir /tmp/radial-generated \
      --scenes demo stress:clean stress:drift stress:ffc stress:outlier stress:vignetting --methods wild-thermal \
      --seeds 3 --steps 5000 --num-downscales 1 --eval-at 500 1000 2000 5000 --fps-frames 0 --runs-per-gpu 9 \
      --set pipeline.model.camera_pattern_min_motion=0.0 pipeline.model.camera_flat_field=0 \
      > "$OUT/radial-generated.log" 2>&1
    cp /tmp/radial-generated/bench.json "$OUT/radial-generated-bench.json"
    cp /tmp/radial-generated/bench.md "$OUT/radial-generated-bench.md"
    ;;
  gpu-tests)  # the tests that skip without CUDA: gsplat against the torch rasterizer, the CUDA graphs of the render,
    # loss, background and emission, fused Adam's rejected step on the GPU (the divergence guard's device verdict)
    PYTHONPATH=$PWD:/tmp/site timeout 300 python3 -m pytest -q -p no:cacheprovider -rs tests/test_gpu_parity.py \
      "tests/test_upstream.py::test_fused_adam_step_is_adams_step" > "$OUT/gpu_tests.log" 2>&1
    tail -3 "$OUT/gpu_tests.log"
    ;;
  camera-cost-dunr)  # issue 34: what the camera model (the fall-off and the 8x8 map DUNR's content motion turns on)
    # costs a step: the first 3,000 steps of a default DUNR run with it and without it, in turn, seeds 0-2
    # (CAMERAS=off: the runs without it alone)
    for seed in 0 1 2; do
      for camera in ${CAMERAS:-on off}; do
        set_args=(); [ $camera = off ] && set_args=(--set $(camera_model none))
        PYTHONPATH=$PWD:/tmp/site timeout 100 python3 -m experiments.schedule_profile --scene "$PWD/.data/dunr" \
          --cache-dir "$PWD/.data/cache" --seed $seed --steps 3000 "${set_args[@]}" --output-dir "/tmp/camera/$camera-seed$seed" \
          > "/tmp/camera-$camera-seed$seed.log" 2>&1
        python3 -c "import json, sys; d = json.load(open(sys.argv[1])); d.pop('windows'); d['camera'] = sys.argv[2]; print(json.dumps(d))" \
          "/tmp/camera/$camera-seed$seed/schedule.json" $camera | tee -a "$OUT/$plan.jsonl" | cut -c1-200
      done
    done
    ;;
  survey-camera)  # issue 33: does the camera model take scene content on a capture the rule turns it on for? The
    # synthetic drone survey (48 frames; content motion above the rule's threshold; radial vignetting and drift; its
    # held-out frames clean, without either) with no camera model, the radial fall-off, and the fall-off and an 8x8
    # map (the default there), 3 seeds each, the three benches side by side (9 runs; timings shared; VARIANTS=none:
    # that one alone)
    for variant in ${VARIANTS:-none radial map8}; do
      set_args=$(camera_model $variant)
      PYTHONPATH=$PWD:/tmp/site timeout 560 python3 -m experiments.bench --output-dir "/tmp/survey-$variant" \
        --scenes survey:48 --methods wild-thermal --seeds 3 --runs-per-gpu 3 --steps 5000 \
        --eval-at 1000 2000 5000 --fps-frames 0 --fit-steps 20 --set $set_args > "$OUT/survey-$variant.log" 2>&1 &
    done
    wait
    for variant in ${VARIANTS:-none radial map8}; do
      cp "/tmp/survey-$variant/bench.json" "$OUT/survey-$variant.json"
      grep -A3 "^PSNR / SSIM, \`\(novel\|time\|aligned\)\`" "/tmp/survey-$variant/bench.md" | grep wild
    done
    ;;
  budget-camera-flight2|budget-camera-dunr)  # issue 33: the Gaussian budget once the camera model is on (with it
    # flight2 no longer loses `novel` as it grows, docs/results/growth): the defaults (100k), the budget the
    # held-back frames raise (auto_stop.grow_budget, up to 1M; before the camera model docs/results/grow_budget),
    # and a fixed 300k, 3 seeds each, side by side (9 runs; timings shared)
    one_at_a_time ${plan#budget-camera-} budget auto_stop.grow_budget=True pipeline.model.max_gaussians=300000
    ;;
  camera-graph-dunr)  # issue 34: the camera model's response replayed as CUDA graphs (graphed_camera, the default)
    # against kernel by kernel: the first 3,000 steps of a default DUNR run each way, in turn, seeds ${SEEDS:-0 1 2}
    for seed in ${SEEDS:-0 1 2}; do
      for graphed in True False; do
        PYTHONPATH=$PWD:/tmp/site timeout 100 python3 -m experiments.schedule_profile --scene "$PWD/.data/dunr" \
          --cache-dir "$PWD/.data/cache" --seed $seed --steps 3000 --set pipeline.model.graphed_camera=$graphed \
          --output-dir "/tmp/camgraph/$graphed-seed$seed" > "/tmp/camgraph-$graphed-seed$seed.log" 2>&1
        python3 -c "import json, sys; d = json.load(open(sys.argv[1])); d.pop('windows'); d['graphed_camera'] = sys.argv[2]; print(json.dumps(d))" \
          "/tmp/camgraph/$graphed-seed$seed/schedule.json" $graphed | tee -a "$OUT/$plan.jsonl" | cut -c1-200
      done
    done
    ;;
  smoothness-flight2|smoothness-dunr)  # issue 33's moonshot (`time` within 1 dB of `oracle`): the frame states kept
    # predictable from their neighbours (state_smoothness 0, the default, 0.1 and 1.0), 3 seeds each, side by side
    # (9 runs; timings shared), one_at_a_time's protocol; results to $OUT/smoothness-WEIGHT.json. WEIGHTS="0.1 1.0"
    # leaves out the defaults' runs where another call of the same session ran them (scores do not depend on the call)
    scene=${plan#smoothness-}
    weights=${WEIGHTS:-0 0.1 1.0}
    for weight in $weights; do
      PYTHONPATH=$PWD:/tmp/site timeout 560 python3 -m experiments.bench --output-dir "/tmp/smoothness-$weight" \
        --scenes "$PWD/.data/$scene" --cache-dir "$PWD/.data/cache" --methods wild-thermal --seeds 3 --runs-per-gpu 3 \
        --fit-steps 20 --fps-frames 0 --steps 15000 --schedule 30000 --eval-at 5000 15000 \
        --set pipeline.model.state_smoothness=$weight > "$OUT/smoothness-$weight.log" 2>&1 &
    done
    wait
    for weight in $weights; do cp "/tmp/smoothness-$weight/bench.json" "$OUT/smoothness-$weight.json"; done
    ;;
  state-generated)  # issue 33's moonshot: the flat-field scene's `time`-`oracle` gap is the predicted state's level
    # (docs/results/state_bound, docs/results/ffc_state_cpu: its neighbours' states are off at the held-out view,
    # differently per seed); on the CPU state_smoothness 0.1 and a 10k Gaussian cap each narrowed it. Every generated
    # scene with each (VARIANT=smoothness or cap; VARIANT=default: neither), 3 seeds, the protocol of radial-generated (GPUS=2: nine runs at a
    # time on each of two GPUs); needs .devicebundle
    source .devicebundle/setup.sh > "$OUT/bundle_setup.log" 2>&1
    variant=${VARIANT:?VARIANT=default, smoothness, cap, grow, grow12500 or fixed}
    set_args=()  # default: the same code's defaults, the baseline of the other two on the same card
    case $variant in
      smoothness) set_args=(--set pipeline.model.state_smoothness=0.1) ;;
      cap) set_args=(--max-gaussians 10000) ;;
      grow) set_args=(--max-gaussians 5000 --set auto_stop.grow_budget=True) ;;  # the held-back frames set the budget
      grow12500) set_args=(--max-gaussians 12500 --set auto_stop.grow_budget=True) ;;  # grow-small's start
      fixed) set_args=(--set auto_stop.grow_budget=False) ;;  # the fixed 100k (`default` until 2026-11-28)
    esac
    PYTHONPATH=$PWD:/tmp/site timeout 580 python3 -m experiments.bench --output-dir "/tmp/state-$variant" \
      --scenes demo stress:clean stress:drift stress:ffc stress:outlier stress:vignetting --methods wild-thermal \
      --seeds 3 --steps 5000 --num-downscales 1 --eval-at 500 1000 2000 5000 --fps-frames 0 --runs-per-gpu 9 \
      --gpus ${GPUS:-1} "${set_args[@]}" > "$OUT/state-$variant.log" 2>&1
    cp "/tmp/state-$variant/bench.json" "$OUT/state-$variant-bench.json"
    cp "/tmp/state-$variant/bench.md" "$OUT/state-$variant-bench.md"
    ;;
  *) echo "unknown plan $plan" >&2; exit 2 ;;
esac
