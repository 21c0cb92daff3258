"""Resuming from a checkpoint continues the same run: the same step, optimizer state, embeddings,
densification statistics and training order, so the parameters match the uninterrupted run."""

import json
import subprocess
import sys

import pytest
import torch
from test_model import unpack_mlp_state

from thermal_wild_ns.demo import demo_trainer_config
from thermal_wild_ns.model.wild_thermal import WildThermalModel

pytestmark = pytest.mark.slow  # trains through nerfstudio: minutes on a CPU


def _run(out, demo_scene_dir, steps, save_every, load_dir=None, auto_stop=False, lean_step=True):
    config = demo_trainer_config(out, steps=60, max_gaussians=3000)  # the same schedule for every run
    config.lean_step = lean_step
    config.auto_stop.enabled = auto_stop  # the automatic stop has its own test below
    config.auto_stop.check_every, config.auto_stop.patience = 10, 2
    config.pipeline.datamanager.dataparser.data = demo_scene_dir
    config.pipeline.model.densify_grad_thresh = (
        1e-9  # every Gaussian grows at step 10: the budget picks by the statistics
    )
    config.pipeline.model.stop_split_at = (
        60  # gsplat pauses refinement for 45 steps after start: one refinement, at step 50
    )
    config.max_num_iterations = steps
    config.steps_per_save = save_every
    config.save_only_latest_checkpoint = False
    config.load_dir = load_dir
    trainer = config.setup(local_rank=0, world_size=1)
    trainer.setup()
    trainer.train()
    return trainer


def _as_before_the_mlps_were_packed(checkpoints, out, model):
    """The last of `checkpoints` (a folder) written to `out` as a version before `PackedMLP` saved it: each
    MLP's layers as tensors of their own, in the model's state (`net.0.weight`, `net.0.bias`, ...) and in
    its optimizer's (a moment and a step count each, the optimizer's tensors numbered on)."""
    path = sorted(checkpoints.glob("*.ckpt"))[-1]
    state = torch.load(path, map_location="cpu", weights_only=False)
    unpack_mlp_state(model, state["pipeline"], prefix="_model.")
    for name in ("emission_mlp", "background_mlp"):
        net = getattr(model, name).net
        adam = state["optimizers"][name]
        (group,) = adam["param_groups"]
        at = [p is net.packed for p in getattr(model, name).parameters()].index(True)  # after a background's offset
        moments = [adam["state"][i] for i in group["params"]]
        layers = {key: net.layers(moments[at][key]) for key in ("exp_avg", "exp_avg_sq")}
        separate = [
            {"step": moments[at]["step"].clone(), **{key: layers[key][i][j].clone() for key in layers}}
            for i in range(len(net.shapes))
            for j in range(2)
        ]
        adam["state"] = dict(enumerate(moments[:at] + separate + moments[at + 1 :]))
        group["params"] = list(range(len(adam["state"])))
    out.mkdir(parents=True)
    torch.save(state, out / path.name)
    return out


def test_resume_reproduces_the_uninterrupted_run(tmp_path, demo_scene_dir):
    """Also from a checkpoint of a version before each MLP was one parameter (`PackedMLP`): its model and
    optimizer states load as they are now, and the run continues as the uninterrupted one."""
    torch.manual_seed(0)
    straight = _run(tmp_path / "a", demo_scene_dir, steps=60, save_every=1000)
    torch.manual_seed(0)
    first = _run(tmp_path / "b", demo_scene_dir, steps=30, save_every=1000)
    checkpoints = first.checkpoint_dir
    # a short run saves every 10 % of its steps (here every 3) whatever --steps-per-save says, and at its end
    assert sorted(p.name for p in checkpoints.glob("*.ckpt")) == [f"step-{s:09d}.ckpt" for s in (*range(3, 30, 3), 29)]
    torch.manual_seed(123)  # whatever the process did in between
    # --max-num-iterations is the total: resumed after step 29, the run trains steps 30..59
    resumed = _run(tmp_path / "c", demo_scene_dir, steps=60, save_every=1000, load_dir=checkpoints)
    assert resumed._start_step == 30
    before = _as_before_the_mlps_were_packed(checkpoints, tmp_path / "before", first.pipeline.model)
    torch.manual_seed(123)
    resumed_before = _run(tmp_path / "d", demo_scene_dir, steps=60, save_every=1000, load_dir=before)
    assert resumed_before._start_step == 30
    a = straight.pipeline.model
    for b in (resumed.pipeline.model, resumed_before.pipeline.model):
        assert a.num_points == b.num_points != 2340  # the refinement at step 50 grew and pruned alike
        for (name, pa), (_, pb) in zip(a.named_parameters(), b.named_parameters()):
            torch.testing.assert_close(pa, pb, msg=name)


def test_the_lean_step_trains_exactly_as_nerfstudios_step(tmp_path, demo_scene_dir):
    """The same 60 steps (densification, pruning and an opacity reset among them) through the
    trainer's lean step and through nerfstudio's `Trainer.train_iteration`: the same parameters
    and optimizer states, bit for bit."""
    runs = {}
    for lean in (True, False):
        torch.manual_seed(0)
        runs[lean] = _run(tmp_path / str(lean), demo_scene_dir, steps=60, save_every=1000, lean_step=lean)
    assert runs[True].lean and not runs[False].lean
    a, b = runs[True].pipeline.model, runs[False].pipeline.model
    assert a.num_points == b.num_points != 2340
    for (name, pa), (_, pb) in zip(a.named_parameters(), b.named_parameters()):
        assert torch.equal(pa, pb), name
    for name, optimizer in runs[True].optimizers.optimizers.items():
        reference = runs[False].optimizers.optimizers[name]
        for p, q in zip(optimizer.param_groups[0]["params"], reference.param_groups[0]["params"]):
            for key, value in optimizer.state[p].items():
                assert torch.equal(value, reference.state[q][key]), (name, key)


def test_the_lean_step_computes_metrics_at_log_steps_and_resizes_a_frame_once_per_size(
    tmp_path, demo_scene_dir, monkeypatch
):
    """The lean step asks the pipeline for the step's metrics (the training PSNR) at nerfstudio's log steps
    alone, and gets them there; during the resolution warm-up each training frame is resized once per size
    (the datamanager hands the same tensor again), and the losses see the resized frame as splatfacto's
    `get_gt_img` gives it."""
    from thermal_wild_ns.pipeline.thermal_pipeline import ThermalPipeline

    config = demo_trainer_config(tmp_path, steps=60, max_gaussians=3000)
    config.pipeline.datamanager.dataparser.data = demo_scene_dir
    config.pipeline.model.num_downscales, config.pipeline.model.resolution_schedule = 1, 50  # 1/2 size to step 49
    config.logging.steps_per_log = 5
    config.auto_stop.enabled = False
    asked, resized = [], []
    original_losses = ThermalPipeline.get_train_loss_dict
    original_resize = WildThermalModel.get_gt_img

    def get_train_loss_dict(self, step, metrics=True):
        outputs, losses, metrics_dict = original_losses(self, step, metrics=metrics)
        asked.append((step, metrics, "psnr" in metrics_dict))
        return outputs, losses, metrics_dict

    def get_gt_img(self, image):
        gt = original_resize(self, image)
        if self.training:
            resized.append((self.step, self._get_downscale_factor(), id(image), tuple(gt.shape)))
        return gt

    monkeypatch.setattr(ThermalPipeline, "get_train_loss_dict", get_train_loss_dict)
    monkeypatch.setattr(WildThermalModel, "get_gt_img", get_gt_img)
    trainer = config.setup(local_rank=0, world_size=1)
    trainer.setup()
    trainer.train()
    assert trainer.lean
    assert [(step, metrics) for step, metrics, _ in asked] == [(s, s % 5 == 0) for s in range(60)]
    assert all(found == metrics for _, metrics, found in asked)
    half = [r for r in resized if r[1] == 2]
    frames = {frame for _, _, frame, _ in half}
    assert half and len(half) == len(frames) < 50  # 50 steps at 1/2 size revisit frames, each resized once
    height, width = (
        trainer.pipeline.datamanager.train_dataset.cameras[0].height,
        trainer.pipeline.datamanager.train_dataset.cameras[0].width,
    )
    assert {shape for *_, shape in half} == {(int(height) // 2, int(width) // 2, 1)}
    assert len([r for r in resized if r[1] == 1]) == 10  # full size: no copy kept, the frame itself each step


def test_resume_continues_the_automatic_stop(tmp_path, demo_scene_dir, monkeypatch):
    """A run with the automatic stop, cut at step 29 (where it keeps its best model, of step 19) and
    resumed, trains on from the state it had trained, remembers its checks and its best model, and
    ends as the uninterrupted run does: stopped at step 39, the model of step 19 kept."""
    scores = {9: 20.0, 19: 25.0, 29: 24.0, 39: 24.5}  # best at 19; 29 and 39 bring no rise: stop at 39
    monkeypatch.setattr(
        "thermal_wild_ns.training.auto_stop.held_back_score", lambda pipeline, images: scores[pipeline.model.step]
    )
    monkeypatch.setattr(WildThermalModel, "settled_step", property(lambda self: 0))  # checks from step 0

    def run(out, steps, load_dir=None):
        trainer = _run(out, demo_scene_dir, steps=steps, save_every=1000, load_dir=load_dir, auto_stop=True)
        record = json.loads((trainer.config.get_base_dir() / "auto_stop.json").read_text())
        return trainer, record

    torch.manual_seed(0)
    straight, straight_record = run(tmp_path / "a", 60)
    torch.manual_seed(0)
    first, first_record = run(tmp_path / "b", 30)
    assert first_record["kept_step"] == 19 and first_record["last_step"] == 29
    torch.manual_seed(123)
    resumed, resumed_record = run(tmp_path / "c", 60, load_dir=first.checkpoint_dir)
    assert straight_record["stopped_early"] and straight_record["last_step"] == 39
    for key in ("stopped_early", "last_step", "kept_step", "checks", "reason"):
        assert resumed_record[key] == straight_record[key], key
    assert resumed_record["kept_step"] == 19
    models = straight.pipeline.model, resumed.pipeline.model
    for (name, pa), (_, pb) in zip(models[0].named_parameters(), models[1].named_parameters()):
        torch.testing.assert_close(pa, pb, msg=name)


def test_resume_stops_at_the_total_and_a_missing_load_dir_is_one_line(tmp_path, demo_scene_dir):
    first = _run(tmp_path / "b", demo_scene_dir, steps=12, save_every=1000)
    done = _run(tmp_path / "c", demo_scene_dir, steps=12, save_every=1000, load_dir=first.checkpoint_dir)
    assert done._start_step == 12 and not list((tmp_path / "c").rglob("*.ckpt"))  # nothing left to train
    with pytest.raises(SystemExit, match=r"--load-dir .*nowhere: no such folder"):
        _run(tmp_path / "d", demo_scene_dir, steps=12, save_every=1000, load_dir=tmp_path / "nowhere")
    # through ns-train: the message, exit status 1, no traceback
    ns_train = [str(__import__("pathlib").Path(sys.executable).parent / "ns-train"), "wild-thermal"]
    result = subprocess.run(
        [
            *ns_train,
            "--load-dir",
            str(tmp_path / "nowhere"),
            "--output-dir",
            str(tmp_path / "e"),
            "--vis",
            "tensorboard",
        ],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp_path,
    )
    assert result.returncode == 1 and "no such folder" in result.stderr and "Traceback" not in result.stderr
