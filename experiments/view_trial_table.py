"""Per scene and rule, each run's verdict on the view term on trial and the held-out scores, from bench.json
files: the tables of docs/results/view_trial_gpu/README.md (its `plain/` and `radial/` folders) or of any
bench files named (each labelled by its file name, with the radial share each verdict saw).

    python -m experiments.view_trial_table docs/results/view_trial_gpu
    python -m experiments.view_trial_table A-bench.json B-bench.json ...
"""

import json
import sys
from pathlib import Path
from typing import List, Tuple

from experiments import mean_range

COLUMNS = ["scene", "rule", "seeds", "kept", "held-back gain with the term (dB, each seed)"]
SCORES = ["`novel`", "`time`", "`aligned` (a fit)"]


def rows(path: Path, label: str, shares: bool) -> List[List[str]]:
    """One row per scene of one bench.json."""
    runs_all = json.loads(path.read_text())["runs"]
    found = []
    for scene in dict.fromkeys(r["scene"] for r in runs_all):
        runs = sorted((r for r in runs_all if r["scene"] == scene), key=lambda r: r["seed"])
        verdicts = [(r.get("auto_stop") or {}).get("view_term") for r in runs]
        if all(v is None for v in verdicts):
            kept, gains, share = "—", "—", "—"
        else:
            decided = [v for v in verdicts if v is not None]
            kept = f"{sum(v['kept'] for v in decided)}/{len(verdicts)}"
            gains = ", ".join(f"{v['with_term'] - v['without']:+.2f}" for v in decided)
            share = ", ".join("—" if v.get("radial_share") is None else f"{v['radial_share']:.3f}" for v in decided)
        scores = [mean_range([r[f"psnr_{p}"] for r in runs]) for p in ("novel", "time", "aligned")]
        found.append([scene, label, str(len(runs)), kept, gains] + ([share] if shares else []) + scores)
    return found


def main(paths: List[Path]) -> None:
    if len(paths) == 1 and paths[0].is_dir():  # view_trial_gpu's folders
        folder = paths[0]
        files: List[Tuple[Path, str]] = []
        for rule in ("plain", "radial"):
            for path in sorted((folder / rule).glob("*-bench.json")):
                files.append((path, "defaults (no term)" if "default" in path.name else f"trial, {rule} score"))
        shares = False
    else:
        files, shares = [(path, path.name) for path in paths], True
    columns = COLUMNS + (["radial share (each seed)"] if shares else []) + SCORES
    print("| " + " | ".join(columns) + " |")
    print("|" + " --- |" * len(columns))
    for path, label in files:
        for row in rows(path, label, shares):
            print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    main([Path(a) for a in sys.argv[1:]])
