#!/usr/bin/env bash
# Plans for the GPU, 2026-12-04 (issue 34: the host's floor under a training step). One H200 or H100, each call
# right after the two installs of gpu_2026-11-29.sh on a warm machine (a machine stays warm 30 s):
#     bash experiments/gpu_2026-11-29.sh install          # .devicebundle carried
#     bash experiments/gpu_2026-11-29.sh install-extra    # .data/wheels_extra carried
#     bash experiments/gpu_2026-12-04.sh step-floor dunr
#         # .data/dunr .data/cache/triangulation-c639ec94ec8782da
#     bash experiments/gpu_2026-12-04.sh step-floor flight2
#         # .data/flight2/rjpeg .data/flight2/metashape .data/cache/triangulation-ff4070e3f7030d32
#     rm -rf .baseline && mkdir .baseline && git archive c9217e0 thermal_wild_ns | tar -x -C .baseline
#     bash experiments/gpu_2026-12-04.sh bilinear-ab     # .baseline .data/dunr .data/cache/triangulation-c639ec94ec8782da
# Ran 2026-12-04 (the nineteenth session), one H200: step-floor dunr, step-floor flight2 and WARMUP=7000 step-floor dunr
# on one warm machine (code of c9217e0 plus step_floor.py), then on a fresh one after the installs experiments.profile_step
# at step 7,000 by hand (docs/results/step_floor_h200), then on a third bilinear-ab (docs/results/bilinear_resize_h200).
# A later session (2026-12-04): after the two installs, SEEDS=3 schedule dunr wild-thermal, schedule dunr splatfacto,
# SEEDS=3 schedule flight2 wild-thermal, schedule flight2 splatfacto on one warm machine; a fresh one after the
# installs, ROUNDS=2 profile-stop flight2 (docs/results/default_schedule_h200).
# Ready, not run (no GPU lent to the session of 2026-12-04 that wrote it): fewer host operations per step (the guard's
# verdict, the densification statistics, no empty_cache at refinements; docs/results/step_ops_cpu) against the package
# before them, after the two installs, on one warm machine (the scenes' carries do not fit one call together):
#     rm -rf .baseline && mkdir .baseline && git archive 173dc9e thermal_wild_ns | tar -x -C .baseline
#     ROUNDS=2 bash experiments/gpu_2026-12-04.sh host-ab dunr      # .baseline and DUNR's carry
#     ROUNDS=2 bash experiments/gpu_2026-12-04.sh host-ab flight2   # .baseline and flight2's carry
set -uo pipefail
plan=${1:?plan: step-floor SCENE (dunr or flight2), bilinear-ab, schedule SCENE METHOD..., profile-stop SCENE, host-ab SCENE}
OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"
export PATH=/tmp/site/bin:$PATH PYTHONUNBUFFERED=1
case "$plan" in
  step-floor)  # the full method's step against gsplat's least step on the same Gaussians, cameras and frames
    # (experiments.step_floor), after WARMUP steps, ROUNDS rounds of 500 steps each, alternated
    test -d /tmp/site/tensorly || { echo cold; exit 3; }
    scene=${2:?scene: dunr or flight2}
    PYTHONPATH=$PWD:/tmp/site timeout ${LIMIT:-200} python3 -m experiments.step_floor --scene "$PWD/.data/$scene" \
      --cache-dir "$PWD/.data/cache" --warmup ${WARMUP:-3000} --rounds ${ROUNDS:-3} \
      --output-dir "/tmp/floor-$scene" > "$OUT/step-floor-$scene.log" 2>&1
    cp "/tmp/floor-$scene/step_floor.json" "$OUT/step-floor-$scene.json"
    cp "/tmp/floor-$scene/step_floor.md" "$OUT/step-floor-$scene.md" && cat "$OUT/step-floor-$scene.md"
    tail -n 5 "$OUT/step-floor-$scene.log"
    ;;
  bilinear-ab)  # the flat-field cells and the background grid resized by matrix products (model/bilinear.py) against
    # torch's bilinear interpolation (.baseline: the package before): the GPU parity tests of the resize and of the
    # CUDA graphs that hold it; profile_step on DUNR at step 7,000 (full resolution; 300 timed steps), before and
    # after, alternated over ROUNDS rounds (1); then DUNR's default schedule (30k asked, the stop on), 3 seeds each
    # side, all six runs side by side on the GPU: accuracy only (their seconds share one GPU)
    test -d /tmp/site/tensorly || { echo cold; exit 3; }
    root=$PWD
    PYTHONPATH=$PWD:/tmp/site timeout 150 python3 -m pytest -q -p no:cacheprovider tests/test_gpu_parity.py \
      -k "bilinear or camera_response or background_mlp" > "$OUT/gpu-tests.log" 2>&1
    grep -E "^(E  |FAILED|[0-9]+ (passed|failed))" "$OUT/gpu-tests.log" | head -20
    rm -rf .baseline/experiments && cp -r experiments .baseline/
    for round in $(seq ${ROUNDS:-1}); do
      for arm in before after; do
        dir=$root; [ $arm = before ] && dir=$root/.baseline
        (cd "$dir" && PYTHONPATH=$dir:/tmp/site timeout 150 python3 -m experiments.profile_step --scene "$root/.data/dunr" \
          --cache-dir "$root/.data/cache" --warmup 7000 --steps 300 --profile-steps 10 --python-steps 0 \
          --output-dir "/tmp/profile-$arm-$round" > "/tmp/profile-$arm-$round.log" 2>&1) || tail -5 "/tmp/profile-$arm-$round.log"
        cp "/tmp/profile-$arm-$round/profile.md" "$OUT/profile-$arm-$round.md" && echo "$arm $round: $(grep -m1 'ms/step' "$OUT/profile-$arm-$round.md")"
      done
    done
    for arm in before after; do
      dir=$root; [ $arm = before ] && dir=$root/.baseline
      (cd "$dir" && PYTHONPATH=$dir:/tmp/site timeout ${LIMIT:-330} python3 -m experiments.bench --output-dir "/tmp/bench-$arm" \
        --scenes "$root/.data/dunr" --methods wild-thermal --seeds 3 --seed 0 --fps-frames 0 --runs-per-gpu 3 \
        --cache-dir "$root/.data/cache" > "$OUT/bench-$arm.log" 2>&1; cp "/tmp/bench-$arm/bench.json" "$OUT/bench-$arm.json") &
    done
    wait
    for arm in before after; do tail -n 2 "$OUT/bench-$arm.log"; done
    ;;
  schedule)  # SCENE METHOD...: each method's default schedule (30k steps asked; the full method's automatic stop
    # on), SEEDS seeds from SEED (defaults SEEDS=1, SEED=0), each run alone on the GPU (clean timings), checkpoints
    # scored at the ttq steps; one call per splatfacto seed (its 30k: 258-350 s on H200s); merged with `bench --merge`.
    # STEPS (30000): the steps asked, the schedule's first ones where fewer (the same runs up to there, for a session
    # short of device time); TIME_LIMIT (540): the bench's --time-limit per run
    test -d /tmp/site/tensorly || { echo cold; exit 3; }
    scene=${2:?scene: dunr or flight2}; shift 2
    tag=$scene-$(echo "$*" | tr " " -)-seed${SEED:-0}  # one name, no spaces: a name with one does not come back
    PYTHONPATH=$PWD:/tmp/site timeout ${LIMIT:-585} python3 -m experiments.bench --output-dir "/tmp/schedule-$tag" \
      --scenes "$PWD/.data/$scene" --cache-dir "$PWD/.data/cache" --methods "$@" --seeds ${SEEDS:-1} \
      --seed ${SEED:-0} --runs-per-gpu 1 --fit-steps 20 --fps-frames 0 --steps ${STEPS:-30000} \
      --eval-at 1000 2000 5000 10000 20000 30000 --time-limit ${TIME_LIMIT:-540} > "$OUT/schedule-$tag.log" 2>&1
    cp "/tmp/schedule-$tag/bench.json" "$OUT/schedule-$tag-bench.json"
    python3 -c "import json, sys; [print(r['method'], r.get('seed'), r.get('steps'), r.get('train_seconds'), \
      r.get('ms_per_step'), r.get('gaussians'), r.get('psnr_aligned')) for r in json.load(open(sys.argv[1]))['runs']]" \
      "$OUT/schedule-$tag-bench.json"
    tail -n 3 "$OUT/schedule-$tag.log"
    ;;
  profile-stop)  # SCENE: experiments.profile_step after WARMUP steps (3000) as the bench trains (the automatic
    # stop's held-back frames and the budget they set) and with the stop off (every frame trains, the fixed budget),
    # alternated over ROUNDS rounds (1): where a bench run's step goes that profile_step's usual run does not show
    test -d /tmp/site/tensorly || { echo cold; exit 3; }
    scene=${2:?scene: dunr or flight2}
    for round in $(seq ${ROUNDS:-1}); do
      for arm in stop no-stop; do
        flag=--auto-stop; [ $arm = no-stop ] && flag=--no-auto-stop
        PYTHONPATH=$PWD:/tmp/site timeout ${LIMIT:-150} python3 -m experiments.profile_step --scene "$PWD/.data/$scene" \
          --cache-dir "$PWD/.data/cache" --warmup ${WARMUP:-3000} --steps 300 --profile-steps 10 --python-steps 50 \
          $flag --output-dir "/tmp/profile-$arm-$round" > "/tmp/profile-$arm-$round.log" 2>&1 || tail -5 "/tmp/profile-$arm-$round.log"
        cp "/tmp/profile-$arm-$round/profile.md" "$OUT/profile-$scene-$arm-$round.md" && \
          echo "$arm $round: $(sed -n 1,3p "$OUT/profile-$scene-$arm-$round.md" | tr '\n' ' ')"
      done
    done
    ;;
  host-ab)  # SCENE: experiments.profile_step as the bench trains (--auto-stop) after WARMUP steps (3000), the package
    # before (.baseline) and now, alternated over ROUNDS rounds (1), the now-arm first in odd rounds; the GPU tests of
    # the guard's verdict and of the CUDA graphs first (dunr only)
    test -d /tmp/site/tensorly || { echo cold; exit 3; }
    scene=${2:?scene: dunr or flight2}
    root=$PWD
    if [ "$scene" = dunr ]; then
      PYTHONPATH=$PWD:/tmp/site timeout 200 python3 -m pytest -q -p no:cacheprovider tests/test_gpu_parity.py \
        > "$OUT/gpu-tests.log" 2>&1
      grep -E "^(E  |FAILED|[0-9]+ (passed|failed))" "$OUT/gpu-tests.log" | head -20
    fi
    rm -rf .baseline/experiments && cp -r experiments .baseline/
    for round in $(seq ${ROUNDS:-1}); do
      arms="after before"; [ $((round % 2)) = 0 ] && arms="before after"
      for arm in $arms; do
        dir=$root; [ $arm = before ] && dir=$root/.baseline
        (cd "$dir" && PYTHONPATH=$dir:/tmp/site timeout ${LIMIT:-150} python3 -m experiments.profile_step \
          --scene "$root/.data/$scene" --cache-dir "$root/.data/cache" --warmup ${WARMUP:-3000} --steps 500 \
          --profile-steps 10 --python-steps 0 --auto-stop --output-dir "/tmp/host-$arm-$round" \
          > "/tmp/host-$arm-$round.log" 2>&1) || tail -5 "/tmp/host-$arm-$round.log"
        cp "/tmp/host-$arm-$round/profile.md" "$OUT/host-$scene-$arm-$round.md" && \
          echo "$arm $round: $(sed -n 1,4p "$OUT/host-$scene-$arm-$round.md" | tr '\n' ' ')"
      done
    done
    ;;
  *) echo "unknown plan: $plan"; exit 2 ;;
esac
