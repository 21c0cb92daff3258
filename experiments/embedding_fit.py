"""`python -m experiments.embedding_fit`: the time of one step of the `half` and `oracle` protocols' embedding fit
(`pipeline.evaluation.fit_embeddings`, `eval_fit_steps` of them in `ns-eval`, `eval_fit_views` views per render) on
a trained run's first `--views` held-out views, with the package on the path (this tree, or another commit's unpacked
in `.baseline/`: run from there to time it), and the embedding it ends at (to compare the two).

    python -m experiments.embedding_fit --load-config RUN/config.yml --output-path fit.json [--steps 5 --views 8]

Writes `--output-path` (ms per fit step of every round, per view too, the first embedding's first values, the
package's path) and prints ms per step, mean (min–max).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch
from nerfstudio.utils.eval_utils import eval_setup

import thermal_wild_ns
from experiments import mean_range
from thermal_wild_ns.pipeline.evaluation import Fit, fit_embeddings
from thermal_wild_ns.state_names import CANONICAL


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--load-config", type=Path, required=True)
    parser.add_argument("--output-path", type=Path, required=True)
    parser.add_argument("--steps", type=int, default=5, help="fit steps per round")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--views", type=int, default=1, help="held-out views fitted together, one render per step")
    args = parser.parse_args()
    _, pipeline, _, _ = eval_setup(args.load_config, test_mode="test")
    model = pipeline.model
    cameras = pipeline.datamanager.eval_dataset.cameras
    start = model.state_embedding(CANONICAL)
    fits = []
    for k in range(min(args.views, len(cameras))):
        camera = cameras[k : k + 1].to(model.device)
        target = torch.zeros(int(camera.height), int(camera.width), device=model.device)  # the time is asked
        fits.append(Fit(camera, target, slice(None), start))
    rounds, embedding = [], start
    for _ in range(args.rounds):
        began = time.perf_counter()
        embedding = fit_embeddings(model, fits, args.steps, 1e-2)[0]
        rounds.append(1000 * (time.perf_counter() - began) / args.steps)
    result = {
        "package": str(Path(thermal_wild_ns.__file__).parent),
        "view": f"{int(camera.width)}x{int(camera.height)}",
        "gaussians": int(model.num_points),
        "threads": torch.get_num_threads(),
        "views": len(fits),
        "ms_per_fit_step": rounds,
        "ms_per_fit_step_and_view": [ms / len(fits) for ms in rounds],
        "embedding_head": embedding[:4].tolist(),
    }
    args.output_path.parent.mkdir(parents=True, exist_ok=True)
    args.output_path.write_text(json.dumps(result, indent=1))
    size = f"{result['view']}, {len(fits)} view(s) a render, {result['gaussians']} Gaussians"
    print(f"{result['package']}: {mean_range(rounds)} ms per fit step ({size})")


if __name__ == "__main__":
    main()
