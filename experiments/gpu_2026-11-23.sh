#!/usr/bin/env bash
# The GPU runs of 2026-11-23, one plan per device command (each must end inside 10 minutes):
#     bash experiments/gpu_2026-11-23.sh PLAN
# run from the repository root on the GPU machine, with `.devicebundle` (../shared/device/prepare.sh
# plyfile) carried, and `.data` (DUNR and its triangulation cache, made on a CPU machine: the GPU
# image has no pycolmap) for the DUNR plans. Results go to $OUT (what the device tool brings back).
set -uo pipefail
plan=${1:?plan: setup, dunr-splatfacto, dunr-3dgs, dunr-emission-mlp, dunr-wild-thermal, demo-a, demo-b, dunr-auto, demo-auto, speed, loss-space, stress-a, stress-b, stress-c, stress-d, stress-e, splatfacto-parts}
OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"

bundle() {  # the prebuilt route: wheels + gsplat's prebuilt extension into /tmp/site
  source .devicebundle/setup.sh > "$OUT/bundle_setup.log" 2>&1
}

bench() {  # bench ARGS...: one bench command, its files copied to $OUT even when it is cut short
  local dir=/tmp/bench-$plan
  timeout 540 python3 -m experiments.bench --output-dir "$dir" "$@" 2>&1 | tee "$OUT/$plan.log" | grep -E "step [0-9]+,|FAILED|Error" | tail -40
  for f in bench.json bench.md speed_accuracy.png; do [ -f "$dir/$f" ] && cp "$dir/$f" "$OUT/$plan-$f"; done
}

bench_parts() {  # bench_parts ARGS... --output-dir DIR (last): a bench over GPU queues; every finished run's files to $OUT
  local dir=${*: -1} name
  name=$(basename "$dir")
  timeout "${LIMIT:-540}" python3 -m experiments.bench "$@" > "$OUT/$name.log" 2>&1
  tail -3 "$OUT/$name.log"
  for f in bench.json bench.md speed_accuracy.png; do [ -f "$dir/$f" ] && cp "$dir/$f" "$OUT/$name-$f"; done
  (cd "$dir" && find gpu* -name bench.json -o -path "*/strips/*" -name "*.npy" | tar czf "$OUT/$name-parts.tgz" -T -)
}

stress() {  # stress --methods ...: the five stress scenes of issue 16
  bench_parts --scenes stress:clean stress:drift stress:ffc stress:outlier stress:vignetting "$@" --seeds 3 --steps 5000 \
    --num-downscales 1 --eval-at 500 1000 2000 5000 --fps-frames 0 --runs-per-gpu 4 --output-dir "/tmp/$plan"
}

# DUNR: the first 10,000 steps of the 30k schedule, 3 seeds per method, one method per command
dunr() {
  bundle
  bench --scenes "$PWD/.data/dunr" --cache-dir "$PWD/.data/cache" --methods "$1" --seeds 3 --steps 10000 --schedule 30000 \
    --eval-at 1000 2000 5000 10000
}

case "$plan" in
  setup)  # the README's GPU route (light nerfstudio closure, wheels from the carried folder), then the main job
    python3 -m pip list 2>/dev/null > "$OUT/image_pip_list.txt"
    export PIP_NO_INDEX=1 PIP_FIND_LINKS="$PWD/.devicebundle/wheels"
    { time GPU=1 NERFSTUDIO_DEPS=light GSPLAT_PREBUILT=.devicebundle/gsplat_csrc.so bash thermal_wild_ns/install/setup_env.sh; } \
      > "$OUT/gpu_setup.log" 2>&1
    { time timeout 400 .venv/bin/wild-thermal-demo --output-dir /tmp/demo; } > "$OUT/gpu_demo.log" 2>&1
    cp /tmp/demo/metrics.json "$OUT/gpu_demo_metrics.json" 2>/dev/null
    tail -5 "$OUT/gpu_setup.log" "$OUT/gpu_demo.log"
    # a short bench of splatfacto and the full method through that environment (catches a broken bench early)
    timeout 150 .venv/bin/python -m experiments.bench --scenes demo --methods splatfacto wild-thermal --steps 300 --eval-at 300 \
      --num-downscales 1 --fit-steps 5 --fps-frames 20 --output-dir /tmp/smoke > "$OUT/smoke.log" 2>&1
    tail -3 "$OUT/smoke.log"; cp /tmp/smoke/bench.md "$OUT/smoke-bench.md" 2>/dev/null
    ;;
  dunr-splatfacto) dunr splatfacto ;;
  dunr-3dgs) dunr wild-thermal-3dgs ;;
  dunr-emission-mlp) dunr wild-thermal-emission-mlp ;;
  dunr-wild-thermal) dunr wild-thermal ;;
  # the demo scene: 5,000 steps (the 30k schedule compressed), 3 seeds; splatfacto's 1/4-resolution
  # warm-up on 128x96 frames explodes (docs/), so every method starts at 1/2
  demo-a)
    bundle
    bench --scenes demo --methods splatfacto wild-thermal-3dgs --seeds 3 --steps 5000 --num-downscales 1 --eval-at 500 1000 2000 5000
    ;;
  demo-b)
    bundle
    bench --scenes demo --methods wild-thermal-emission-mlp wild-thermal --seeds 3 --steps 5000 --num-downscales 1 --eval-at 500 1000 2000 5000
    ;;
  # the automatic stop (training/auto_stop.py) on: the same runs as dunr-wild-thermal and demo-b's full method
  dunr-auto)  # the first 15,000 steps of the 30k schedule, the 3 seeds side by side on the one GPU (timings shared)
    bundle
    bench --scenes "$PWD/.data/dunr" --cache-dir "$PWD/.data/cache" --methods wild-thermal --seeds 3 --steps 15000 \
      --schedule 30000 --eval-at 1000 2000 5000 10000 15000 --auto-stop --runs-per-gpu 3 --fps-frames 0
    cp /tmp/bench-$plan/gpu0/*/runs/dunr/*/wild-thermal/run/auto_stop.json "$OUT/" 2>/dev/null
    # where a baked frame's time goes (the first seed's run)
    timeout 60 python3 -m experiments.render_fps --frames 300 --profile-frames 50 --output-dir "$OUT/render" \
      --load-config /tmp/bench-$plan/gpu0/00_dunr_wild-thermal_seed0/runs/dunr/wild-thermal_seed0/wild-thermal/run/config.yml \
      | tail -12
    ;;
  demo-auto)
    bundle
    bench --scenes demo --methods wild-thermal --seeds 3 --steps 5000 --num-downscales 1 --eval-at 500 1000 2000 5000 --auto-stop
    ;;
  speed)  # a training step of the full method and of splatfacto on DUNR, then both in one bench run (no automatic stop)
    bundle
    for method in wild-thermal splatfacto; do
      timeout 150 python3 -m experiments.profile_step --scene "$PWD/.data/dunr" --cache-dir "$PWD/.data/cache" \
        --method $method --output-dir "$OUT/profile-$method" 2>&1 | grep -E "ms/step|syncs per step"
    done
    bench --scenes "$PWD/.data/dunr" --cache-dir "$PWD/.data/cache" --methods splatfacto wild-thermal --steps 10000 \
      --schedule 30000 --eval-at 1000 2000 5000 10000 --no-auto-stop --fit-steps 20
    ;;
  loss-space)  # the photometric loss in the training space and in the original space, 3 seeds each, 3 runs at a time
    bundle
    for space in training original; do
      timeout 230 python3 -m experiments.bench --output-dir /tmp/bench-$space --scenes "$PWD/.data/dunr" \
        --cache-dir "$PWD/.data/cache" --methods wild-thermal --seeds 3 --steps 5000 --schedule 30000 \
        --eval-at 1000 2000 5000 --fit-steps 20 --fps-frames 300 --no-auto-stop --set pipeline.model.loss_space=$space --runs-per-gpu 3 \
        > "$OUT/loss-space-$space.log" 2>&1
      for f in bench.json bench.md; do cp /tmp/bench-$space/$f "$OUT/loss-space-$space-$f" 2>/dev/null; done
      grep -E "^\| wild" "$OUT/loss-space-$space-bench.md" | head -5
    done
    # where a baked frame's time goes now (a training-space run)
    timeout 60 python3 -m experiments.render_fps --frames 300 --profile-frames 50 --output-dir "$OUT/render" \
      --load-config /tmp/bench-training/gpu0/00_dunr_wild-thermal_seed0/runs/dunr/*/wild-thermal/run/config.yml | tail -8
    ;;
  # the stress scenes (one fault each), 5,000 steps like the demo, 3 seeds, 4 runs side by side on the GPU;
  # each run's own bench.json and strips come back too (parts.tgz), so runs that finished before a
  # cut-off still count (python -m experiments.bench --merge)
  stress-a)
    bundle
    stress --methods splatfacto
    ;;
  stress-b)  # the full method with its preprocessing forced on (stress-clean), then the ablations without an emission MLP
    bundle
    bench_parts --scenes stress:clean --methods wild-thermal --set pipeline.datamanager.preprocessing.skip_when_stable=False \
      --seeds 3 --steps 5000 --num-downscales 1 --eval-at 500 1000 2000 5000 --fps-frames 0 --runs-per-gpu 3 --output-dir /tmp/forced-on
    LIMIT=450 stress --methods wild-thermal-3dgs wild-thermal-3dgs-stab-bbhe
    ;;
  stress-c)
    bundle
    stress --methods wild-thermal-emission-mlp wild-thermal
    ;;
  # the full method on stress-outlier with the robust frame-mean spread (MAD; stress-c ran with the std,
  # which the one bright frame inflated), then the preprocessing ablation on the demo and DUNR with the
  # conditions of the 3-seed tables it joins (no automatic stop, 5,000 / the first 10,000 of 30,000 steps)
  stress-d)
    bundle
    bench_parts --scenes stress:outlier --methods wild-thermal --seeds 3 --steps 5000 --num-downscales 1 \
      --eval-at 500 1000 2000 5000 --fps-frames 0 --runs-per-gpu 3 --output-dir /tmp/outlier-mad
    LIMIT=120 bench_parts --scenes demo --methods wild-thermal-3dgs-stab-bbhe --seeds 3 --steps 5000 --num-downscales 1 \
      --eval-at 500 1000 2000 5000 --fps-frames 0 --no-auto-stop --runs-per-gpu 3 --output-dir /tmp/demo-stab-bbhe
    LIMIT=300 bench_parts --scenes "$PWD/.data/dunr" --cache-dir "$PWD/.data/cache" --methods wild-thermal-3dgs-stab-bbhe \
      --seeds 3 --steps 10000 --schedule 30000 --eval-at 1000 2000 5000 10000 --fps-frames 0 --no-auto-stop --runs-per-gpu 3 \
      --output-dir /tmp/dunr-stab-bbhe
    ;;
  stress-e)  # run on commit c1ac6fc: the full method, the automatic stop's window a whole opacity-reset cycle while
    # resets come (patience_at, reverted after this run: no gain, more steps; docs/results/stress_protocols_3seeds)
    bundle
    bench_parts --scenes stress:clean stress:drift stress:ffc stress:outlier stress:vignetting --methods wild-thermal --seeds 3 \
      --steps 5000 --num-downscales 1 --eval-at 500 1000 2000 5000 --fps-frames 0 --runs-per-gpu 5 --output-dir /tmp/reset-cycle
    ;;
  splatfacto-parts)  # what splatfacto's lead on stress-clean comes from: no view-dependent colour (SH degree 0), or a
    # black training background in place of its random one; 3 seeds each, the six runs at once
    bundle
    LIMIT=230 bench_parts --scenes stress:clean --methods splatfacto --set pipeline.model.sh_degree=0 --seeds 3 --steps 5000 \
      --num-downscales 1 --eval-at 500 1000 2000 5000 --fps-frames 0 --runs-per-gpu 3 --output-dir /tmp/sf-sh0 &
    LIMIT=230 bench_parts --scenes stress:clean --methods splatfacto --set pipeline.model.background_color=black --seeds 3 \
      --steps 5000 --num-downscales 1 --eval-at 500 1000 2000 5000 --fps-frames 0 --runs-per-gpu 3 --output-dir /tmp/sf-black
    wait
    ;;
  *) echo "unknown plan $plan" >&2; exit 2 ;;
esac
