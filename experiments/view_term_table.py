"""The table of docs/results/view_term_gpu/README.md (printed) from the *-bench.json files of that folder.

python -m experiments.view_term_table docs/results/view_term_gpu
"""

import json
import sys
from pathlib import Path

import numpy as np

from experiments import mean_range

FILES = {
    "flight2": ["flight2-default", "flight2-sh1", "flight2-sh2", "flight2-auto", "flight2-splatfacto"],
    "dunr": ["dunr-default", "dunr-sh1", "dunr-sh2", "dunr-auto", "dunr-splatfacto"],
    "synthetic": ["synthetic-default", "synthetic-view-default", "synthetic-sh2", "synthetic-auto"],
}
LABELS = {
    "default": "wild-thermal (defaults)",
    "sh1": "wild-thermal, view_sh_degree=1",
    "sh2": "wild-thermal, view_sh_degree=2",
    "auto": "wild-thermal, view_sh_degree=2, zero-test rule (kept in every run)",
    "view-default": "wild-thermal (defaults)",
    "splatfacto": "splatfacto (first 10k steps of 30k)",
}
COLUMNS = ["scene", "configuration", "seeds", "`novel`", "`time`", "`aligned`", "`oracle` (a bound)", "steps"]
COLUMNS += ["Gaussians", "ms/step (shared)"]


def main(folder: Path) -> None:
    print("| " + " | ".join(COLUMNS) + " |")
    print("|" + " --- |" * len(COLUMNS))
    for names in FILES.values():
        for name in names:
            runs_all = json.loads((folder / f"{name}-bench.json").read_text())["runs"]
            for scene in dict.fromkeys(r["scene"] for r in runs_all):
                runs = [r for r in runs_all if r["scene"] == scene]
                label = LABELS[name.split("-", 1)[1]]
                cols = [mean_range([r[f"psnr_{p}"] for r in runs]) for p in ("novel", "time", "aligned", "oracle")]
                if label.startswith("splatfacto"):  # no photometric state: `time` is `novel`, no oracle
                    cols[1] = cols[3] = "—"
                steps = int(np.mean([r["steps"] for r in runs]))
                gaussians = int(np.mean([r["gaussians"] for r in runs]))
                ms = np.mean([r["ms_per_step"] for r in runs])
                row = [scene, label, str(len(runs)), *cols, str(steps), str(gaussians), f"{ms:.1f}"]
                print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    main(Path(sys.argv[1]))
