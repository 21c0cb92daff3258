"""The tables of docs/results/view_trial_gpu/README.md (printed) from the *-bench.json files of its
`plain/` and `radial/` folders: per scene and rule, each run's verdict on the view term on trial and
the held-out scores.

python -m experiments.view_trial_table docs/results/view_trial_gpu
"""

import json
import sys
from pathlib import Path

from experiments import mean_range

COLUMNS = ["scene", "rule", "seeds", "kept", "held-back gain with the term (dB, each seed)", "`novel`", "`time`"]
COLUMNS += ["`aligned`"]


def main(folder: Path) -> None:
    print("| " + " | ".join(COLUMNS) + " |")
    print("|" + " --- |" * len(COLUMNS))
    for rule in ("plain", "radial"):
        for path in sorted((folder / rule).glob("*-bench.json")):
            runs_all = json.loads(path.read_text())["runs"]
            label = "defaults (no term)" if "default" in path.name else f"trial, {rule} score"
            for scene in dict.fromkeys(r["scene"] for r in runs_all):
                runs = [r for r in runs_all if r["scene"] == scene]
                verdicts = [(r.get("auto_stop") or {}).get("view_term") for r in runs]
                if all(v is None for v in verdicts):
                    kept, gains = "—", "—"
                else:
                    kept = f"{sum(v['kept'] for v in verdicts)}/{len(verdicts)}"
                    gains = ", ".join(f"{v['with_term'] - v['without']:+.2f}" for v in verdicts)
                scores = [mean_range([r[f"psnr_{p}"] for r in runs]) for p in ("novel", "time", "aligned")]
                print("| " + " | ".join([scene, label, str(len(runs)), kept, gains, *scores]) + " |")


if __name__ == "__main__":
    main(Path(sys.argv[1]))
