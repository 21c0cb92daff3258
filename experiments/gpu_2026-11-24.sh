#!/usr/bin/env bash
# The GPU runs of 2026-11-24 (issue 17, speed), one plan per device command (each inside 10 minutes):
#     bash experiments/gpu_2026-11-24.sh PLAN
# run from the repository root on the GPU machine. The tree, `.devicebundle` and `.data` together are
# over the 64 MiB a call may carry, so a session takes two calls back to back (the machine stays warm
# for 30 s and keeps /tmp): `install` with `.devicebundle` carried, then a plan with `.data` carried
# (DUNR and its triangulation cache, made on a CPU machine: the GPU image has no pycolmap).
# Results go to $OUT (what the device tool brings back).
set -uo pipefail
plan=${1:?plan: install, profile, compare, dunr-splatfacto, dunr-wild-thermal, dunr-both, demo, stress-no-preprocessing, no-preprocessing, random-background, full-setting, generated, dunr-full, dunr-ablations}
OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"
export PYTHONPATH=/tmp/site PATH=/tmp/site/bin:$PATH
dunr=(--scene "$PWD/.data/dunr" --cache-dir "$PWD/.data/cache")

bench() {  # bench NAME ARGS...: one bench command into /tmp/NAME; its bench.json and bench.md to $OUT
  local name=$1; shift
  timeout 560 python3 -m experiments.bench --output-dir "/tmp/$name" "$@" > "/tmp/$name.log" 2>&1 || tail -20 "/tmp/$name.log"
  for f in bench.json bench.md; do cp "/tmp/$name/$f" "$OUT/$name-$f" 2>/dev/null; done
  grep -E "^\| (splatfacto|wild)" "$OUT/$name-bench.md" | head -4
}

case "$plan" in
  install)  # the prebuilt route: wheels, gsplat's prebuilt extension and this project into /tmp/site
    source .devicebundle/setup.sh > "$OUT/bundle_setup.log" 2>&1
    tail -2 "$OUT/bundle_setup.log"
    ;;
  profile)  # where a training step's and a baked frame's host time goes: the full method and splatfacto on DUNR
    for method in wild-thermal splatfacto; do
      timeout 200 python3 -m experiments.profile_step "${dunr[@]}" --method $method --output-dir "/tmp/profile-$method" \
        > "$OUT/profile-$method.log" 2>&1
      grep -E "ms/step|syncs per step" "/tmp/profile-$method/profile.md"
      cp "/tmp/profile-$method/profile.md" "$OUT/profile-$method.md"
    done
    timeout 90 python3 -m experiments.render_fps --frames 300 --profile-frames 50 --output-dir /tmp/render \
      --load-config /tmp/profile-wild-thermal/runs/*/wild-thermal/run/config.yml > "$OUT/render.log" 2>&1
    tail -12 "$OUT/render.log"
    cp /tmp/render/fps.json /tmp/render/render_profile.md "$OUT/"
    ;;
  compare)  # before and after on one machine: the package of the baseline commit, unpacked into .baseline/
    # (git archive BASELINE thermal_wild_ns | tar -x -C .baseline, carried with .data), against this tree's;
    # both measured by this tree's experiments/ (run from the folder whose package is imported)
    rm -rf .baseline/experiments && cp -r experiments .baseline/
    for side in before after; do
      dir=$PWD; [ $side = before ] && dir=$PWD/.baseline
      (cd "$dir" && timeout 200 python3 -m experiments.profile_step "${dunr[@]}" --method wild-thermal \
        --output-dir "/tmp/profile-$side" > "/tmp/profile-$side.log" 2>&1) || tail -20 "/tmp/profile-$side.log"
      cp "/tmp/profile-$side/profile.md" "$OUT/profile-$side.md"
      echo "$side: $(grep -E 'ms/step' "$OUT/profile-$side.md")"
    done
    config=$(find /tmp/profile-after -name config.yml | head -1)
    for side in before after; do  # the after run's Gaussians, rendered by each side's code
      dir=$PWD; [ $side = before ] && dir=$PWD/.baseline
      (cd "$dir" && timeout 90 python3 -m experiments.render_fps --frames 300 --profile-frames 50 --load-config "$config" \
        --output-dir "/tmp/render-$side" > "/tmp/render-$side.log" 2>&1) || tail -20 "/tmp/render-$side.log"
      cp "/tmp/render-$side/fps.json" "$OUT/fps-$side.json"; cp "/tmp/render-$side/render_profile.md" "$OUT/render_profile-$side.md"
      echo "$side: $(grep -A4 '"fps"' "$OUT/fps-$side.json" | tr -d '\n ')"
    done
    ;;
  # each method's default schedule on DUNR (splatfacto 30k steps; the full method 30k with its automatic
  # stop), one method per command on the same warm machine (together they pass a command's 10 minutes),
  # then merged: python -m experiments.bench --merge dunr-splatfacto-bench.json dunr-wild-thermal-bench.json
  dunr-splatfacto)
    bench dunr-splatfacto --scenes "$PWD/.data/dunr" --cache-dir "$PWD/.data/cache" --methods splatfacto --steps 30000 \
      --eval-at 1000 2000 5000 10000 20000 30000 --fit-steps 20
    ;;
  dunr-wild-thermal)
    bench dunr-wild-thermal --scenes "$PWD/.data/dunr" --cache-dir "$PWD/.data/cache" --methods wild-thermal --steps 30000 \
      --eval-at 1000 2000 5000 10000 20000 30000 --fit-steps 20
    ;;
  dunr-both)  # both methods in one bench run (one command): the first 10,000 steps of the 30k schedule, no stop
    bench dunr-both --scenes "$PWD/.data/dunr" --cache-dir "$PWD/.data/cache" --methods splatfacto wild-thermal \
      --steps 10000 --schedule 30000 --eval-at 1000 2000 5000 10000 --no-auto-stop --fit-steps 20
    ;;
  demo)  # the demo scene's protocol (5,000 steps, 1/2-resolution warm-up for every method), both methods in one run
    bench demo --scenes demo --methods splatfacto wild-thermal --steps 5000 --num-downscales 1 --eval-at 500 1000 2000 5000
    ;;
  stress-no-preprocessing)  # issue 16: is preprocessing what costs the full method against the emission MLP
    # on drift and flat-field? The full method with preprocessing off, 3 seeds, the stress protocol of
    # docs/results/stress_protocols_3seeds (3 runs at a time: timings shared). Needs only .devicebundle.
    source .devicebundle/setup.sh > "$OUT/bundle_setup.log" 2>&1
    # (run again with SCENES=stress:vignetting for the third scene the rule preprocessed)
    bench "stress-no-preprocessing${SCENES:+-${SCENES#stress:}}" --scenes ${SCENES:-stress:drift stress:ffc} --methods wild-thermal \
      --set pipeline.datamanager.preprocessing.variant=none --seeds 3 --steps 5000 --num-downscales 1 \
      --eval-at 500 1000 2000 5000 --fps-frames 0 --runs-per-gpu 3
    ;;
  no-preprocessing)  # the same question on DUNR and the demo, with the conditions of the full method's rows of
    # docs/results/full_vs_ablations.md (auto_stop_dunr: 15,000 steps of the 30k schedule; auto_stop_demo: 5,000)
    bench dunr-no-preprocessing --scenes "$PWD/.data/dunr" --cache-dir "$PWD/.data/cache" --methods wild-thermal \
      --set pipeline.datamanager.preprocessing.variant=none --seeds 3 --steps 15000 --schedule 30000 \
      --eval-at 1000 2000 5000 10000 15000 --fps-frames 0 --runs-per-gpu 3
    bench demo-no-preprocessing --scenes demo --methods wild-thermal --set pipeline.datamanager.preprocessing.variant=none \
      --seeds 3 --steps 5000 --num-downscales 1 --eval-at 500 1000 2000 5000 --fps-frames 0 --runs-per-gpu 3
    ;;
  random-background)  # issue 16: splatfacto's random training background in the variants without a background
    # MLP, on the GPU (docs/results/random_background_cpu had it on CPU only); stress-clean, 3 seeds. Needs .devicebundle.
    source .devicebundle/setup.sh > "$OUT/bundle_setup.log" 2>&1
    bench random-background --scenes stress:clean --methods wild-thermal-3dgs wild-thermal-emission-mlp \
      --set pipeline.model.random_background=True --seeds 3 --steps 5000 --num-downscales 1 \
      --eval-at 500 1000 2000 5000 --fps-frames 0 --runs-per-gpu 3
    ;;
  full-setting)  # issue 16: the full method with one setting changed (SETTING, a bench --set, named TAG) on the
    # scenes where it is short of splatfacto, the protocol of docs/results/full_vs_ablations.md (5,000 steps,
    # 1/2-resolution warm-up, automatic stop), 3 seeds, 5 runs at a time (timings shared). Needs .devicebundle.
    source .devicebundle/setup.sh > "$OUT/bundle_setup.log" 2>&1
    bench "full-${TAG:?TAG names the setting}" --scenes ${SCENES:-demo stress:clean stress:drift stress:ffc stress:outlier} \
      --methods wild-thermal --set "${SETTING:?SETTING: a bench --set}" --seeds 3 --steps 5000 --num-downscales 1 \
      --eval-at 500 1000 2000 5000 --fps-frames 0 --runs-per-gpu 5
    ;;
  generated)  # issue 16's table on the generated scenes, every method (METHODS), scored with the targets of
    # 3ef2af3 (time/half/oracle against the recorded frame): 5,000 steps, 1/2-resolution warm-up, 3 seeds,
    # RUNS at a time (timings shared); TAG names the part; SETTING, a bench --set, if given. Needs .devicebundle.
    source .devicebundle/setup.sh > "$OUT/bundle_setup.log" 2>&1
    bench "generated-${TAG:?TAG names the part}" \
      --scenes ${SCENES:-demo stress:clean stress:drift stress:ffc stress:outlier stress:vignetting} \
      --methods ${METHODS:?METHODS: bench --methods} ${SETTING:+--set "$SETTING"} --seeds 3 --steps 5000 \
      --num-downscales 1 --eval-at 500 1000 2000 5000 --fps-frames 0 --runs-per-gpu ${RUNS:-6}
    ;;
  dunr-full)  # issue 16's table on DUNR with the defaults of 83ad6d5: the full method as auto_stop_dunr
    # (15,000 steps of the 30k schedule asked, the automatic stop on), 3 seeds side by side
    bench dunr-full "${dunr[@]/--scene/--scenes}" --methods wild-thermal --seeds 3 --steps 15000 --schedule 30000 \
      --eval-at 1000 2000 5000 10000 15000 --fps-frames 0 --runs-per-gpu 3
    ;;
  dunr-ablations)  # ... and the ablations as dunr_protocols_3seeds (the first 10,000 steps, no stop), 9 runs at once
    bench dunr-ablations "${dunr[@]/--scene/--scenes}" --methods wild-thermal-emission-mlp wild-thermal-3dgs \
      wild-thermal-3dgs-stab-bbhe --seeds 3 --steps 10000 --schedule 30000 --no-auto-stop \
      --eval-at 1000 2000 5000 10000 --fps-frames 0 --runs-per-gpu 9
    ;;
  *) echo "unknown plan $plan" >&2; exit 2 ;;
esac
