#!/usr/bin/env bash
# The GPU measurements, one named plan per device call, from the repository root on the GPU machine:
#     bash experiments/gpu_plans.sh PLAN [ARGS]
# The machine is bare: `install` first (with .devicebundle carried: bash ../shared/device/prepare.sh here), then the
# plans on the same warm machine, each call right after the last. The code is the carried tree's (PYTHONPATH), the
# dependencies the bundle's. Real scenes travel in the git-ignored .data/ (.data/dunr, .data/flight2/{rjpeg,metashape})
# with their triangulation caches in .data/cache; a plan's files go to $OUT (8 files at most come back: several go
# into $OUT/PLAN.tgz, rewritten after each stage, so a plan stopped at its limit keeps what it finished).
#
#   install            the bundle (and .data/wheels_extra/*.whl where carried: the GPU tests' extra imports); on a
#                      warm machine without .devicebundle, the carried wheels alone (pycolmap for a survey that is
#                      triangulated, such as flight2: with the bundle it passes the carry limit)
#   tests              every GPU test (tests/test_gpu_parity.py, tests/test_padded_isect.py); with THEN=PLAN, PLAN
#                      after them if they all pass
#   schedule SCENE METHOD...   each method's default schedule (30k steps asked; the full method's automatic stop on),
#                      SEEDS seeds from SEED (1, 0), each run alone on the GPU, checkpoints scored at the
#                      time-to-quality steps; STEPS (30000) the steps asked; TIME_LIMIT (540) per run
#   baselines SCENE    the baselines a nerfstudio user would try, 3 seeds each (SEEDS), RUNS_PER_GPU (3) at once:
#                      splatfacto with its bilateral grid, stock splatfacto (the first STEPS (5000) steps of their
#                      30k schedule, scored at 1,000, 2,000 and 5,000), then the full method's default (30k asked,
#                      its automatic stop); each bench's files as it ends, with 3 held-out views in °C (the first
#                      seed's, on a calibrated capture)
#   ab SCENE SETTING   the full method at its default (30k asked, its automatic stop) and with SETTING (a bench
#                      --set, e.g. pipeline.model.alpha_lambda=0.0), SEEDS (3) seeds each, RUNS_PER_GPU (3) at once,
#                      one bench each: default-bench.json, set-bench.json (merged here by experiments.bench --merge)
#   table SCENE        the scene table from one call: the full method, wild-thermal-paper and every ablation at
#                      their default (30k asked, the automatic stop), then splatfacto over the first STEPS (5000)
#                      steps of its 30k schedule (its best on the real captures), SEEDS (3) seeds each, over every
#                      GPU of the host, RUNS_PER_GPU (3) at once on each (a host of several GPUs keeps it within a
#                      call); then here `python -m experiments.full_vs_ablations` on the two bench.json
#   survey-timing [SURVEY...]  experiments.survey_timing: every phase from a survey folder to the °C map, timed
#                      (default survey:250); one survey per call (survey:1000, survey:4000, metashape:$PWD/.data/flight2
#                      after pycolmap's install), the calls' survey_timing.json tabled here with --merge; a survey
#                      too long for one call over two calls of one warm machine (TIMED_PHASES="setup train", then
#                      "score points orthomosaic"), the earlier call's rows kept in the table; with
#                      PROFILE_SCORE=SECONDS each survey's run scored again (experiments.score_time) for each count
#                      of views a fit's render in FIT_VIEWS ("8"), the first under cProfile
#   score-ab [SURVEY]  the survey (survey:1000) as the survey-timing plan trained it on this machine, else set up and
#                      trained to its automatic stop (experiments.survey_timing --phases setup train), then its
#                      scoring timed (experiments.score_time) by the package before
#                      (.baseline: git archive REV thermal_wild_ns experiments, where carried) and now, for each
#                      count of views a fit's render in FIT_VIEWS ("32"): before.jsonl, after.jsonl
#   trace SCENE        the full method's step at step 3,000 as the bench trains: its profile and timeline
#   renders SCENE      the render ways (as ns-render and the viewer draw) on a model of the scene trained to step
#                      3,400 as the bench trains: 3 rounds of 1,000 frames at 640x512 (experiments.render_fps)
#   host-ab SCENE      the step of the package before (.baseline: git archive REV thermal_wild_ns) and now, as the
#                      bench trains at step WARMUP (3000), alternated over ROUNDS rounds (1)
#   survey-cost [FRAMES...]   one GPU: the Gaussian count a synthetic survey of FRAMES frames (250 1000) holds
#                      (experiments.survey_cost; GAUSSIANS="N ..." the counts tried, GROWTH_STEPS=N)
#   two-vs-one         a 2-GPU host: experiments.multi_gpu_cost on the 1,000-frame survey with one GPU, then two
#   large-two          a 2-GPU host: the 1,000-frame survey trained across both at a count one GPU does not hold,
#                      then scored on one GPU
#   stop-two           a 2-GPU host: the 250-frame survey through the launcher to its automatic stop, scored
#   quality-one|quality-two   a 2-GPU host: the 250-frame survey (FRAMES) trained 2,000 steps on one GPU or across
#                      two, 3 seeds (SEEDS), scored (SCORE=later: train only; then quality-score)
set -uo pipefail
plan=${1:?plan: see the header of experiments/gpu_plans.sh}
shift
OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"
export PATH=/tmp/site/bin:$PATH PYTHONUNBUFFERED=1
root=$PWD
res=/tmp/res-$plan
mkdir -p "$res"
pack() { tar czf "$OUT/$plan.tgz" -C "$res" .; }
warm() { test -d /tmp/site/nerfstudio || { echo "cold machine: run the install plan first"; exit 3; }; }
py() { PYTHONPATH=$root:/tmp/site python3 "$@"; }

profiled() {  # NAME DIR [FLAG...]: experiments.profile_step on SCENE at step WARMUP as the bench trains, the package
  # of DIR; its profile to $res/profile-NAME.md
  local name=$1 dir=$2
  shift 2
  (cd "$dir" && PYTHONPATH=$dir:/tmp/site timeout "${LIMIT:-150}" python3 -m experiments.profile_step \
    --scene "$root/.data/$scene" --cache-dir "$root/.data/cache" --warmup "${WARMUP:-3000}" --steps 400 \
    --profile-steps 10 --python-steps 0 --auto-stop --output-dir "/tmp/profile-$name" "$@" \
    > "/tmp/profile-$name.log" 2>&1) || tail -5 "/tmp/profile-$name.log"
  cp "/tmp/profile-$name/profile.md" "$res/profile-$name.md" && echo "$name: $(sed -n 3,4p "$res/profile-$name.md" | tr '\n' ' ')"
}

synthetic_survey() {  # FRAMES: the synthetic survey of FRAMES frames in /tmp/survey_FRAMES (every core)
  py -c "from pathlib import Path; from thermal_wild_ns.data.survey_scene import *; \
generate_survey_scene(Path('/tmp/survey_$1'), SurveySceneConfig(num_frames=$1))" > "$OUT/generate_$1.log" 2>&1
}

score() {  # RUN GPU: experiments.score_checkpoint on the quality plans' run /tmp/q/RUN, on that GPU
  CUDA_VISIBLE_DEVICES=$2 timeout 500 python3 -m experiments.score_checkpoint "/tmp/q/$1/survey/wild-thermal/run/config.yml" \
    --protocols ${PROTOCOLS:-novel time aligned} 2> "$OUT/score-$1.log" | tail -1 > "$OUT/score-$1.json" && touch "/tmp/q/$1/scored"
}

case "$plan" in
  install)
    if [ -d .devicebundle ] || [ ! -d /tmp/site/nerfstudio ]; then  # a warm machine takes more wheels alone
      source .devicebundle/setup.sh > "$OUT/bundle_setup.log" 2>&1
      tail -2 "$OUT/bundle_setup.log"
    fi
    if ls .data/wheels_extra/*.whl > /dev/null 2>&1; then
      python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site \
        .data/wheels_extra/*.whl 2>&1 | { grep -v WARNING || true; }
    fi
    ;;
  tests)
    warm
    # with them the held-out fits' one pass for several views, through one gsplat rasterization (test_bench)
    py -m pytest -q -p no:cacheprovider tests/test_gpu_parity.py tests/test_padded_isect.py \
      "tests/test_bench.py::test_held_out_fits_of_several_views_in_one_render_end_where_each_would_alone" \
      "tests/test_bench.py::test_several_views_rendered_for_a_fit_in_one_pass_are_each_views_own_render" \
      > "$res/gpu-tests.log" 2>&1
    grep -E "^(E  |FAILED|[0-9]+ (passed|failed))" "$res/gpu-tests.log" | head -30
    pack
    summary=$(grep -E "[0-9]+ (passed|failed)" "$res/gpu-tests.log" | tail -1)
    case "$summary" in *failed*|*error*|"") echo "GPU tests not all passed: nothing else runs"; exit 1 ;; esac
    [ -n "${THEN:-}" ] && OUT=$OUT bash "$0" $THEN
    ;;
  schedule)
    warm
    scene=${1:?scene: dunr or flight2}; shift
    tag=$scene-$(echo "$*" | tr " " -)-seed${SEED:-0}  # one name, no spaces: a name with one does not come back
    py -m experiments.bench --output-dir "/tmp/schedule-$tag" --scenes "$root/.data/$scene" \
      --cache-dir "$root/.data/cache" --methods "$@" --seeds "${SEEDS:-1}" --seed "${SEED:-0}" --runs-per-gpu 1 \
      --fit-steps 20 --fps-frames 0 --steps "${STEPS:-30000}" --eval-at 1000 2000 5000 10000 20000 30000 \
      --time-limit "${TIME_LIMIT:-540}" > "$OUT/schedule-$tag.log" 2>&1
    cp "/tmp/schedule-$tag/bench.json" "$OUT/schedule-$tag-bench.json"
    tail -n 3 "$OUT/schedule-$tag.log"
    ;;
  baselines)
    warm
    scene=${1:?scene: dunr or flight2}
    bench() {  # NAME BENCH-ARGS...: one bench of SEEDS seeds on the scene, its bench.json and log into the results
      local name=$1
      shift
      py -m experiments.bench --output-dir "/tmp/$name" --scenes "$root/.data/$scene" --cache-dir "$root/.data/cache" \
        --seeds "${SEEDS:-3}" --runs-per-gpu "${RUNS_PER_GPU:-3}" --fps-frames 0 --fit-steps 20 "$@" > "$res/$name.log" 2>&1
      cp "/tmp/$name/bench.json" "$res/$name-bench.json" && tail -n 2 "$res/$name.log"
      for log in "/tmp/$name"/gpu*/*/log.txt; do  # each run's own log (its fallbacks and warnings)
        [ -f "$log" ] && cp "$log" "$res/$name-$(basename "$(dirname "$log")").log"
      done
      for panel in "/tmp/$name"/renders/*/*_seed0/test_0[0-2]_celsius.png; do  # 3 held-out views in °C, first seed
        [ -f "$panel" ] && cp "$panel" "$res/$name-$(basename "$panel")"
      done
      pack
    }
    short=(--steps "${STEPS:-5000}" --schedule 30000 --eval-at 1000 2000 5000)
    bench "$scene-bilateral-grid" --methods splatfacto "${short[@]}" --set pipeline.model.use_bilateral_grid=True
    bench "$scene-splatfacto" --methods splatfacto "${short[@]}"
    bench "$scene-wild-thermal" --methods wild-thermal --eval-at 1000 2000 5000 10000 20000 30000
    ;;
  ab)
    warm
    scene=${1:?scene: dunr or flight2}; setting=${2:?setting: path.to.field=value}
    for arm in default set; do
      extra=(); [ "$arm" = set ] && extra=(--set "$setting")
      py -m experiments.bench --output-dir "/tmp/ab-$arm" --scenes "$root/.data/$scene" --cache-dir "$root/.data/cache" \
        --methods wild-thermal --seeds "${SEEDS:-3}" --runs-per-gpu "${RUNS_PER_GPU:-3}" --fps-frames 0 --fit-steps 20 \
        --eval-at 30000 "${extra[@]}" > "$res/$arm.log" 2>&1
      cp "/tmp/ab-$arm/bench.json" "$res/$arm-bench.json" && tail -n 2 "$res/$arm.log"
      pack
    done
    ;;
  table)
    warm
    scene=${1:?scene: dunr, flight2 (from .data), demo or stress:FAULT}
    case "$scene" in demo|stress:*) path=$scene ;; *) path=$root/.data/$scene ;; esac
    name=table-$(echo "$scene" | tr : -)
    table() {  # PART BENCH-ARGS...: one bench of the table over every GPU, its files into the results
      local part=$name-$1
      shift
      py -m experiments.bench --output-dir "/tmp/$part" --scenes "$path" --cache-dir "$root/.data/cache" \
        --seeds "${SEEDS:-3}" --gpus "$(nvidia-smi -L | wc -l)" --runs-per-gpu "${RUNS_PER_GPU:-3}" --fps-frames 0 \
        --fit-steps 20 --time-limit "${TIME_LIMIT:-400}" "$@" > "$res/$part.log" 2>&1
      cp "/tmp/$part/bench.json" "$res/$part-bench.json" && tail -n 2 "$res/$part.log"
      pack
    }
    table methods --methods wild-thermal wild-thermal-paper wild-thermal-3dgs wild-thermal-3dgs-histeq \
      wild-thermal-3dgs-bbhe wild-thermal-3dgs-stab wild-thermal-3dgs-stab-bbhe wild-thermal-emission-mlp
    table splatfacto --methods splatfacto --steps "${STEPS:-5000}" --schedule 30000 --eval-at 1000 2000 5000
    ;;
  survey-timing)
    warm
    surveys=("${@:-survey:250}")
    keep() {  # the table, and each survey's phase logs and scores (eval.json: the held-out views' count)
      cp /tmp/survey-timing/survey_timing.* "$res/" 2>/dev/null
      for f in /tmp/survey-timing/*/*.log /tmp/survey-timing/*/eval.json; do
        [ -f "$f" ] && cp "$f" "$res/$(basename "$(dirname "$f")")-$(basename "$f")"
      done
      pack
    }
    (while sleep 15; do keep; done) &  # the phases so far come back if the call is cut at its limit
    packer=$!
    earlier=()  # a warm machine's earlier call: its rows join these (a survey's phases over two calls: TIMED_PHASES)
    if [ -f /tmp/survey-timing/survey_timing.json ]; then
      cp /tmp/survey-timing/survey_timing.json /tmp/survey-timing-earlier.json
      earlier=(--merge /tmp/survey-timing-earlier.json)
    fi
    py -m experiments.survey_timing --surveys ${surveys[@]} --phases ${TIMED_PHASES:-setup train score points orthomosaic} \
      "${earlier[@]}" --output-dir /tmp/survey-timing > "$res/survey-timing.log" 2>&1
    kill $packer
    keep; tail -n 8 "$res/survey-timing.log"
    if [ -n "${PROFILE_SCORE:-}" ]; then  # where each survey's scoring time goes, within PROFILE_SCORE seconds
      for config in /tmp/survey-timing/*/runs/*/wild-thermal/run/config.yml; do
        counts=(${FIT_VIEWS:-8})
        for views in "${counts[@]}"; do  # the first count profiled, the others timed
          profile=(); [ "$views" = "${counts[0]}" ] && profile=(--profile "$res/score-profile.md")
          PYTHONPATH=$root:/tmp/site timeout "$PROFILE_SCORE" python3 -m experiments.score_time "$config" \
            --fit-views "$views" "${profile[@]}" >> "$res/score-time.jsonl" 2>> "$res/score-time.log"
          pack
        done
      done
      pack; tail -n 1 "$res/score-time.jsonl"
    fi
    ;;
  score-ab)
    warm
    survey=${1:-survey:1000}
    config=$(ls /tmp/survey-timing/"${survey/:/-}"/runs/*/wild-thermal/run/config.yml 2>/dev/null | head -1)
    if [ -z "$config" ]; then  # not trained by an earlier survey-timing plan on this machine
      py -m experiments.survey_timing --surveys "$survey" --phases setup train --output-dir /tmp/score-ab \
        > "$res/survey-timing.log" 2>&1
      config=$(ls /tmp/score-ab/*/runs/*/wild-thermal/run/config.yml | head -1)
    fi
    for views in ${FIT_VIEWS:-32}; do
      for side in before after; do
        tree=$root; [ "$side" = before ] && tree=$root/.baseline
        [ -d "$tree/thermal_wild_ns" ] || continue
        (cd "$tree" && PYTHONPATH=$tree:/tmp/site timeout 150 python3 -m experiments.score_time "$config" \
          --fit-views "$views" >> "$res/$side.jsonl" 2>> "$res/score-ab.log")
        pack
      done
    done
    tail -n 4 "$res"/*.jsonl
    ;;
  trace)
    warm
    scene=${1:?scene: dunr or flight2}
    profiled "$scene" "$root" --trace
    cp "/tmp/profile-$scene/trace.json.gz" "$res/trace-$scene.json.gz"
    py -m experiments.trace_summary "$res/trace-$scene.json.gz" > "$res/trace-$scene.md"
    head -30 "$res/trace-$scene.md"
    pack
    ;;
  renders)
    warm
    scene=${1:?scene: dunr or flight2}
    WARMUP=${WARMUP:-3000} profiled "$scene" "$root"
    config=$(ls /tmp/profile-"$scene"/runs/*/wild-thermal/run/config.yml | head -1)
    for round in 1 2 3; do
      py -m experiments.render_fps --load-config "$config" --frames 1000 --output-dir "/tmp/render-$round" \
        > "/tmp/render-$round.log" 2>&1 || tail -20 "/tmp/render-$round.log"
      python3 -c "import json, sys; r = json.load(open(sys.argv[1])); r['round'] = int(sys.argv[2]); print(json.dumps(r))" \
        "/tmp/render-$round/fps.json" "$round" | tee -a "$res/fps_rounds.jsonl"
    done
    pack
    ;;
  host-ab)
    warm
    scene=${1:?scene: dunr or flight2}
    rm -rf .baseline/experiments && cp -r experiments .baseline/
    for round in $(seq "${ROUNDS:-1}"); do
      arms="now before"; [ $((round % 2)) = 0 ] && arms="before now"
      for arm in $arms; do
        dir=$root; [ "$arm" = before ] && dir=$root/.baseline
        profiled "$arm-$round" "$dir"
        pack
      done
    done
    ;;
  survey-cost)
    warm
    frames=("${@:-250 1000}")
    counts=(${GAUSSIANS:-1000000 4000000 16000000 64000000 128000000 192000000 256000000 320000000 384000000})
    py -m experiments.survey_cost --frames ${frames[@]} --gaussians "${counts[@]}" --growth-steps "${GROWTH_STEPS:-0}" \
      --output-dir /tmp/cost > "$OUT/survey-cost.log" 2>&1
    cp /tmp/cost/cost.json /tmp/cost/cost.md "$OUT/"; tail -25 "$OUT/survey-cost.log"
    ;;
  two-vs-one)
    warm
    synthetic_survey 1000
    mkdir -p /tmp/mgc && ln -sfn /tmp/survey_1000 /tmp/mgc/survey_1000
    # the 2-GPU sweep stops below twice what one GPU held: a rank out of memory would leave the other waiting
    both=(4000000 16000000 64000000 192000000)
    export PYTHONPATH=$root:/tmp/site
    CUDA_VISIBLE_DEVICES=0 timeout 200 torchrun --standalone --nproc-per-node 1 -m experiments.multi_gpu_cost \
      --frames 1000 --gaussians "${both[@]}" 256000000 --output-dir /tmp/mgc > "$OUT/one.log" 2>&1
    timeout 300 torchrun --standalone --nproc-per-node 2 -m experiments.multi_gpu_cost \
      --frames 1000 --gaussians "${both[@]}" 256000000 320000000 384000000 --output-dir /tmp/mgc > "$OUT/two.log" 2>&1
    cp /tmp/mgc/multi_gpu_cost_*.json "$OUT/"; grep -h '^{"gaussians' "$OUT/one.log" "$OUT/two.log"
    ;;
  large-two)
    warm
    synthetic_survey 1000
    mkdir -p /tmp/mgl && ln -sfn /tmp/survey_1000 /tmp/mgl/survey_1000
    mib=$(nvidia-smi --query-gpu=memory.total --format=csv,noheader,nounits | head -1)
    count=192000000; [ "$mib" -gt 100000 ] && count=256000000
    export PYTHONPATH=$root:/tmp/site
    timeout 420 torchrun --standalone --nproc-per-node 2 -m experiments.multi_gpu_cost --frames 1000 \
      --gaussians 4000000 --steps 5 --train-at $count --train-steps 600 --score-every 200 \
      --output-dir /tmp/mgl > "$OUT/large-two.log" 2>&1
    cp /tmp/mgl/multi_gpu_train_2.json "$OUT/"; tail -n 30 "$OUT/large-two.log"
    CUDA_VISIBLE_DEVICES=0 timeout 150 python3 -m experiments.score_checkpoint \
      /tmp/mgl/runs/survey_1000/wild-thermal/cost/config.yml > "$OUT/score-large-one-gpu.json" 2> "$OUT/score-large-one-gpu.log"
    cat "$OUT/score-large-one-gpu.json"
    ;;
  stop-two)
    warm
    synthetic_survey 250
    export PYTHONPATH=$root:/tmp/site
    timeout 450 torchrun --standalone --nproc-per-node 2 -m thermal_wild_ns.multi_gpu wild-thermal \
      --output-dir /tmp/stop --experiment-name survey --timestamp run --pipeline.model.max-gaussians 1000000 \
      --max-num-iterations "${STOP_STEPS:-30000}" --vis tensorboard --pipeline.datamanager.preprocessing-cache /tmp/stop/cache \
      thermal-demo-data --data /tmp/survey_250 --scene survey --survey-frames 250 > "$OUT/stop-two.log" 2>&1
    cp /tmp/stop/survey/wild-thermal/run/auto_stop.json "$OUT/stop-two-auto_stop.json"
    timeout 90 python3 -m experiments.score_checkpoint /tmp/stop/survey/wild-thermal/run/config.yml \
      > "$OUT/score-stop-two.json" 2> "$OUT/score-stop-two.log"
    cat "$OUT/score-stop-two.json"
    ;;
  quality-one|quality-two)
    warm
    frames=${FRAMES:-250}; synthetic_survey "$frames"
    export PYTHONPATH=$root:/tmp/site
    train() {  # GPUS SEED CUDA_VISIBLE_DEVICES
      CUDA_VISIBLE_DEVICES=$3 timeout 240 torchrun --standalone --nproc-per-node "$1" -m thermal_wild_ns.multi_gpu \
        wild-thermal --output-dir "/tmp/q/gpus$1-seed$2" --experiment-name survey --timestamp run \
        --max-num-iterations 2000 --machine.seed "$2" --pipeline.datamanager.train-order-seed "$2" \
        --pipeline.model.max-gaussians 1000000 --pipeline.datamanager.preprocessing-cache /tmp/q/cache \
        thermal-demo-data --data "/tmp/survey_$frames" --scene survey --survey-frames "$frames" > "$OUT/train-gpus$1-seed$2.log" 2>&1
      [ "${SCORE:-}" = later ] || score "gpus$1-seed$2" 0
    }
    if [ "$plan" = quality-one ]; then
      for seed in ${SEEDS:-1 2 3}; do train 1 "$seed" 0; done
    else
      for seed in ${SEEDS:-1 2 3}; do train 2 "$seed" 0,1; done
    fi
    tail -n1 "$OUT"/score-*.json
    ;;
  quality-score)
    warm
    export PYTHONPATH=$root:/tmp/site
    gpu=0; n=0
    for run in /tmp/q/gpus*-seed*; do
      [ -e "$run/scored" ] && continue
      score "$(basename "$run")" $gpu &
      n=$((n + 1)); gpu=$((n % 2))
    done
    wait; tail -n1 "$OUT"/score-*.json
    ;;
  *) echo "unknown plan: $plan (see the header of experiments/gpu_plans.sh)"; exit 2 ;;
esac
