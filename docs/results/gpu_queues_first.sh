#!/bin/bash
# The GPU runs of 2026-11-22 (issues 5 and 6), as the device tool ran them from the repository root:
#   bash results/gpu_queues_first.sh PLAN      (PLAN: demo | sweep | stress | equalization)
# Each PLAN runs up to four queues side by side, one per GPU of an nvidia-h200-x4 machine, each
# queue a list of `wild-thermal-bench` commands run one after another (one run per GPU at a time:
# two per GPU measured not to pay). After LIMIT seconds (default 560, the device allows 600 per
# command) unfinished runs are stopped; every bench writes its bench.json after each run, so
# finished runs are kept. The results (no renders, no checkpoints) go to $OUT/PLAN.tar.gz.
# The queues do what `wild-thermal-bench --gpus N` does (run_in_gpu_queues), but for runs whose
# bench arguments differ (steps, warm-up, budget, time limit), which one `--gpus` command cannot mix.
source .devicebundle/setup.sh >/dev/null
R=$PWD
export PYTHONPATH=$R:$PYTHONPATH
cd /tmp && mkdir -p q
BENCH="python3 -m thermal_wild_ns.benchmarks.bench --cache-dir $R/.data/cache"
DUNR=$R/.data/dunr
STRESS="--steps 5000 --eval-at 1000 2500 5000 --wild-steps 30 --fps-frames 0 --time-limit 150"
SWEEP="--scenes $DUNR --methods wild-thermal --steps 30000 --fps-frames 0 --wild-steps 5 --eval-at 30000"  # as wild-thermal-budget-sweep runs each budget

queue() {  # queue GPU "NAME|BENCH ARGUMENTS" ...: one bench after another on GPU, output in q/NAME
  local gpu=$1
  shift
  (for item in "$@"; do
    name=${item%%|*}
    echo "$(date +%T) GPU $gpu start $name: ${item#*|}" >>q/queues.log
    CUDA_VISIBLE_DEVICES=$gpu OMP_NUM_THREADS=16 $BENCH ${item#*|} --output-dir q/$name >q/$name.log 2>&1
    echo "$(date +%T) GPU $gpu end $name: exit $?" >>q/queues.log
  done) &
}

case $1 in
demo)  # issue 5: every method, the full 30k schedule, on the embedded demo scene
  queue 0 "demo_wild-thermal|--scenes demo --methods wild-thermal" "demo_3dgs|--scenes demo --methods wild-thermal-3dgs"
  queue 1 "demo_emission-mlp|--scenes demo --methods wild-thermal-emission-mlp" "demo_histeq|--scenes demo --methods wild-thermal-3dgs-histeq" \
    "stress_wild-thermal_sky|--scenes stress:sky --methods wild-thermal $STRESS"
  queue 2 "demo_splatfacto_ds1|--scenes demo --methods splatfacto --num-downscales 1" "demo_bbhe|--scenes demo --methods wild-thermal-3dgs-bbhe" \
    "demo_splatfacto|--scenes demo --methods splatfacto --time-limit 60"
  queue 3 "demo_stab|--scenes demo --methods wild-thermal-3dgs-stab" "demo_stab-bbhe|--scenes demo --methods wild-thermal-3dgs-stab-bbhe" \
    "stress_wild-thermal_all|--scenes stress:all --methods wild-thermal $STRESS"
  ;;
sweep)  # issue 5: the Gaussian budget of full wild-thermal on DUNR; then issue 6: splatfacto on the stress scenes
  queue 0 "budget_50000|$SWEEP --max-gaussians 50000" \
    "stress_splatfacto_ds1_a|--scenes stress:clean stress:outlier stress:drift --methods splatfacto --num-downscales 1 $STRESS"
  queue 1 "budget_100000|$SWEEP --max-gaussians 100000" \
    "stress_splatfacto_ds1_b|--scenes stress:ffc stress:vignetting stress:fixed-pattern --methods splatfacto --num-downscales 1 $STRESS"
  queue 2 "budget_150000|$SWEEP --max-gaussians 150000" \
    "stress_splatfacto_ds1_c|--scenes stress:low-contrast stress:sky stress:all --methods splatfacto --num-downscales 1 $STRESS"
  queue 3 "budget_uncapped|$SWEEP --max-gaussians 100000000" \
    "stress_splatfacto_stock|--scenes stress:clean stress:outlier --methods splatfacto ${STRESS/--time-limit 150/--time-limit 45}"
  ;;
stress)  # issue 6: the plugin's methods again on clean/outlier, with the screen-size rule fix (0b7b541)
  queue 0 "stress_rerun_wt|--scenes stress:clean stress:outlier --methods wild-thermal $STRESS"
  queue 1 "stress_rerun_3dgs|--scenes stress:clean stress:outlier --methods wild-thermal-3dgs $STRESS"
  queue 2 "stress_rerun_stabbbhe|--scenes stress:clean stress:outlier --methods wild-thermal-3dgs-stab-bbhe $STRESS"
  queue 3 "stress_rerun_mlp|--scenes stress:clean stress:outlier --methods wild-thermal-emission-mlp $STRESS"
  ;;
equalization)  # half-strength BBHE (--equalization-strength 0.5) for the full method, on one GPU (nvidia-h200)
  queue 0 "eq05_dunr|--scenes $DUNR --methods wild-thermal --steps 30000 --equalization-strength 0.5" \
    "eq05_stress|--scenes stress:clean stress:outlier --methods wild-thermal --equalization-strength 0.5 $STRESS"
  ;;
*) echo "unknown plan '$1' (demo | sweep | stress | equalization)" >&2; exit 2 ;;
esac

deadline=$((SECONDS + ${LIMIT:-560}))
while [ -n "$(jobs -rp)" ] && [ $SECONDS -lt $deadline ]; do sleep 5; done
if [ -n "$(jobs -rp)" ]; then
  echo "$(date +%T) time up: stopping the queues" >>q/queues.log
  kill $(jobs -p) 2>/dev/null  # the queues first, or they would start their next run
  pkill -f thermal_wild_ns.benchmarks.bench
  sleep 5
fi
cat q/queues.log
cd q && find . -type f \( -name bench.json -o -name bench.md -o -name '*.png' -o -name '*.npy' -o -name '*.log' \) \
  -not -regex '\./[^/]*/\(demo-scene\|stress-[^/]*\|renders\|runs\)/.*' | tar czf $OUT/$1.tar.gz -T -
ls -la $OUT
