"""`python -m experiments.survey_timing`: the time from a survey folder to the °C map, phase by phase, as a user
runs the commands, with each phase's peak memory (host and GPU).

    python -m experiments.survey_timing --surveys survey:250 survey:1000 survey:4000 .data/flight2 \
      --output-dir outputs/survey_timing

Each phase runs in a fresh process (its peak memory is its own), through the command a user runs:
- `setup`: the thermal dataparser alone: every frame read and decoded, the radiometric range, the poses and the
  seed points (the layout's, or triangulated from the known poses), cached for the training;
- `train`: `ns-train wild-thermal` to its automatic stop (`--max-steps` caps it);
- `score`: `ns-eval` on the held-out frames (every protocol);
- `points`: `wild-thermal-export celsius-points`;
- `orthomosaic`: `wild-thermal-export orthomosaic` (a georeferenced capture only; otherwise listed as skipped).
A synthetic survey (`survey:N`, `data/survey_scene.py`) is generated first: not a phase a user meets, its
seconds are listed apart. Writes `survey_timing.json`, `survey_timing.md` and `survey_timing.png` (seconds per
phase, stacked, per survey) after every phase. Surveys timed in separate runs (one per device call, each within its
limit) are tabled together with `--merge A/survey_timing.json B/survey_timing.json --surveys` (nothing more timed);
a survey's phases timed in separate runs (`--phases`) join into its one row.
"""

from __future__ import annotations

import importlib
import json
import resource
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Dict, List, Optional

import tyro

PHASES = ("setup", "train", "score", "points", "orthomosaic")
ENTRY_POINTS = {  # the console scripts' functions (pyproject.toml, nerfstudio's)
    "ns-train": "nerfstudio.scripts.train:entrypoint",
    "ns-eval": "nerfstudio.scripts.eval:entrypoint",
    "wild-thermal-export": "thermal_wild_ns.export.commands:entrypoint",
}


@dataclass
class SurveyTimingArgs:
    surveys: List[str] = field(default_factory=lambda: ["survey:250"])
    """'survey:FRAMES' (the synthetic survey of that many frames) or survey folders (any supported layout,
    detected; 'LAYOUT:FOLDER' names one, e.g. metashape:DATA)."""
    output_dir: Path = Path("outputs/survey_timing")
    max_steps: Optional[int] = None
    """Training steps at most (default: the method's 30k, which its automatic stop ends sooner)."""
    train_options: str = ""
    """More `ns-train` options, one string (e.g. --train-options="--pipeline.datamanager.camera-res-scale-factor
    0.25")."""
    orthomosaic_options: str = ""
    """More `wild-thermal-export orthomosaic` options, one string (e.g. --orthomosaic-options="--ground-resolution
    0.1")."""
    phases: List[str] = field(default_factory=lambda: list(PHASES))
    """The phases to time, of setup, train, score, points, orthomosaic (each needs the ones before it to have run,
    here or in an earlier run into the same --output-dir); a row without the others is tabled as incomplete."""
    merge: List[Path] = field(default_factory=list)
    """`survey_timing.json` files of earlier runs (a survey per device call, each within its limit): their rows go
    into the table ahead of any timed here."""


def _peak_memory() -> Dict[str, float]:
    """This process's peak resident memory and, of its children, the largest's (MB); the GPU's peak allocated
    by torch (MB, 0 without CUDA)."""
    gpu = 0.0
    torch = sys.modules.get("torch")
    if torch is not None and torch.cuda.is_available():
        gpu = torch.cuda.max_memory_allocated() / 2**20
    return {
        "peak_host_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "peak_child_host_mb": round(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024, 1),
        "peak_gpu_mb": round(gpu, 1),
    }


def _child(record: Path, entry: str, argv: List[str]) -> None:
    """A phase's process: `entry` (module:function) run as its command with `argv`; its seconds and peak memory
    written to `record`, also when the command exits through SystemExit."""
    module, function = entry.split(":")
    sys.argv = argv
    start = time.perf_counter()
    code = 0
    try:
        getattr(importlib.import_module(module), function)()
    except SystemExit as end:
        code = end.code if isinstance(end.code, int) else (0 if end.code is None else 1)
    record.write_text(json.dumps({"seconds": round(time.perf_counter() - start, 2), **_peak_memory()}))
    sys.exit(code)


def setup_only(scene: str, output_dir: str, cache_dir: str) -> None:
    """The `setup` phase: the scene's dataparser read once, its caches written (`bench.scene_dataparser`)."""
    from experiments.scenes import scene_dataparser

    parser = scene_dataparser(scene, Path(output_dir), Path(cache_dir)).setup()
    parser.get_dataparser_outputs("train")


def _setup_entrypoint() -> None:
    setup_only(*sys.argv[1:4])


def run_phase(name: str, entry: str, argv: List[str], folder: Path) -> Dict:
    """One phase in a fresh process; its record, or a failure with the end of its log."""
    record, log = folder / f"{name}.json", folder / f"{name}.log"
    command = [sys.executable, "-m", "experiments.survey_timing", "--child", str(record), entry, *argv]
    with open(log, "w") as out:
        done = subprocess.run(command, stdout=out, stderr=subprocess.STDOUT)
    if done.returncode != 0 or not record.is_file():
        return {"failed": log.read_text()[-2000:]}
    return json.loads(record.read_text())


def dataparser_args(scene: str, cache: Path) -> List[str]:
    """`ns-train`'s dataparser subcommand and options for the scene (the same reading as `setup`'s)."""
    if scene.startswith("survey:"):
        frames = scene.split(":", 1)[1]
        return ["thermal-demo-data", "--scene", "survey", "--survey-frames", frames]
    from experiments.scenes import layout_and_folder

    layout, folder = layout_and_folder(scene)
    return ["thermal", "--data", folder, "--layout", layout, "--cache-dir", str(cache)]


def time_survey(scene: str, args: SurveyTimingArgs, on_phase: Callable[[Dict], None] = lambda row: None) -> Dict:
    """Every phase of one survey, in order; a phase that fails ends the survey's row. `on_phase(row)` after each
    phase (a run cut short keeps the phases it finished)."""
    from experiments.scenes import scene_name
    from thermal_wild_ns.data.survey_scene import SurveySceneConfig, generate_survey_scene

    name = scene_name(scene)
    folder = (args.output_dir / name).resolve()
    folder.mkdir(parents=True, exist_ok=True)
    cache = folder / "cache"
    row: Dict = {"survey": scene, "phases": {}}
    # a synthetic survey is generated before the phases (not a user's): once, by the run that sets it up; a run of the
    # later phases alone reads the frames it wrote (written again, they would be new files to the kept frame scan)
    if scene.startswith("survey:") and ("setup" in args.phases or not (folder / name).is_dir()):
        start = time.perf_counter()
        generate_survey_scene(folder / name, SurveySceneConfig(num_frames=int(scene.split(":", 1)[1])))
        row["generate_seconds"] = round(time.perf_counter() - start, 2)
    config = folder / "runs" / name / "wild-thermal" / "run" / "config.yml"
    train = ["ns-train", "wild-thermal", "--output-dir", str(folder / "runs"), "--experiment-name", name]
    train += ["--timestamp", "run", "--vis", "tensorboard", "--pipeline.datamanager.preprocessing-cache", str(cache)]
    if args.max_steps is not None:
        train += ["--max-num-iterations", str(args.max_steps)]
    train += shlex.split(args.train_options)
    data = dataparser_args(scene, cache)
    if scene.startswith("survey:"):
        data[1:1] = ["--data", str(folder / name)]
    export = ["wild-thermal-export"]
    phases = {
        "setup": ("experiments.survey_timing:_setup_entrypoint", ["setup", scene, str(folder), str(cache)]),
        "train": (ENTRY_POINTS["ns-train"], train + data),
        "score": (
            ENTRY_POINTS["ns-eval"],
            ["ns-eval", "--load-config", str(config), "--output-path", str(folder / "eval.json")],
        ),
        "points": (
            ENTRY_POINTS["wild-thermal-export"],
            export + ["celsius-points", "--load-config", str(config), "--output-path", str(folder / "points.ply")],
        ),
        "orthomosaic": (
            ENTRY_POINTS["wild-thermal-export"],
            export
            + ["orthomosaic", "--load-config", str(config), "--output-path", str(folder / "ortho.tif")]
            + shlex.split(args.orthomosaic_options),
        ),
    }
    for phase in PHASES:
        if phase not in args.phases:  # no record: the table shows the row as incomplete
            continue
        if phase == "orthomosaic" and not _georeferenced(config):
            row["phases"][phase] = {"skipped": "the capture has no georeference (its layout gives none)"}
            continue
        entry, argv = phases[phase]
        result = run_phase(phase, entry, argv, folder)
        row["phases"][phase] = result
        on_phase(row)
        print(f"{scene} {phase}: {json.dumps(result)[:300]}", flush=True)
        if "failed" in result:
            break
    return row


def _georeferenced(config: Path) -> bool:
    from thermal_wild_ns._upstream import prepare_checkpoint_commands
    from thermal_wild_ns.export.survey import run_georeference

    prepare_checkpoint_commands()
    return config.is_file() and run_georeference(config) is not None


def markdown(rows: List[Dict]) -> str:
    head = "| survey | " + " | ".join(f"{p} s (host / GPU MB)" for p in PHASES) + " | total s |"
    lines = [head, "|" + " --- |" * (len(PHASES) + 2)]
    for row in rows:
        cells, total = [], 0.0
        for phase in PHASES:
            r = row["phases"].get(phase)
            if r is None:
                cells.append("—")
            elif "skipped" in r:
                cells.append("skipped")
            elif "failed" in r:
                cells.append("failed")
            else:
                total += r["seconds"]
                cells.append(f"{r['seconds']:.1f} ({r['peak_host_mb']:.0f} / {r['peak_gpu_mb']:.0f})")
        generated = f" (generated in {row['generate_seconds']:.0f} s)" if "generate_seconds" in row else ""
        complete = all(cell not in ("failed", "—") for cell in cells)
        shown = f"{total:.1f}" if complete else f"{total:.1f} so far (incomplete)"
        lines.append(f"| {row['survey']}{generated} | " + " | ".join(cells) + f" | {shown} |")
    return "\n".join(lines) + "\n"


def chart(rows: List[Dict], path: Path) -> None:
    """Seconds per phase, stacked, one bar per survey."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 1.2 + 0.6 * len(rows)))
    left = [0.0] * len(rows)
    for phase in PHASES:
        widths = [row["phases"].get(phase, {}).get("seconds", 0.0) for row in rows]
        ax.barh([row["survey"] for row in rows], widths, left=left, label=phase)
        left = [a + b for a, b in zip(left, widths)]
    ax.set(xlabel="seconds (each phase a fresh process)", title="From a survey folder to the °C map")
    ax.invert_yaxis()
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.35), ncol=len(PHASES))
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)


def write_results(rows: List[Dict], output_dir: Path) -> None:
    """`survey_timing.json`, `.md` and `.png` of the rows so far."""
    (output_dir / "survey_timing.json").write_text(json.dumps(rows, indent=1))
    (output_dir / "survey_timing.md").write_text(markdown(rows))
    chart(rows, output_dir / "survey_timing.png")


def main(args: SurveyTimingArgs) -> List[Dict]:
    unknown = set(args.phases) - set(PHASES)
    if unknown:
        raise ValueError(f"--phases {sorted(unknown)}: each one of {', '.join(PHASES)}")
    args.output_dir.mkdir(parents=True, exist_ok=True)
    rows = [row for path in args.merge for row in json.loads(Path(path).read_text())]
    for scene in args.surveys:
        rows.append(time_survey(scene, args, lambda row: write_results(folded([*rows, row]), args.output_dir)))
    rows = folded(rows)
    write_results(rows, args.output_dir)
    print(markdown(rows))
    return rows


def folded(rows: List[Dict]) -> List[Dict]:
    """The rows of one survey (its phases timed in separate runs, `--phases`) joined into one, in the order the
    surveys first come; a phase timed again replaces its earlier record, other fields keep their first value."""
    joined: Dict[str, Dict] = {}
    for row in rows:
        into = joined.setdefault(row["survey"], {"survey": row["survey"], "phases": {}})
        into["phases"].update(row["phases"])
        for key, value in row.items():
            into.setdefault(key, value)
    return [{**row, "phases": {p: row["phases"][p] for p in PHASES if p in row["phases"]}} for row in joined.values()]


if __name__ == "__main__":
    if len(sys.argv) > 3 and sys.argv[1] == "--child":
        _child(Path(sys.argv[2]), sys.argv[3], sys.argv[4:])
    else:
        main(tyro.cli(SurveyTimingArgs))
