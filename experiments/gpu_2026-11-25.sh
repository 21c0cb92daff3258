#!/usr/bin/env bash
# The GPU runs of 2026-11-25 (issue 31: flight2, a drone survey read from its R-JPEGs and Metashape XML):
#     bash experiments/gpu_2026-11-25.sh PLAN
# from the repository root on the GPU machine, two calls back to back on one warm machine: `install`
# with `.devicebundle` carried, then `flight2` with `.data` carried: `.data/flight2` (a copy of
# ../shared/data/flight2) and `.data/cache` (its triangulation, made on the CPU machine: the GPU image
# has no pycolmap) by
#     python -c "from pathlib import Path; from thermal_wild_ns.data.dataparsers import ThermalDataParserConfig as C; \
#       C(data=Path('.data/flight2').resolve(), cache_dir=Path('.data/cache').resolve()).setup().get_dataparser_outputs('train')"
# The EXIF route (flight2-exif) reads the same frames with `exif-gps`: its SfM poses are cached the same way,
#     python -c "from pathlib import Path; from thermal_wild_ns.data.dataparsers import ThermalDataParserConfig as C; \
#       C(data=Path('.data/flight2').resolve(), layout='exif-gps', cache_dir=Path('.data/cache').resolve()).setup().get_dataparser_outputs('train')"
# Results go to $OUT (what the device tool brings back).
set -uo pipefail
plan=${1:?plan: install, flight2, flight2-exif, flight2-run}
OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"
export PYTHONPATH=/tmp/site PATH=/tmp/site/bin:$PATH

case "$plan" in
  install)  # wheels, gsplat's prebuilt extension and this project into /tmp/site
    source .devicebundle/setup.sh > "$OUT/bundle_setup.log" 2>&1
    tail -2 "$OUT/bundle_setup.log"
    ;;
  flight2)  # the full method with its defaults (automatic stop) on flight2, 3 seeds side by side: the
    # protocols and the held-out error in °C (the camera's own calibration)
    timeout 540 python3 -m experiments.bench --output-dir /tmp/flight2 --scenes "$PWD/.data/flight2" \
      --cache-dir "$PWD/.data/cache" --methods wild-thermal --seeds 3 --steps 15000 --schedule 30000 \
      --eval-at 2000 5000 10000 15000 --fit-steps 20 --fps-frames 0 --runs-per-gpu 3 > /tmp/flight2.log 2>&1 \
      || tail -30 /tmp/flight2.log
    cp /tmp/flight2.log "$OUT/flight2.log"
    for f in bench.json bench.md; do cp "/tmp/flight2/$f" "$OUT/flight2-$f" 2>/dev/null; done
    grep -E "^\| wild" "$OUT/flight2-bench.md" | head -4
    ;;
  flight2-exif)  # the same as flight2, with the poses of the EXIF route (GPS + gimbal priors, SfM)
    timeout 540 python3 -m experiments.bench --output-dir /tmp/flight2-exif --scenes "exif-gps:$PWD/.data/flight2" \
      --cache-dir "$PWD/.data/cache" --methods wild-thermal --seeds 3 --steps 15000 --schedule 30000 \
      --eval-at 2000 5000 10000 15000 --fit-steps 20 --fps-frames 0 --runs-per-gpu 3 > /tmp/flight2-exif.log 2>&1 \
      || tail -30 /tmp/flight2-exif.log
    cp /tmp/flight2-exif.log "$OUT/flight2-exif.log"
    for f in bench.json bench.md; do cp "/tmp/flight2-exif/$f" "$OUT/flight2-exif-$f" 2>/dev/null; done
    grep -E "^\| wild" "$OUT/flight2-exif-bench.md" | head -4
    ;;
  flight2-run)  # one run of the full method with its defaults on flight2 (seed 0), brought back whole for the
    # survey exports made on the CPU machine (wild-thermal-export celsius-points / orthomosaic)
    rm -rf /tmp/runs  # a warm machine keeps /tmp: an earlier run's states would travel too
    timeout 540 ns-train wild-thermal --output-dir /tmp/runs --experiment-name flight2 --timestamp seed0 \
      --vis tensorboard --max-num-iterations 15000 thermal --data "$PWD/.data/flight2" --cache-dir "$PWD/.data/cache" \
      > "$OUT/flight2-run.log" 2>&1 || tail -30 "$OUT/flight2-run.log"
    run=/tmp/runs/flight2/wild-thermal/seed0
    rm -rf "$run"/events* "$run"/.partial "$run"/auto_stop  # what exporting needs: config, records, the model
    ls "$run"/nerfstudio_models/step-*.ckpt | sort | head -n -1 | xargs -r rm  # the final checkpoint only
    # the model alone (no optimizer moments): the device tool brings back files of 16 MiB at most
    python3 -c "import sys, torch; p = sys.argv[1]; c = torch.load(p, weights_only=False); \
      torch.save({k: c[k] for k in ('step', 'pipeline')}, p)" "$run"/nerfstudio_models/step-*.ckpt
    tar -C /tmp/runs -cJf "$OUT/flight2-run.tar.xz" flight2  # shallow folders only come back: one archive
    ls -la "$OUT"
    tail -3 "$OUT/flight2-run.log"; head -12 /tmp/runs/flight2/wild-thermal/seed0/auto_stop.json
    ;;
esac
