"""`python -m experiments.canonical_background BENCH_DIR`: does the canonical state lose `aligned` because its fit
leaves the background out? Every run of a bench scored (`novel`, `aligned`) at the model's `typical` state and at
a typical state fitted on the background too.

The typical state (docs/design.md, "The canonical state") matches the training frames' mean emission of the
Gaussians only; the background MLP b(d, e) takes the same state, and nothing asks its value under that state to be
the frames' mean background. Where a frame shows much background (the generated scenes' sky) a render at the
canonical state may then put the sky and the scene in a relation no frame had, which a gain and offset per view
(`aligned`) cannot undo. The second state adds the background along the training cameras' pixel directions where
the Gaussians leave it visible (1 - alpha), as many samples as its share of the training pixels asks, to the same
least-squares fit (`frame_states.typical_state`). Each run in its own process (as `experiments.score_checkpoint`);
writes `canonical_background.jsonl` and `.md` into BENCH_DIR and prints the table;
`python -m experiments.canonical_background --table JSONL...` prints one table of several benches' lines.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Dict, List

import torch

from experiments import json_from_module, mean_range

PROTOCOLS = ("novel", "aligned")
STATES = ("typical", "typical+background")


def background_samples(pipeline, count_per_gaussian_sample: int, generator: torch.Generator):
    """Unit directions [M, 3] where the training frames show the background, drawn with weight 1 - alpha, and the
    background's share of the training pixels (M = that share / (1 - share) per Gaussian sample)."""
    from thermal_wild_ns.model.camera_views import ray_directions

    model = pipeline.model
    cameras = pipeline.datamanager.train_dataset.cameras.to(model.device)
    stride = model.config.background_stride  # the background's grid
    dirs, weights = [], []
    with torch.no_grad():
        for i in range(len(cameras)):
            camera = cameras[i : i + 1]
            alpha = model.get_outputs(camera)["accumulation"][..., 0]  # [H, W]
            H, W = alpha.shape
            pooled = torch.nn.functional.avg_pool2d(alpha[None, None], stride, ceil_mode=True)[0, 0]  # [h, w]
            K = camera.get_intrinsics_matrices()[0].to(model.device)
            d = ray_directions(K, camera.camera_to_worlds[0], W, H, stride)  # [h, w, 3]
            dirs.append(d.reshape(-1, 3))
            weights.append((1.0 - pooled).clamp(min=0).reshape(-1))
    dirs, weights = torch.cat(dirs), torch.cat(weights)
    share = float(weights.mean())
    count = min(int(round(count_per_gaussian_sample * share / max(1.0 - share, 1e-3))), 65536)
    if count == 0 or float(weights.sum()) == 0.0:
        return dirs[:0], share
    pick = torch.multinomial(weights.cpu(), count, replacement=True, generator=generator).to(dirs.device)
    return dirs[pick], share


def score(config: str, state: str) -> Dict:
    return json_from_module("experiments.canonical_background", "--one", config, state)


def score_one(config: Path, state: str) -> None:
    from nerfstudio.utils.eval_utils import eval_setup

    from thermal_wild_ns._upstream import prepare_checkpoint_commands
    from thermal_wild_ns.pipeline.evaluation import evaluate

    prepare_checkpoint_commands()
    _, pipeline, _, _ = eval_setup(config, test_mode="test")
    model = pipeline.model
    model.config.canonical_embedding = "typical"
    extra = {}
    if state == "typical+background" and model.background_mlp is not None:
        emission = model.typical_emission()
        n = int(emission(model.frame_embed.weight[0].detach()).shape[0])
        dirs, share = background_samples(pipeline, n, torch.Generator().manual_seed(0))
        encoded = model.background_mlp.encode(dirs).detach()  # [M, 16]

        def with_background(state_embed):
            background = model.background_mlp.from_encoded(encoded, state_embed)[..., 0]  # [M]
            return torch.cat([emission(state_embed), background])

        model.typical_emission = lambda: with_background
        model.frame_states._cache.clear()
        extra = {"background_share": share, "background_samples": int(dirs.shape[0]), "gaussian_samples": n}
    scores = evaluate(pipeline, protocols=PROTOCOLS)
    print(json.dumps({**{k: v for k, v in scores.items() if not isinstance(v, (list, dict))}, **extra}))


def table(rows: List[Dict]) -> str:
    lines = [
        "| scene | canonical state | seeds | `novel` PSNR | `aligned` PSNR (a fit) | Δ `novel` (paired, per seed) "
        "| Δ `aligned` (paired) |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for scene in dict.fromkeys(r["scene"] for r in rows):
        base = {r["seed"]: r for r in rows if r["scene"] == scene and r["canonical"] == STATES[0]}
        for state in STATES:
            runs = [r for r in rows if r["scene"] == scene and r["canonical"] == state]
            novel = ", ".join(f"{r['psnr_novel'] - base[r['seed']]['psnr_novel']:+.2f}" for r in runs)
            delta = mean_range([r["psnr_aligned"] - base[r["seed"]]["psnr_aligned"] for r in runs])
            cells = [mean_range([r[f"psnr_{p}"] for r in runs]) for p in PROTOCOLS]
            lines.append(f"| {scene} | {state} | {len(runs)} | " + " | ".join(cells) + f" | {novel} | {delta} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    if sys.argv[1:2] == ["--one"]:
        score_one(Path(sys.argv[2]), sys.argv[3])
        return
    if sys.argv[1:2] == ["--table"]:  # the table of several benches' canonical_background.jsonl files
        print(table([json.loads(line) for path in sys.argv[2:] for line in Path(path).read_text().splitlines()]))
        return
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("bench_dir", type=Path, help="an experiments.bench output folder (its bench.json)")
    args = parser.parse_args()
    runs = json.loads((args.bench_dir / "bench.json").read_text())["runs"]
    rows = []
    for run in runs:
        for state in STATES:
            rows.append({"scene": run["scene"], "seed": run["seed"], "canonical": state, **score(run["config"], state)})
            print(
                f"{run['scene']} seed {run['seed']} {state}: aligned {rows[-1]['psnr_aligned']:.2f} dB", file=sys.stderr
            )
    (args.bench_dir / "canonical_background.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    markdown = table(rows)
    (args.bench_dir / "canonical_background.md").write_text(markdown)
    print(markdown)


if __name__ == "__main__":
    main()
