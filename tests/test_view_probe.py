"""The held-back frames decide the view term (`training/view_probe.py`): kept where the capture's
radiance changes with the view, off where what looks like it is each frame's own noise; through a
run, held at zero until the first scored check, recorded, reported and replayed on resume."""

import json
import math

import torch
from layout_fixtures import cameras as arc_poses
from layout_fixtures import opengl
from nerfstudio.cameras.cameras import Cameras
from test_model import make_model

from thermal_wild_ns.demo import demo_trainer_config
from thermal_wild_ns.model.wild_thermal import WildThermalModel
from thermal_wild_ns.training.trainer import seeded_trainer
from thermal_wild_ns.training.view_probe import probe_view_term

WIDTH, HEIGHT = 48, 32


def arc_cameras(n: int):
    """`n` cameras on the layout fixtures' arc around the origin (OpenGL, as nerfstudio's), 48x32."""
    cameras = []
    for k, c2w in enumerate(arc_poses(n, radius=3.0)):
        pose = torch.from_numpy(opengl(c2w)[:3]).float()[None]  # [1, 3, 4]
        camera = Cameras(
            camera_to_worlds=pose, fx=40.0, fy=40.0, cx=WIDTH / 2, cy=HEIGHT / 2, width=WIDTH, height=HEIGHT
        )
        camera.metadata = {"cam_idx": k}
        cameras.append(camera)
    return cameras


def scalar_model(frames: int) -> WildThermalModel:
    """Plain scalar emission with a degree-2 view term (zero): the same Gaussians at every call."""
    torch.manual_seed(0)  # their rotations are drawn from torch's generator
    return make_model(n=300, frames=frames, use_emission_mlp=False, use_background_mlp=False, view_sh_degree=2)


def render(model, camera) -> torch.Tensor:
    model.eval()
    with torch.no_grad():
        return model.get_outputs(camera)["thermal"]


def probe_on(truth_view: bool, frame_noise: float):
    """The probe on a model that has the truth's Gaussians exactly and no view term; the truth has
    one (`truth_view`) or not, and each frame adds its own noise of `frame_noise`."""
    held = [3, 8, 13]  # between training views, as the automatic stop holds frames back
    train = [k for k in range(16) if k not in held]
    truth_model = scalar_model(16)
    if truth_view:
        with torch.no_grad():
            truth_model.gauss_params["view_sh"].normal_(0, 0.3, generator=torch.Generator().manual_seed(1))
    g = torch.Generator().manual_seed(2)
    cameras = arc_cameras(16)
    truth = [render(truth_model, c) + frame_noise * torch.randn(HEIGHT, WIDTH, 1, generator=g) for c in cameras]
    model = scalar_model(16)
    assert torch.equal(model.quats, truth_model.quats)  # the truth's Gaussians exactly
    order = torch.Generator().manual_seed(3)

    def training_loss():
        k = train[int(torch.randint(len(train), (1,), generator=order))]
        model.train()
        outputs = model.get_outputs(cameras[k])
        return sum(model.get_loss_dict(outputs, {"image": truth[k], "image_idx": k}).values())

    def score():
        errors = [float(((render(model, cameras[k]) - truth[k]) ** 2).mean()) for k in held]
        return float(sum(-10 * math.log10(e) for e in errors) / len(errors))

    return probe_view_term(model.gauss_params["view_sh"], training_loss, score, 60, 2e-2, 0.05, step=0)


def test_the_view_term_is_kept_where_the_radiance_changes_with_the_view():
    verdict = probe_on(truth_view=True, frame_noise=0.01)
    assert verdict.kept and verdict.with_term > verdict.without + 1.0, verdict


def test_the_view_term_stays_off_where_the_training_views_differ_by_their_own_noise():
    verdict = probe_on(truth_view=False, frame_noise=0.05)
    assert not verdict.kept and verdict.with_term < verdict.without + 0.05, verdict


def _run(tmp_path, demo_scene_dir, monkeypatch, scores, steps=12):
    """The demo with a degree-2 view term decided by the held-back frames at the first check (step
    3), whose scores follow `scores` (one per call: without the term, with it, then one per check)."""
    config = demo_trainer_config(tmp_path, steps=steps, max_gaussians=3000)
    config.pipeline.datamanager.dataparser.data = demo_scene_dir
    config.pipeline.model.view_sh_degree = 2
    config.auto_stop.check_every, config.auto_stop.patience = 4, 10
    config.auto_stop.decide_view_term, config.auto_stop.view_probe_steps = True, 3
    calls = iter(scores)
    monkeypatch.setattr("thermal_wild_ns.training.auto_stop.held_back_score", lambda pipeline, images: next(calls))
    monkeypatch.setattr(WildThermalModel, "settled_step", property(lambda self: 0))
    seen = []
    probe = probe_view_term

    def watched(coefficients, *args, **kwargs):
        seen.append(float(coefficients.abs().max()))  # before the probe: trained with the term held at zero
        return probe(coefficients, *args, **kwargs)

    monkeypatch.setattr("thermal_wild_ns.training.auto_stop.probe_view_term", watched)
    trainer = seeded_trainer(config)
    trainer.train()
    run = trainer.config.get_base_dir()
    decisions = json.loads((run / "decisions.json").read_text())
    entry = next(d for d in decisions if d["part"] == "view-dependent emission")
    return trainer, json.loads((run / "auto_stop.json").read_text())["view_term"], entry, seen


def test_a_run_keeps_the_view_term_its_held_back_frames_gain_from(tmp_path, demo_scene_dir, monkeypatch):
    trainer, verdict, entry, seen = _run(tmp_path, demo_scene_dir, monkeypatch, [20.0, 20.5, 21.0, 22.0])
    assert seen == [0.0] and verdict["step"] == 3 and verdict["kept"]
    assert entry["choice"] == "on" and entry["decided_by"] == "data" and "20.00 -> 20.50" in entry["why"]
    assert trainer.pipeline.model.gauss_params["view_sh"].abs().max() > 0  # fitted, then trained


def test_a_run_drops_the_view_term_its_held_back_frames_do_not_gain_from(tmp_path, demo_scene_dir, monkeypatch):
    trainer, verdict, entry, seen = _run(tmp_path, demo_scene_dir, monkeypatch, [20.0, 20.01, 21.0, 22.0])
    assert seen == [0.0] and verdict["step"] == 3 and not verdict["kept"]
    assert entry["choice"] == "off" and entry["decided_by"] == "data"
    assert trainer.pipeline.model.gauss_params["view_sh"].abs().max() == 0  # zero after 8 more steps
    # a resumed run keeps the decision: its further steps leave the term at zero, no new probe
    config = trainer.config
    config.load_dir, config.max_num_iterations = trainer.checkpoint_dir, 16
    calls = iter([23.0])
    monkeypatch.setattr("thermal_wild_ns.training.auto_stop.held_back_score", lambda pipeline, images: next(calls))
    resumed = seeded_trainer(config)
    resumed.train()
    assert resumed.pipeline.model.gauss_params["view_sh"].abs().max() == 0
    assert resumed.auto_stop.view_verdict is not None and not resumed.auto_stop.view_verdict.kept


def test_a_run_that_ends_before_its_first_scored_check_leaves_the_term_off(tmp_path, demo_scene_dir):
    """No scored check (the schedule's start-up lasts past the run): the term stayed zero all along,
    and the run's decisions say it is off and why."""
    config = demo_trainer_config(tmp_path, steps=8, max_gaussians=3000)
    config.pipeline.datamanager.dataparser.data = demo_scene_dir
    config.pipeline.model.view_sh_degree = 2
    config.auto_stop.check_every, config.auto_stop.decide_view_term = 4, True
    trainer = seeded_trainer(config)
    assert trainer.pipeline.model.settled_step > 8
    trainer.train()
    decisions = json.loads((trainer.config.get_base_dir() / "decisions.json").read_text())
    entry = next(d for d in decisions if d["part"] == "view-dependent emission")
    assert entry["choice"] == "off" and "ended at step 7" in entry["why"]
    assert trainer.pipeline.model.gauss_params["view_sh"].abs().max() == 0
