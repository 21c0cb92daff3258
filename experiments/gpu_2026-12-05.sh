#!/usr/bin/env bash
# Plans for the GPU, 2026-12-05 (issue 34). One H100 (`nvidia-h100-x1`, the machine its targets name) or H200; each call
# right after the last on one warm machine (a machine stays warm 30 s), after the two installs:
#     bash experiments/gpu_2026-11-29.sh install          # .devicebundle carried
#     bash experiments/gpu_2026-11-29.sh install-extra    # .data/wheels_extra carried
#     rm -rf .baseline && mkdir .baseline && git archive 173dc9e thermal_wild_ns | tar -x -C .baseline
#     bash experiments/gpu_2026-12-05.sh host-dunr        # .baseline .data/dunr .data/cache/triangulation-c639ec94ec8782da
#     bash experiments/gpu_2026-12-05.sh host-flight2     # .baseline .data/flight2/rjpeg .data/flight2/metashape
#                                                         # .data/cache/triangulation-ff4070e3f7030d32
# Each plan's files go into one archive, $OUT/PLAN.tgz, rewritten after each of its stages (a call returns at most 8
# files, and a plan stopped at its limit keeps what its finished stages wrote).
set -uo pipefail
plan=${1:?plan: host-dunr, host-flight2}
OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"
export PATH=/tmp/site/bin:$PATH PYTHONUNBUFFERED=1
test -d /tmp/site/tensorly || { echo cold; exit 3; }
res=/tmp/res-$plan
mkdir -p "$res"
pack() { tar czf "$OUT/$plan.tgz" -C "$res" .; }

traced() {  # SCENE: profile_step at step 3,000 as the bench trains (--auto-stop), its timeline kept (--trace)
  local scene=$1
  PYTHONPATH=$PWD:/tmp/site timeout ${LIMIT:-150} python3 -m experiments.profile_step --scene "$PWD/.data/$scene" \
    --cache-dir "$PWD/.data/cache" --warmup 3000 --steps 500 --profile-steps 10 --python-steps 50 --auto-stop \
    --trace --output-dir "/tmp/trace-$scene" > "/tmp/trace-$scene.log" 2>&1 || tail -5 "/tmp/trace-$scene.log"
  cp "/tmp/trace-$scene/profile.md" "$res/trace-$scene.md"
  cp "/tmp/trace-$scene/trace.json.gz" "$res/trace-$scene.json.gz"
  echo "traced $scene: $(sed -n 3,4p "$res/trace-$scene.md" | tr '\n' ' ')"
}

case "$plan" in
  host-dunr)  # every GPU test (the guard's verdict, the held gradient nodes of the CUDA graphs among them) and
    # host-ab dunr (the host operations of 875022d-c67b74c against 173dc9e, alternated, 2 rounds), then render-slices
    # (the frames per second through each render way, 3 rounds of 1,000 frames on a DUNR model of step 3,000), then
    # a profile with its timeline
    OUT=$res ROUNDS=2 bash experiments/gpu_2026-12-04.sh host-ab dunr
    pack
    OUT=$res ROUNDS=3 bash experiments/gpu_2026-11-29.sh render-slices
    pack
    traced dunr
    pack
    ;;
  host-flight2)  # host-ab flight2 (2 rounds), then a profile with its timeline
    OUT=$res ROUNDS=2 bash experiments/gpu_2026-12-04.sh host-ab flight2
    pack
    traced flight2
    pack
    ;;
  *) echo "unknown plan: $plan"; exit 2 ;;
esac
