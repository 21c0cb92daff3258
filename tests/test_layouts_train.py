"""Every registered dataparser trains end to end: `ns-train wild-thermal <parser> --data FIXTURE`
on CPU, parsed by nerfstudio's own command line, for a few steps. The layout tests
(test_data_layouts.py) check poses and splits; this checks that training consumes what the
readers give (a COLMAP reader's float64 intrinsics once crashed every COLMAP layout at step 0)."""

from __future__ import annotations

import layout_fixtures as fx
import numpy as np
import pytest
import torch

pytestmark = pytest.mark.slow  # trains through nerfstudio: minutes on a CPU

STEPS = 12

# registered parser -> (fixture writer, folder name); 'thermal' detects the layout itself
PARSERS = {
    "thermal": (fx.write_colmap, "scene"),
    "thermal-nerfstudio-data": (fx.write_nerfstudio, "scene"),
    "thermalnerf-data": (fx.write_thermalnerf, "scene"),
    "ye-thermal-data": (fx.write_ye, "seq01"),
    "msx-data": (fx.write_msx, "scene"),
    "thermalmix-data": (fx.write_thermalmix, "lion"),
    "mvtv-data": (lambda root: fx.write_llff(root, folder="thermal"), "scene"),
    "llff-thermal-data": (fx.write_llff, "scene"),
    "thermal-colmap-data": (fx.write_colmap, "scene"),
    "ti-nsd-data": (fx.write_colmap, "scene"),
    "thermal-demo-data": (None, "scene"),
}


def ns_train(args):
    """`ns-train ARGS` in this process: nerfstudio's own parser and train main."""
    import tyro
    from nerfstudio.configs.method_configs import AnnotatedBaseConfigUnion
    from nerfstudio.scripts.train import main

    config = tyro.cli(AnnotatedBaseConfigUnion, args=args)
    main(config)
    return config


def test_every_registered_parser_has_a_case():
    from nerfstudio.plugins.registry_dataparser import discover_dataparsers

    ours = {
        name for name, spec in discover_dataparsers()[0].items() if type(spec).__module__.startswith("thermal_wild_ns")
    }
    assert ours == set(PARSERS)


@pytest.mark.parametrize("parser", sorted(PARSERS))
def test_parser_trains_end_to_end(parser, tmp_path):
    writer, folder = PARSERS[parser]
    root = tmp_path / "data" / folder
    if writer is not None:
        writer(root)
    out = tmp_path / "out"
    config = ns_train(
        [
            "wild-thermal",
            "--max-num-iterations",
            str(STEPS),
            "--vis",
            "tensorboard",
            "--output-dir",
            str(out),
            "--experiment-name",
            "x",
            "--timestamp",
            "run",
            "--steps-per-save",
            str(STEPS),
            "--pipeline.model.max-gaussians",
            "3000",
            "--pipeline.model.num-downscales",
            "0",
            "--pipeline.datamanager.preprocessing-cache",
            str(tmp_path / "cache"),
            parser,
            "--data",
            str(root),
            "--num-random-points",
            "400",
        ]
    )
    checkpoint = sorted((out / "x" / "wild-thermal" / "run" / "nerfstudio_models").glob("step-*.ckpt"))
    assert checkpoint, "no checkpoint written"
    state = torch.load(checkpoint[-1], map_location="cpu")
    assert state["step"] == STEPS - 1
    means = state["pipeline"]["_model.gauss_params.means"]
    assert means.dtype == torch.float32 and means.shape[0] >= 4 and bool(torch.isfinite(means).all())
    layout = config.pipeline.datamanager.dataparser.layout
    assert layout == ("auto" if parser == "thermal" else layout)
    assert np.isfinite(float(state["pipeline"]["_model.gauss_params.opacities"].mean()))
