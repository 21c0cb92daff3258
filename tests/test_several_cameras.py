"""Several training cameras per step (`--pipeline.cameras-per-step`): a run through `ns-train` with the
method's defaults to its final checkpoint, each step trains that many distinct frames of the order (the
schedule counting frames: `--max-num-iterations` of them in 1/that many steps, said in decisions.json), and
the pipeline refuses what it cannot batch, saying why."""

import json
from types import SimpleNamespace

import pytest
import torch
import yaml
from nerfstudio.cameras.cameras import Cameras
from ns_runs import STEPS, check_run_end_to_end, ns_train, run_args

from thermal_wild_ns.errors import InputError
from thermal_wild_ns.pipeline.datamanager import ThermalDatamanager
from thermal_wild_ns.pipeline.thermal_pipeline import ThermalPipeline

pytestmark = pytest.mark.slow  # trains through nerfstudio


def test_a_run_of_two_cameras_per_step_trains_to_its_final_checkpoint(tmp_path, demo_scene_dir, monkeypatch):
    steps = []
    original = ThermalDatamanager.next_train_cameras

    def record(self, step, count):
        pairs = original(self, step, count)
        steps.append([int(camera.metadata["cam_idx"]) for camera, _ in pairs])
        return pairs

    monkeypatch.setattr(ThermalDatamanager, "next_train_cameras", record)
    out = tmp_path / "out"
    frames = 2 * STEPS  # the schedule counts training frames: STEPS steps of two
    config = ns_train(
        [*run_args(out, frames, "--pipeline.cameras-per-step", "2"), "thermal-demo-data", "--data", str(demo_scene_dir)]
    )
    assert config.pipeline.cameras_per_step == 2 and config.pipeline.model.num_downscales > 0  # the warm-up on
    assert len(steps) == STEPS and all(len(set(images)) == 2 for images in steps)
    run = out / "x" / "wild-thermal" / "run"
    check_run_end_to_end(run, tmp_path, steps=STEPS)
    saved = yaml.load((run / "config.yml").read_text(), Loader=yaml.Loader)
    assert saved.max_num_iterations == frames  # config.yml holds the frames asked; the trainer ran them in steps
    decisions = {d["part"]: d for d in json.loads((run / "decisions.json").read_text())}
    assert decisions["training frames per step"]["choice"] == "2"
    assert f"at most {STEPS:,} steps" in decisions["training frames per step"]["why"]


def test_several_cameras_per_step_are_refused_where_they_cannot_be_batched():
    def pipeline(model, world=1, widths=(48, 48)):
        cameras = Cameras(
            camera_to_worlds=torch.eye(4)[None, :3].repeat(len(widths), 1, 1),
            fx=50.0,
            fy=50.0,
            cx=24.0,
            cy=16.0,
            width=torch.tensor(widths)[:, None],
            height=32,
        )
        datamanager = SimpleNamespace(
            ranks=SimpleNamespace(world=world), train_dataset=SimpleNamespace(cameras=cameras)
        )
        return SimpleNamespace(model=model, datamanager=datamanager)

    batching = SimpleNamespace(get_training_outputs=print, get_training_metrics_and_losses=print)
    ThermalPipeline._check_several_cameras(pipeline(batching), 2)  # nothing to refuse
    for fake, count, why in [
        (pipeline(batching), 0, "at least 1"),
        (pipeline(SimpleNamespace()), 2, "renders one camera per step"),
        (pipeline(batching, world=2), 2, "multi-GPU"),
        (pipeline(batching, widths=(48, 24)), 2, r"differ in size \(24x32, 48x32\)"),
    ]:
        with pytest.raises(InputError, match=rf"cameras-per-step {count}: .*{why}"):
            ThermalPipeline._check_several_cameras(fake, count)
