#!/usr/bin/env bash
# Plans for the GPU, 2026-12-03 (issue 34: several cameras per training step). One H200 or H100, each call right
# after the two installs of gpu_2026-11-29.sh on a warm machine (a machine stays warm 30 s):
#     bash experiments/gpu_2026-11-29.sh install          # .devicebundle carried
#     bash experiments/gpu_2026-11-29.sh install-extra    # .data/wheels_extra carried
#     SEED=0 bash experiments/gpu_2026-12-03.sh cameras-per-step dunr
#         # .data/dunr .data/cache/triangulation-c639ec94ec8782da; then SEED=1, SEED=2
#     SEED=0 bash experiments/gpu_2026-12-03.sh cameras-per-step flight2
#         # .data/flight2/rjpeg .data/flight2/metashape .data/cache/triangulation-ff4070e3f7030d32
# 2026-12-03, a second session: cameras-probe-demo after splatfacto-30k-bg on one warm machine (docs/results/
# cameras_probe_h200): it found CUDA graphs replayed across a step's cameras (fixed since); cameras-per-step not run.
# A third session (2026-12-03): gpu-tests and cameras-probe-demo, then LIMIT=180 SEED=0 cameras-per-step dunr, then
# FRAMES=1 CAMERAS=2 LIMIT=125 SEED=0 cameras-per-step dunr (docs/results/cameras_per_step_h200).
# A fourth (2026-12-03, on ad05288): after the installs, in one call, FRAMES=1 CAMERAS="1 2" LIMIT=140 SEED=1 and
# SEED=2 cameras-per-step dunr (docs/results/cameras_per_step_h200). FRAMES is gone since: the schedule counts frames.
# A fifth machine the same session (on 4c64ea4): CAMERAS=2 LIMIT=150 SEED=0 cameras-per-step dunr, the rerun through the
# trainer's frame count (docs/results/cameras_per_step_h200).
# 2026-12-04 (on 77d9eae), after splatfacto-30k-generated on the same warm machine: CAMERAS="1 2" LIMIT=140 SEED=0
# cameras-per-step flight2 (216 s; docs/results/cameras_per_step_h200). The next session (on 2326485), after
# splatfacto-30k-generated's seed-2 call on the same warm machine: the same with SEED=1 (212 s). The next (on d679d7b), right after
# the two installs: SEED=2 (267 s). flight2's three seeds are complete.
set -uo pipefail
plan=${1:?plan: gpu-tests, cameras-per-step SCENE (dunr or flight2), cameras-probe-demo}
OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"
export PATH=/tmp/site/bin:$PATH PYTHONUNBUFFERED=1
case "$plan" in
  gpu-tests)  # the GPU parity tests (CUDA graphs against kernel by kernel, the slots of several cameras per step
    # among them), each failure's first lines and the count to $OUT/gpu-tests.log
    test -d /tmp/site/tensorly || { echo cold; exit 3; }
    PYTHONPATH=$PWD:/tmp/site timeout 180 python3 -m pytest -q -p no:cacheprovider -rs tests/test_gpu_parity.py \
      > "$OUT/gpu-tests.log" 2>&1
    grep -E "^(E  |FAILED|SKIPPED|[0-9]+ (passed|failed))" "$OUT/gpu-tests.log" | head -20
    ;;
  cameras-per-step)  # the full method at the scene table's protocol (the first 15,000 frames of the 30k schedule
    # asked, the stop on) with 1, 2 and 4 training frames per step (CAMERAS), one seed (SEED) per call, each run
    # alone on the GPU one after another (a speed measurement: no run beside it), curve points every 1,000 frames
    # for accuracy against seconds (experiments.bench's speed_time chart after --merge)
    test -d /tmp/site/tensorly || { echo cold; exit 3; }
    scene=${2:?scene: dunr or flight2}
    # the schedule counts training frames since the trainer does (training/schedule.py): B cameras a step train
    # 1/B of the steps; FRAMES=1 did that here by hand before (--steps, --schedule and --eval-at over B)
    for count in ${CAMERAS:-1 2 4}; do
      name=cameras-$scene-b$count-seed${SEED:-0}-frames
      PYTHONPATH=$PWD:/tmp/site timeout ${LIMIT:-190} python3 -m experiments.bench --output-dir "/tmp/$name" \
        --scenes "$PWD/.data/$scene" --methods wild-thermal --seeds 1 --seed "${SEED:-0}" --fps-frames 0 \
        --cache-dir "$PWD/.data/cache" --fit-steps 20 --steps 15000 --schedule 30000 \
        --eval-at 1000 2000 3000 4000 5000 6000 8000 10000 12000 15000 \
        --set pipeline.cameras_per_step=$count > "$OUT/$name.log" 2>&1
      cp "/tmp/$name/bench.json" "$OUT/$name-bench.json" && tail -n 3 "$OUT/$name.log"
    done
    ;;
  cameras-probe-demo)  # a first reading (not run yet: no device time was left 2026-12-03): the training step's ms
    # on the demo scene (no carry) at step 1,500 with 1, 2 and 4 cameras per step (experiments.profile_step, 300 steps timed), each arm's
    # profile to $OUT as soon as it ends
    test -d /tmp/site/tensorly || { echo cold; exit 3; }
    for count in ${CAMERAS:-1 2 4}; do
      PYTHONPATH=$PWD:/tmp/site timeout ${LIMIT:-50} python3 -m experiments.profile_step --scene demo --warmup 1500 \
        --steps 300 --profile-steps 5 --python-steps 5 --output-dir "/tmp/probe-b$count" \
        --set pipeline.cameras_per_step=$count > "$OUT/probe-b$count.log" 2>&1
      cp "/tmp/probe-b$count/profile.md" "$OUT/probe-b$count.md" && echo "b$count: $(grep -m1 'ms/step' "$OUT/probe-b$count.md")"
    done
    ;;
  *) echo "unknown plan $plan"; exit 2 ;;
esac
