"""How much of a generated scene's `time`-`oracle` gap no model can close: the gap of a perfect model.

    python -m experiments.state_bound --scenes demo stress:drift stress:ffc --output docs/results/state_bound/bound.md

On a generated scene the sensor's per-frame gain and offset are known (`demo_scene.sensor_faults`). A
perfect model renders each held-out frame exactly as the sensor would with some state; this script
scores, against each recorded held-out frame (its noise included), that frame rebuilt from the scene's
clean counts with

- the frame's own gain and offset: the ceiling any `oracle` can reach (only the sensor's noise is left);
- the gain and offset interpolated between the neighbouring training frames in capture time, as the
  `time` protocol interpolates their states (`time_weights`: the nearest training frame's before the
  first and after the last);
- a straight line fitted over every training frame's gain and offset (least squares against capture
  position), the best a smooth-drift predictor could do where the drift is a ramp;
- a straight line fitted over the `LOCAL_FRAMES` training frames nearest in capture time (`local`): a
  predictor that averages out its neighbours' own jitter, where the two-neighbour rule copies it.

PSNR in the dataset-normalised space (data range 1, the bench's), mean over held-out views. `own` -
`neighbours` is the gap a perfect model leaves under the `time` protocol: the share of a measured gap
that the data itself makes unpredictable (frame-to-frame jitter, a flat-field correction's drop between
two training frames). The per-view rows show which frames carry it.

With `--bench FILE...` (bench.json files of runs on these scenes) each run's held-out views are split
the same way: the state error a perfect model makes (`neighbours`' mean squared error less `own`'s,
the sensor's noise) added to the run's own `oracle` error (independent errors: their mean squares add)
gives the `time` PSNR the run would reach if its only loss under `time` were the data's
unpredictability; `oracle` - that is the data's share of the run's gap, that - `time` the model's (how
its states interpolate, and what the `oracle`'s fit on the held-out frame absorbs).
"""

from __future__ import annotations

import json
import tempfile
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import numpy as np
import torch
import tyro

from experiments import mean_range, write_report
from experiments.scenes import scene_dataparser, scene_name
from thermal_wild_ns.data.dataparsers import ThermalDemoDataParserConfig
from thermal_wild_ns.data.demo_scene import DemoSceneConfig, camera_to_world, clean_counts, sensor_counts, sensor_faults
from thermal_wild_ns.image_metrics import psnr
from thermal_wild_ns.preprocessing.photometric import time_weights

PREDICTORS = ("own", "neighbours", "line", "local")
LOCAL_FRAMES = 4
STATE = ("gain", "offset", "outlier")  # a frame's sensor state in `sensor_faults`
GENERATED = ("demo", "stress:clean", "stress:drift", "stress:ffc", "stress:outlier", "stress:vignetting")


@dataclass
class Args:
    scenes: Tuple[str, ...] = GENERATED
    """'demo' or 'stress:FAULT' (as in python -m experiments.bench)."""
    output: Path = Path("outputs/state_bound/bound.md")
    work_dir: Path = Path(tempfile.gettempdir()) / "thermal_wild_ns_state_bound"
    """Where the scenes are generated (reused when up to date)."""
    bench: Optional[Tuple[Path, ...]] = None
    """bench.json files whose runs on these scenes get their `time`-`oracle` gap split into the data's
    share and the model's."""


def line_fit(times: np.ndarray, values: np.ndarray) -> Tuple[float, float]:
    """(slope, intercept) of the least-squares line through (times, values)."""
    slope, intercept = np.polyfit(times, values, 1)
    return float(slope), float(intercept)


def predicted_states(
    faults: Dict[str, np.ndarray], train: np.ndarray, lines: Dict[str, Tuple[float, float]], frame: int
) -> Dict[str, Tuple[float, ...]]:
    """(gain, offset, outlier factor) of held-out `frame` by each predictor, from the training frames `train`
    and the lines (slope, intercept) fitted through their states."""
    i, j, w = time_weights(train.tolist(), float(frame))
    a, b = train[i], train[j]
    near = train[np.argsort(np.abs(train - frame), kind="stable")[:LOCAL_FRAMES]]
    return {
        "own": tuple(float(faults[k][frame]) for k in STATE),
        "neighbours": tuple(float((1 - w) * faults[k][a] + w * faults[k][b]) for k in STATE),
        "line": tuple(lines[k][0] * frame + lines[k][1] for k in STATE),
        "local": tuple(float(np.polyval(np.polyfit(near, faults[k][near], 1), frame)) for k in STATE),
    }


def scene_bound(scene: str, work_dir: Path) -> List[dict]:
    """One row per held-out frame: its index and each predictor's PSNR against the recorded frame."""
    parser_config = scene_dataparser(scene, work_dir, work_dir / "cache")
    if not isinstance(parser_config, ThermalDemoDataParserConfig) or parser_config.scene == "survey":
        raise ValueError(f"{scene!r}: only 'demo' and 'stress:FAULT' scenes have known sensor states")
    parser = parser_config.setup()
    outputs = parser.get_dataparser_outputs("test")  # generates the scene; its images are the fault-free truth
    folder = Path(parser_config.data)
    generator = json.loads((folder / "transforms.json").read_text())["thermal_demo"]["config"]
    cfg = DemoSceneConfig(**generator)  # the config the scene was generated with
    faults = sensor_faults(cfg)
    held_out = sorted(int(Path(p).stem.split("_")[-1]) for p in outputs.image_filenames)  # frame_00008.png -> 8
    train = np.array([i for i in range(cfg.num_frames) if i not in held_out])
    lines = {k: line_fit(train.astype(np.float64), faults[k][train]) for k in STATE}
    rng = parser.radiometric_range()
    rows = []
    for frame in held_out:
        # the frame as the sensor recorded it, which `time` and `oracle` score against, dataset-normalised
        recorded = torch.from_numpy(rng.read(folder / "images" / f"frame_{frame:05d}.png"))
        clean, _ = clean_counts(camera_to_world(frame, cfg), cfg)
        row = {"frame": frame}
        for name, state in predicted_states(faults, train, lines, frame).items():
            rebuilt = torch.from_numpy(rng.normalize(sensor_counts(clean, faults, *state)))
            row[name] = float(psnr(rebuilt, recorded))
        rows.append(row)
    return rows


def report(bounds: Dict[str, List[dict]]) -> str:
    lines = [
        "A perfect model's held-out PSNR (dB, dataset-normalised, mean over held-out views (min–max)) with the "
        "frame's own sensor state, the state interpolated between its neighbouring training frames (the `time` "
        "protocol's rule), and a line fitted over the training frames' states; `own` - `neighbours`: the gap no "
        "model closes under the `time` protocol; `local`: a line through the "
        f"{LOCAL_FRAMES} training frames nearest in capture time.",
        "",
        "| scene | views | `own` (ceiling) | `neighbours` | `line` | `local` | `own` - `neighbours` | `own` - `line` "
        "| `own` - `local` |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for scene, rows in bounds.items():
        own, near, line, local = (np.array([r[k] for r in rows]) for k in PREDICTORS)
        lines.append(
            f"| {scene} | {len(rows)} | {mean_range(own)} | {mean_range(near)} | {mean_range(line)} "
            f"| {mean_range(local)} | {own.mean() - near.mean():.2f} | {own.mean() - line.mean():.2f} "
            f"| {own.mean() - local.mean():.2f} |"
        )
    lines += ["", "Per held-out view (`own` / `neighbours` / `line` / `local`):", ""]
    for scene, rows in bounds.items():
        cells = ", ".join(
            f"{r['frame']}: {r['own']:.1f} / {r['neighbours']:.1f} / {r['line']:.1f} / {r['local']:.1f}" for r in rows
        )
        lines.append(f"- {scene}: {cells}")
    return "\n".join(lines) + "\n"


def mse(psnr_db: float) -> float:
    """The mean squared error (data range 1) of a PSNR."""
    return 10 ** (-psnr_db / 10)


def gap_split(bounds: Dict[str, List[dict]], benches: Tuple[Path, ...]) -> str:
    """Each method's `time`, `oracle` and the `time` it would reach with the data's unpredictability as its
    only loss, per scene: mean (min–max) over its runs of the per-run means over held-out views."""
    runs: Dict[Tuple[str, str], List[dict]] = defaultdict(list)
    for path in benches:
        for run in json.loads(Path(path).read_text())["runs"]:
            runs[(run["scene"], run["method"])].append(run)
    lines = [
        "",
        "The measured gap split (`time` if the data were the only loss: each view's `oracle` error plus a perfect "
        "model's state error; mean (min–max) over runs):",
        "",
        "| scene | method | runs | `time` | `oracle` (bound) | data-only `time` | the data's share "
        "| the model's share |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for scene, rows in bounds.items():
        state_error = {r["frame"]: mse(r["neighbours"]) - mse(r["own"]) for r in rows}
        for (name, method), own_runs in runs.items():
            if name != scene_name(scene):
                continue
            time, oracle, data_only = [], [], []
            for run in own_runs:
                views = [v for v in run["per_view"] if v["frame"] in state_error]
                time.append(np.mean([v["psnr_time"] for v in views]))
                oracle.append(np.mean([v["psnr_oracle"] for v in views]))
                data_only.append(
                    np.mean([-10 * np.log10(mse(v["psnr_oracle"]) + state_error[v["frame"]]) for v in views])
                )
            time, oracle, data_only = np.array(time), np.array(oracle), np.array(data_only)
            lines.append(
                f"| {scene} | {method} | {len(own_runs)} | {mean_range(time)} | {mean_range(oracle)} | "
                f"{mean_range(data_only)} | {mean_range(oracle - data_only)} | {mean_range(data_only - time)} |"
            )
    return "\n".join(lines) + "\n"


def main(args: Args) -> Dict[str, List[dict]]:
    bounds = {scene: scene_bound(scene, args.work_dir) for scene in args.scenes}
    text = report(bounds) + (gap_split(bounds, args.bench) if args.bench else "")
    write_report(args.output, text)
    return bounds


if __name__ == "__main__":
    main(tyro.cli(Args))
