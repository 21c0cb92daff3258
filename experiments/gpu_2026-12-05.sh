#!/usr/bin/env bash
# Plans for the GPU, 2026-12-05 (issue 34). One H100 (`nvidia-h100-x1`, the machine its targets name) or H200; each call
# right after the last on one warm machine (a machine stays warm 30 s):
#     bash experiments/gpu_2026-11-29.sh install               # .devicebundle carried
#     rm -rf .baseline && mkdir .baseline && git archive 173dc9e thermal_wild_ns | tar -x -C .baseline
#     THEN=host-dunr bash experiments/gpu_2026-12-05.sh tests  # .data/wheels_extra .baseline .data/dunr
#                                                              # .data/cache/triangulation-c639ec94ec8782da
# (`tests` installs the extra wheels and runs the GPU tests; with THEN=PLAN, if they pass, PLAN after: host-dunr, or
# quick-dunr, its first part and one round of the step before, for a session with little device time left)
#     bash experiments/gpu_2026-12-05.sh trace-flight2         # .data/flight2/rjpeg .data/flight2/metashape
#                                                              # .data/cache/triangulation-ff4070e3f7030d32
# then each method's default schedule, each run alone on the GPU, with the `schedule` plan of gpu_2026-12-04.sh:
#     SEEDS=3 bash experiments/gpu_2026-12-04.sh schedule dunr wild-thermal      # .data/dunr .data/cache/triangulation-c639ec94ec8782da
#     bash experiments/gpu_2026-12-04.sh schedule dunr splatfacto                # the same
#     SEEDS=3 bash experiments/gpu_2026-12-04.sh schedule flight2 wild-thermal   # .data/flight2/rjpeg .data/flight2/metashape
#                                                                                # .data/cache/triangulation-ff4070e3f7030d32
#     bash experiments/gpu_2026-12-04.sh schedule flight2 splatfacto             # the same
# Ran 2026-12-05 (docs/results/gpu_tests_h100): on one H100 the install and the tests by hand (every recording failed:
# c67b74c's held gradient nodes); on a second, after the fix, the install and THEN=quick-dunr tests with
# graphed_emission set on in the tree (13 tests passed, the profile crashed at densification after a failed
# re-recording of the emission MLP, the render ways ran on the checkpoint it left), stopped at the call's 195 s.
# A third H100 the same day (docs/results/schedule_h100_graphed): the install, THEN=emission-dunr tests (14 passed),
# then SEEDS=3 schedule dunr wild-thermal, schedule dunr splatfacto, schedule flight2 wild-thermal splatfacto of
# gpu_2026-12-04.sh, one warm machine.
# Next (not run: no device time left that session): the training PSNR at log steps alone and the frames resized once
# per warm-up size (docs/results/step_ops_metrics_cpu) against the package before them, then the default schedules:
#     rm -rf .baseline && mkdir .baseline && git archive fd20c99 thermal_wild_ns | tar -x -C .baseline
#     bash experiments/gpu_2026-11-29.sh install        # .devicebundle
#     bash experiments/gpu_2026-11-29.sh install-extra  # .data/wheels_extra
#     ROUNDS=2 bash experiments/gpu_2026-12-04.sh host-ab dunr      # .baseline and DUNR's carry
# or, where the session's device time (1,800 s) must hold the targets' runs themselves, straight after the installs
# (each call's seconds on the H100 of 2026-12-05; about 1,500 s in all):
#     SEEDS=3 bash experiments/gpu_2026-12-04.sh schedule dunr wild-thermal     # DUNR's carry (282 s)
#     bash experiments/gpu_2026-12-04.sh schedule dunr splatfacto               # the same (375 s)
#     SEEDS=3 bash experiments/gpu_2026-12-04.sh schedule flight2 wild-thermal  # flight2's carry (about 400 s)
#     bash experiments/gpu_2026-12-04.sh schedule flight2 splatfacto            # the same (about 420 s)
# The day's fourth session (the step's host cuts of c244ee4 and 7abe446: the composite's views, the guard's verdict in
# fewer operations, the densification statistics as one CUDA graph), one H100, one warm machine; ran in this order
# (docs/results/schedule_h100_host_cuts; the tracked tree and the carry must stay within 64 MiB, so the install,
# the tests and each scene went in calls of their own):
#     bash experiments/gpu_2026-11-29.sh install                                     # .devicebundle
#     bash experiments/gpu_2026-12-05.sh tests                                       # .data/wheels_extra
#     bash experiments/gpu_2026-12-05.sh trace-dunr && \
#       SEEDS=3 bash experiments/gpu_2026-12-04.sh schedule dunr wild-thermal        # DUNR's carry
#     bash experiments/gpu_2026-12-04.sh schedule dunr splatfacto                    # DUNR's carry
#     bash experiments/gpu_2026-12-04.sh schedule flight2 splatfacto                 # flight2's carry
#     bash experiments/gpu_2026-12-04.sh schedule flight2 wild-thermal               # the same; SEED=1 again
# Next (the day's fifth session had no device lent; since the runs above: bc7d5f9's capture without torch.cuda.graph
# and each MLP's layers as one parameter, PackedMLP, neither run on a GPU yet), one warm machine, each call right after
# the last (about 1,700 s in all: a session's 1,800 s holds them, the trace first, so that a cut short session still
# has the profile):
#     bash experiments/gpu_2026-11-29.sh install                                     # .devicebundle
#     bash experiments/gpu_2026-12-05.sh tests                                       # .data/wheels_extra (about 60 s)
#     bash experiments/gpu_2026-12-05.sh trace-dunr && \
#       SEEDS=3 bash experiments/gpu_2026-12-04.sh schedule dunr wild-thermal        # DUNR's carry (about 330 s)
#     bash experiments/gpu_2026-12-04.sh schedule dunr splatfacto                    # DUNR's carry (about 380 s)
#     SEEDS=3 bash experiments/gpu_2026-12-04.sh schedule flight2 wild-thermal       # flight2's carry (about 400 s)
#     bash experiments/gpu_2026-12-04.sh schedule flight2 splatfacto                 # the same (about 420 s)
# (flight2's carry: its rjpeg and metashape folders and triangulation cache; with the tracked tree it passes the 64 MiB
# limit unless docs/results' three largest files are left out of that call's tree and checked out again after it.)
# The comparison of the package before and after on one machine (.baseline = git archive fd20c99 thermal_wild_ns,
# ROUNDS=2 host-ab dunr of gpu_2026-12-04.sh) where time is left.
# Ran 2026-12-06 (docs/results/schedule_h100_packed: the exact calls; an hour of failed starts left 750 s): the install
# and the tests in one call (the tracked tree without docs/results, which the commands do not read: 64 MiB), then the
# trace and DUNR's 3 seeds, splatfacto on DUNR, flight2's 3 seeds and splatfacto's first 10k steps there (STEPS=10000).
# Next: the guard's verdict test on a GPU (its reason fixed after it failed there), splatfacto's whole 30k on flight2
# beside the full method's seeds, and host-ab on one machine (the cuts' share of the step, which a new host hides).
# Ran the same day (docs/results/schedule_h100_flight2: the exact calls), one H100: the install and the tests (15 passed),
# splatfacto's whole 30k on flight2 (LIMIT=570 TIME_LIMIT=540), the full method's 3 seeds there (TIME_LIMIT=180), then
# on the same warm machine ROUNDS=2 host-ab dunr of gpu_2026-12-04.sh against .baseline = git archive 7abe446 thermal_wild_ns.
# Next (no H100 could be started again that session): the render ways on the package the schedules ran, DUNR's carry:
#     bash experiments/gpu_2026-11-29.sh install && bash experiments/gpu_2026-11-29.sh install-extra && \
#       bash experiments/gpu_2026-12-05.sh renders-dunr
# Each plan's files go into one archive, $OUT/PLAN.tgz, rewritten after each of its stages (a call returns at most 8
# files, and a plan stopped at its limit keeps what its finished stages wrote).
set -uo pipefail
plan=${1:?plan: tests, emission-dunr, host-dunr, quick-dunr, trace-dunr, trace-flight2, renders-dunr}
OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"
export PATH=/tmp/site/bin:$PATH PYTHONUNBUFFERED=1
test -d /tmp/site || { echo cold; exit 3; }
res=/tmp/res-$plan
mkdir -p "$res"
pack() { tar czf "$OUT/$plan.tgz" -C "$res" .; }

profiled() {  # ARM DIR ROUND [FLAG...]: profile_step on DUNR at step 3,000 as the bench trains (--auto-stop), the
  # package of DIR, 500 timed steps; its profile to $res/profile-ARM-ROUND.md
  local arm=$1 dir=$2 round=$3 root=$PWD
  shift 3
  (cd "$dir" && PYTHONPATH=$dir:/tmp/site timeout ${LIMIT:-100} python3 -m experiments.profile_step \
    --scene "$root/.data/dunr" --cache-dir "$root/.data/cache" --warmup 3000 --steps 400 --profile-steps 10 \
    --python-steps 0 --auto-stop --output-dir "/tmp/profile-$arm-$round" "$@" > "/tmp/profile-$arm-$round.log" 2>&1) \
    || tail -5 "/tmp/profile-$arm-$round.log"
  grep -v "^\s*$" "/tmp/profile-$arm-$round.log" | tail -c 200000 > "$res/profile-$arm-$round.log"  # kept: a failure's cause
  cp "/tmp/profile-$arm-$round/profile.md" "$res/profile-$arm-$round.md"
  echo "$arm $round: $(sed -n 3,4p "$res/profile-$arm-$round.md" | tr '\n' ' ')"
}

timeline_and_renders() {  # DIR: the timeline of the profile in DIR (run with --trace) read by
  # experiments.trace_summary, then the render ways on the model it trained (renders)
  local dir=$1
  cp "$dir/trace.json.gz" "$res/trace-dunr.json.gz"
  PYTHONPATH=$PWD:/tmp/site python3 -m experiments.trace_summary "$res/trace-dunr.json.gz" > "$res/trace-dunr.md"
  pack
  renders "$dir"
}

renders() {  # DIR: the render ways on the model the profile in DIR trained, 3 rounds of 1,000 frames at 640x512
  # (experiments.render_fps), each round a line of $res/fps_rounds.jsonl
  local dir=$1 config round
  config=$(ls "$dir"/runs/*/wild-thermal/run/config.yml | head -1)
  for round in 1 2 3; do
    PYTHONPATH=$PWD:/tmp/site timeout 60 python3 -m experiments.render_fps --load-config "$config" --frames 1000 \
      --output-dir "/tmp/render-$round" > "/tmp/render-$round.log" 2>&1 || tail -20 "/tmp/render-$round.log"
    python3 -c "import json, sys; r = json.load(open(sys.argv[1])); r['round'] = int(sys.argv[2]); print(json.dumps(r))" \
      "/tmp/render-$round/fps.json" "$round" | tee -a "$res/fps_rounds.jsonl"
  done
}

case "$plan" in
  tests)  # the extra wheels, then every GPU test (the training render through gsplat's functions, the emission
    # MLP's padded recordings, the guard's verdict, the held gradient nodes of the CUDA graphs, the fixed-size tile
    # intersection of experiments/padded_isect.py among them)
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site \
      .data/wheels_extra/*.whl 2>&1 | grep -v WARNING
    PYTHONPATH=$PWD:/tmp/site timeout 300 python3 -m pytest -q -p no:cacheprovider tests/test_gpu_parity.py \
      tests/test_padded_isect.py > "$res/gpu-tests.log" 2>&1
    grep -E "^(E  |FAILED|[0-9]+ (passed|failed))" "$res/gpu-tests.log" | head -30
    pack
    summary=$(grep -E "[0-9]+ (passed|failed)" "$res/gpu-tests.log" | tail -1)
    case "$summary" in *failed*|*error*|"") echo "GPU tests not all passed: nothing else runs"; exit 1 ;; esac
    [ -n "${THEN:-}" ] && OUT=$OUT bash "$0" "$THEN"
    ;;
  quick-dunr)  # host-dunr's first part (the step now with its timeline, the render ways on its model), then the step
    # before the host work of 2026-12-04 (.baseline, 173dc9e; 6f4d57a's recordings fail: gpu_tests_h100), one round
    # each: for a session with little device time left
    rm -rf .baseline/experiments && cp -r experiments .baseline/
    profiled now "$PWD" 1 --trace
    timeline_and_renders /tmp/profile-now-1
    pack
    profiled before "$PWD/.baseline" 1
    pack
    ;;
  host-dunr)  # the step now (its timeline kept), then the render ways on the model it trained (experiments.render_fps,
    # 3 rounds of 1,000 frames; DUNR to step 3,400 as the bench trains), then the step before the host work of
    # 2026-12-04 (.baseline, 173dc9e) against now, alternated, 2 rounds (not 6f4d57a: its recordings fail on a GPU,
    # docs/results/gpu_tests_h100)
    bash "$0" quick-dunr
    for arm in now before; do
      dir=$PWD; [ $arm = before ] && dir=$PWD/.baseline
      profiled "$arm" "$dir" 2
    done
    cp /tmp/res-quick-dunr/* "$res/"
    pack
    ;;
  emission-dunr)  # graphed_emission on (the tree's default) against off, the step as the bench trains DUNR to step
    # 3,400 (profiled), alternated, ROUNDS rounds (2), the on-arm's first round with its timeline; then the render
    # ways on the on-arm's model (3 rounds of 1,000 frames)
    for round in $(seq ${ROUNDS:-2}); do
      arms="on off"; [ $((round % 2)) = 0 ] && arms="off on"
      for arm in $arms; do
        flags=(); [ $arm = off ] && flags=(--set pipeline.model.graphed_emission=False)
        [ $arm-$round = on-1 ] && flags=(--trace)
        profiled "$arm" "$PWD" "$round" "${flags[@]}"
        pack
      done
    done
    timeline_and_renders /tmp/profile-on-1
    pack
    ;;
  trace-dunr|trace-flight2)  # the scene's step at step 3,000 as the bench trains, its timeline kept (the scene's carry)
    scene=${plan#trace-}
    root=$PWD
    (PYTHONPATH=$root:/tmp/site timeout ${LIMIT:-100} python3 -m experiments.profile_step --scene "$root/.data/$scene" \
      --cache-dir "$root/.data/cache" --warmup 3000 --steps 400 --profile-steps 10 --python-steps 0 --auto-stop --trace \
      --output-dir "/tmp/trace-$scene" > "/tmp/trace-$scene.log" 2>&1) || tail -5 "/tmp/trace-$scene.log"
    cp "/tmp/trace-$scene/profile.md" "$res/profile-$scene.md"
    cp "/tmp/trace-$scene/trace.json.gz" "$res/trace-$scene.json.gz"
    PYTHONPATH=$root:/tmp/site python3 -m experiments.trace_summary "$res/trace-$scene.json.gz" > "$res/trace-$scene.md"
    sed -n 3,4p "$res/profile-$scene.md"; head -30 "$res/trace-$scene.md"
    pack
    ;;
  renders-dunr)  # the render ways (as `ns-render` and the viewer draw) on a DUNR model of the package now, trained to
    # step 3,400 as the bench trains: the render target's numbers for the package the schedules ran (DUNR's carry)
    profiled now "$PWD" 1
    pack
    renders /tmp/profile-now-1
    pack
    ;;
  *) echo "unknown plan: $plan"; exit 2 ;;
esac
