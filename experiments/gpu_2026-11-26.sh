#!/usr/bin/env bash
# The GPU runs of 2026-11-26 (issue 33: a view-dependent emission term, `view_sh_degree`):
#     bash experiments/gpu_2026-11-26.sh PLAN
# from the repository root on the GPU machine, one plan per device call on one warm machine: `install`
# with `.devicebundle` carried (built by `bash ../shared/device/prepare.sh plyfile`: the data layouts read PLY seeds), the flight2 plans with `.data/flight2` and `.data/cache` carried, the
# DUNR plan with `.data/dunr` and `.data/cache` (copies of ../shared/data/*; the cache holds their
# triangulations, made on the CPU machine as experiments/gpu_2026-11-25.sh says: the GPU image has no
# pycolmap). The code is the carried tree's (PYTHONPATH), the dependencies the bundle's.
# Each plan runs two configurations side by side, 3 seeds each (six runs sharing the GPU: timings are shared).
set -uo pipefail
plan=${1:?plan: install, flight2-view, flight2-sh2-splatfacto, dunr-view, dunr-sh2-splatfacto, synthetic-view, flight2-auto, dunr-auto, synthetic-auto, flight2-budget, grow-budget-flight2, grow-budget-dunr, growth-dunr, growth-flight2, growth-variants-dunr, growth-variants-flight2, growth-causes-dunr, growth-causes-flight2, growth-view-dunr, growth-view-flight2, growth-far-dunr, growth-far-flight2, growth-second-dunr, growth-second-flight2, trial-dunr, trial-flight2, trial-synthetic}
OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"
export PYTHONPATH=$PWD:/tmp/site PATH=/tmp/site/bin:$PATH PYTHONUNBUFFERED=1

bench() {  # bench NAME SCENE ARGS...: 3 seeds of one configuration in the background, its files to $OUT
  local name=$1 scene=$2
  shift 2
  timeout 560 python3 -m experiments.bench --output-dir "/tmp/$name" --scenes "$scene" --cache-dir "$PWD/.data/cache" \
    --seeds 3 --runs-per-gpu 3 --fit-steps 20 --fps-frames 0 "$@" > "$OUT/$name.log" 2>&1
  for f in bench.json bench.md; do [ -f "/tmp/$name/$f" ] && cp "/tmp/$name/$f" "$OUT/$name-$f"; done
}
flight2=(--steps 15000 --schedule 30000 --eval-at 2000 5000 10000 15000)
dunr=(--steps 15000 --schedule 30000 --eval-at 2000 5000 10000 15000)
# the growth-* plans (issue 33's growth question): a 1M budget, the first 10k steps of the 30k schedule, no stop
grow=(--max-gaussians 1000000 --steps 10000 --schedule 30000 --eval-at 2000 5000 10000 --no-auto-stop)

case "$plan" in
  install)  # the bundle may carry gsplat's extension xz-compressed (`xz .devicebundle/gsplat_csrc.so` here: 9 MB
    # less, which keeps the tree and the bundle under the 64 MiB a call carries)
    [ -f .devicebundle/gsplat_csrc.so.xz ] && xz -dkf .devicebundle/gsplat_csrc.so.xz
    source .devicebundle/setup.sh > "$OUT/bundle_setup.log" 2>&1
    tail -2 "$OUT/bundle_setup.log"
    ;;
  flight2-view)  # the full method's defaults, and with a degree-1 view term
    bench flight2-default "$PWD/.data/flight2" --methods wild-thermal "${flight2[@]}" &
    bench flight2-sh1 "$PWD/.data/flight2" --methods wild-thermal --set pipeline.model.view_sh_degree=1 "${flight2[@]}" &
    wait
    ;;
  flight2-sh2-splatfacto)  # a degree-2 view term; stock splatfacto (spherical harmonics to degree 3), first 10k steps
    bench flight2-sh2 "$PWD/.data/flight2" --methods wild-thermal --set pipeline.model.view_sh_degree=2 "${flight2[@]}" &
    bench flight2-splatfacto "$PWD/.data/flight2" --methods splatfacto --steps 10000 --schedule 30000 \
      --eval-at 2000 5000 10000 --time-limit 420 &
    wait
    ;;
  dunr-view)
    bench dunr-default "$PWD/.data/dunr" --methods wild-thermal "${dunr[@]}" &
    bench dunr-sh1 "$PWD/.data/dunr" --methods wild-thermal --set pipeline.model.view_sh_degree=1 "${dunr[@]}" &
    wait
    ;;
  synthetic-view)  # generated scenes without view dependence: does the term stay out of the way?
    synthetic=(--scenes demo stress:drift stress:vignetting --steps 5000 --num-downscales 1 --eval-at 1000 2000 5000)
    bench synthetic-default demo --methods wild-thermal "${synthetic[@]}" --runs-per-gpu 5 &
    bench synthetic-sh2 demo --methods wild-thermal --set pipeline.model.view_sh_degree=2 "${synthetic[@]}" --runs-per-gpu 5 &
    wait
    ;;
  flight2-auto)  # degree 2, kept or dropped at the first check by the held-back frames (decide_view_term, default)
    bench flight2-auto "$PWD/.data/flight2" --methods wild-thermal --set pipeline.model.view_sh_degree=2 "${flight2[@]}"
    ;;
  dunr-auto)
    bench dunr-auto "$PWD/.data/dunr" --methods wild-thermal --set pipeline.model.view_sh_degree=2 "${dunr[@]}"
    ;;
  synthetic-auto)  # the generated scenes with the decided view term, and the view-dependent scene without one
    synthetic=(--steps 5000 --num-downscales 1 --eval-at 1000 2000 5000 --runs-per-gpu 6)
    bench synthetic-auto demo --scenes demo stress:drift stress:vignetting stress:view --methods wild-thermal \
      --set pipeline.model.view_sh_degree=2 "${synthetic[@]}" &
    bench synthetic-view-default demo --scenes stress:view --methods wild-thermal "${synthetic[@]}" &
    wait
    ;;
  flight2-budget)  # issue 33's growth question on flight2: the full method with 3x and 10x its Gaussian budget
    bench flight2-300k "$PWD/.data/flight2" --methods wild-thermal --max-gaussians 300000 "${flight2[@]}" &
    bench flight2-1m "$PWD/.data/flight2" --methods wild-thermal --max-gaussians 1000000 "${flight2[@]}" &
    wait
    ;;
  grow-budget-flight2|grow-budget-dunr)  # the budget the held-back frames set (--auto-stop.grow-budget, from 100k
    # up to 1M) beside the defaults; one scene per call: both scenes and the cache do not travel together
    scene=${plan#grow-budget-}; steps=("${flight2[@]}"); [ "$scene" = dunr ] && steps=("${dunr[@]}")
    bench "$scene-default" "$PWD/.data/$scene" --methods wild-thermal "${steps[@]}" &
    bench "$scene-grow" "$PWD/.data/$scene" --methods wild-thermal --set auto_stop.grow_budget=True "${steps[@]}" &
    wait
    ;;
  growth-dunr|growth-flight2)  # issue 33's growth question: the full method at a 1M budget for the first 10k steps
    # of the 30k schedule, no stop (as issue 33's table), its emission as learned and clamped at zero
    scene=${plan#growth-}
    bench "$scene-1m" "$PWD/.data/$scene" --methods wild-thermal "${grow[@]}" &
    bench "$scene-1m-nonnegative" "$PWD/.data/$scene" --methods wild-thermal "${grow[@]}" \
      --set pipeline.model.nonnegative_emission=True &
    wait
    ;;
  growth-variants-dunr|growth-variants-flight2)  # the full method and its 3DGS variant at a 1M budget, as growth-*;
    # GRAD=0.0003 (say) lowers densification's gradient threshold (0.0008) so that they grow further;
    # BUDGET=100000 (say) holds them at another budget than 1M
    scene=${plan#growth-variants-}; budget=${BUDGET:-1000000}; tag=${GRAD:+-grad$GRAD}
    size=$([ "$budget" = 1000000 ] && echo 1m || echo "$budget")
    sized=("${grow[@]}" --max-gaussians "$budget")  # the later --max-gaussians is the one the bench takes
    [ -n "${GRAD:-}" ] && sized+=(--set "pipeline.model.densify_grad_thresh=$GRAD")
    bench "$scene-$size$tag" "$PWD/.data/$scene" --methods wild-thermal "${sized[@]}" &
    bench "$scene-$size-3dgs$tag" "$PWD/.data/$scene" --methods wild-thermal-3dgs "${sized[@]}" &
    wait
    ;;
  growth-causes-dunr|growth-causes-flight2)  # two candidate causes of the fall at a 1M budget (growth-variants-*):
    # the constant background the 3DGS variant can leave pixels to (splatfacto's random one forbids it),
    # and no view dependence in the full method (a degree-2 view term)
    scene=${plan#growth-causes-}
    bench "$scene-1m-3dgs-random-background" "$PWD/.data/$scene" --methods wild-thermal-3dgs "${grow[@]}" \
      --set pipeline.model.random_background=True &
    bench "$scene-1m-sh2" "$PWD/.data/$scene" --methods wild-thermal "${grow[@]}" --set pipeline.model.view_sh_degree=2 &
    wait
    ;;
  growth-view-dunr|growth-view-flight2)  # at a 1M budget: the 3DGS variant with a degree-2 view term, and the full
    # method grown further (densification's gradient threshold 0.0004 instead of 0.0008) without one
    scene=${plan#growth-view-}
    bench "$scene-1m-3dgs-sh2" "$PWD/.data/$scene" --methods wild-thermal-3dgs "${grow[@]}" \
      --set pipeline.model.view_sh_degree=2 &
    bench "$scene-1m-grad0.0004" "$PWD/.data/$scene" --methods wild-thermal "${grow[@]}" \
      --set pipeline.model.densify_grad_thresh=0.0004 &
    wait
    ;;
  growth-far-dunr|growth-far-flight2)  # both variants with a degree-2 view term, grown toward splatfacto's count
    # (gradient threshold 0.0004); one --set with both settings (a second --set replaces the first)
    scene=${plan#growth-far-}
    far=("${grow[@]}" --set pipeline.model.view_sh_degree=2 pipeline.model.densify_grad_thresh=0.0004)
    bench "$scene-1m-sh2-grad0.0004" "$PWD/.data/$scene" --methods wild-thermal "${far[@]}" &
    bench "$scene-1m-3dgs-sh2-grad0.0004" "$PWD/.data/$scene" --methods wild-thermal-3dgs "${far[@]}" &
    wait
    ;;
  growth-second-dunr|growth-second-flight2)  # the rest of growth-* for a second scene: the full method with a degree-2
    # view term, and the 3DGS variant without one, at a 1M budget
    scene=${plan#growth-second-}
    bench "$scene-1m-sh2" "$PWD/.data/$scene" --methods wild-thermal "${grow[@]}" --set pipeline.model.view_sh_degree=2 &
    bench "$scene-1m-3dgs" "$PWD/.data/$scene" --methods wild-thermal-3dgs "${grow[@]}" &
    wait
    ;;
  trial-dunr|trial-flight2)  # the view term on trial, decided by the held-back frames (--auto-stop.decide-view-term)
    # beside the defaults; compare with the view_term_gpu rows of the same scene (no term, and the term always on)
    scene=${plan#trial-}; steps=("${flight2[@]}"); [ "$scene" = dunr ] && steps=("${dunr[@]}")
    bench "$scene-default" "$PWD/.data/$scene" --methods wild-thermal "${steps[@]}" &
    bench "$scene-trial" "$PWD/.data/$scene" --methods wild-thermal "${steps[@]}" \
      --set pipeline.model.view_sh_degree=2 auto_stop.decide_view_term=True &
    wait
    ;;
  trial-synthetic)  # the same on the generated scenes (the term must stay off on vignetting, come on for
    # stress:view); their defaults and always-on rows are view_term_gpu's synthetic-* files (the same protocol)
    bench synthetic-trial demo --scenes demo stress:drift stress:vignetting stress:view --steps 5000 \
      --num-downscales 1 --eval-at 1000 2000 5000 --runs-per-gpu 6 --methods wild-thermal \
      --set pipeline.model.view_sh_degree=2 auto_stop.decide_view_term=True
    ;;
  dunr-sh2-splatfacto)
    bench dunr-sh2 "$PWD/.data/dunr" --methods wild-thermal --set pipeline.model.view_sh_degree=2 "${dunr[@]}" &
    bench dunr-splatfacto "$PWD/.data/dunr" --methods splatfacto --steps 10000 --schedule 30000 \
      --eval-at 2000 5000 10000 --time-limit 420 &
    wait
    ;;
esac
for f in "$OUT"/*-bench.md; do [ -f "$f" ] && { echo "== $f"; grep -E "^\| (wild|splat)" "$f" | head -8; }; done
exit 0
