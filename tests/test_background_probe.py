"""The held-back frames decide whether the background MLP stays (`training/background_probe.py`): a scene whose
background shows keeps it, one whose Gaussians cover every pixel leaves a constant in its place, and a run
that left it keeps the constant through its checkpoints, its report and a resume."""

import json
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from test_model import make_camera, make_model, perturb_output_layers

from thermal_wild_ns.demo import demo_trainer_config
from thermal_wild_ns.image_metrics import psnr
from thermal_wild_ns.model.wild_thermal import WildThermalModel
from thermal_wild_ns.training.background_probe import judge_background, uncovered_mean
from thermal_wild_ns.training.trainer import seeded_trainer


def test_the_constant_is_the_backgrounds_level_where_it_shows():
    background = np.array([[0.2, 0.8], [0.8, 0.8]])
    covered_but_one = np.array([[0.0, 1.0], [1.0, 1.0]])  # only the 0.2 pixel shows
    assert uncovered_mean([background], [covered_but_one]) == pytest.approx(0.2)
    half = np.array([[0.5, 0.5], [1.0, 1.0]])
    assert uncovered_mean([background, background], [half, half]) == pytest.approx(0.5)
    # shown nowhere: its plain mean (whatever it is, it renders nowhere)
    assert uncovered_mean([background], [np.ones((2, 2))]) == pytest.approx(0.65)


def _scene(covered: bool):
    """A model, in eval mode, whose background MLP varies across the view, and a camera: its Gaussians cover
    every pixel (large, opaque, in front of the camera) or none (behind it)."""
    torch.manual_seed(0)
    model = make_model(n=200)
    perturb_output_layers(model)
    with torch.no_grad():
        model.background_mlp.net.layers()[-1][0].normal_(0, 2.0)  # a background that varies with the direction
        params = model.gauss_params
        params["means"].mul_(0.3)
        params["scales"].fill_(np.log(0.6))
        params["opacities"].fill_(8.0)  # opaque
        if not covered:
            params["means"][:, 2] += 10.0  # behind the camera (at z 3, looking down -z)
    model.eval()
    return model, make_camera(1)


@pytest.mark.parametrize("covered", [True, False])
def test_the_background_mlp_stays_where_it_shows_and_leaves_where_the_gaussians_cover_every_pixel(covered):
    """Scored against frames the MLP's renders explain (plus noise), a constant in its place loses nothing where
    the Gaussians cover every pixel, and loses where the background is the whole view: left, or kept."""
    model, camera = _scene(covered)
    render = lambda: model.get_outputs(camera)
    with torch.no_grad():
        first = render()
        coverage = first["accumulation"][..., 0].numpy()
        noise = 0.01 * torch.randn(first["thermal"].shape, generator=torch.Generator().manual_seed(1))
        truth = first["thermal"] + noise
    assert (coverage.min() > 0.98) if covered else (coverage.max() < 0.01)

    def score():
        with torch.no_grad():
            value = float(psnr(render()["thermal"], truth))
        return value, value  # the held-back frames' and the trained views' (here one view for both)

    def mean_background():
        with torch.no_grad():
            outputs = render()
        return uncovered_mean([outputs["background"][..., 0].numpy()], [outputs["accumulation"][..., 0].numpy()])

    verdict = judge_background(model, score, mean_background, min_gain=0.05, step=7)
    assert verdict.kept is not covered and verdict.step == 7
    if covered:
        assert model.background_constant == pytest.approx(verdict.value) and "left for the constant" in verdict.why()
        assert verdict.with_constant == pytest.approx(verdict.with_mlp, abs=0.05)
        with torch.no_grad():
            assert torch.allclose(render()["background"], torch.full_like(first["background"], verdict.value))
    else:
        assert model.background_constant is None and "stays" in verdict.why()
        assert verdict.with_mlp > verdict.with_constant + 1.0
        with torch.no_grad():
            assert torch.equal(render()["background"], first["background"])  # the MLP's again


@pytest.mark.parametrize("held_gain, trained_gain, kept", [(0.0, 0.0, False), (0.5, 0.0, True), (0.0, 0.5, True)])
def test_the_mlp_stays_where_the_held_back_frames_or_the_trained_views_gain_from_it(held_gain, trained_gain, kept):
    """Two held-back frames may miss the sky that other frames show: a gain on either set keeps the MLP."""
    constants = []
    model = SimpleNamespace(use_background_constant=constants.append)
    scored = iter([(20.0 + held_gain, 30.0 + trained_gain), (20.0, 30.0)])  # with the MLP, then the constant
    verdict = judge_background(model, lambda: next(scored), lambda: 0.3, min_gain=0.05, step=5)
    assert verdict.kept is kept and constants == ([0.3, None] if kept else [0.3])
    assert f"trained views {30.0 + trained_gain:.2f} and 30.00 dB" in verdict.why()


def test_a_constant_background_takes_the_alpha_regulariser_with_it_and_comes_back_from_a_checkpoint():
    """With a constant in the MLP's place a training step has no alpha term (a constant predicts no pixel of its
    own) and the MLP no gradient; the constant is saved with the model and loaded with it; None: the MLP again."""
    model, camera = _scene(covered=True)
    model.train()
    batch = {"image": torch.rand(32, 48, 1), "image_idx": 1}
    assert "alpha_loss" in model.get_loss_dict(model.get_outputs(camera), batch)
    model.use_background_constant(0.25)
    outputs = model.get_outputs(camera)
    losses = model.get_loss_dict(outputs, batch)
    assert "alpha_loss" not in losses and torch.allclose(outputs["background"], torch.tensor(0.25))
    sum(losses.values()).backward()
    assert model.background_mlp.net.packed.grad is None and model.gauss_params["means"].grad.abs().sum() > 0
    decisions = {d.part: d for d in model.decisions()}
    assert decisions["background MLP"].choice == "off: a constant 0.2500 in its place"
    assert decisions["background MLP"].decided_by == "data" and decisions["alpha regulariser"].choice == "off"
    loaded = make_model(n=200)
    loaded.load_state_dict(model.state_dict())
    assert loaded.background_constant == 0.25 and not loaded.thermal_loss.alpha_on
    loaded.use_background_constant(None)
    assert loaded.thermal_loss.alpha_on and loaded.parts.background.mlp is loaded.background_mlp
    assert make_model(n=200).background_constant is None  # a model never judged: the MLP


def _run(tmp_path, demo_scene_dir, monkeypatch, scores, steps=12):
    """The demo with its background MLP decided at the first scored check (checks at steps 3, 7 and 11), the
    scores following `scores`: at the verdict the held-back frames' and the trained views' with the MLP, then
    both with the constant; then one a check."""
    config = demo_trainer_config(tmp_path, steps=steps, max_gaussians=3000)
    config.pipeline.datamanager.dataparser.data = demo_scene_dir
    config.auto_stop.check_every, config.auto_stop.patience = 4, 10
    config.auto_stop.decide_background = True
    calls = iter(scores)
    monkeypatch.setattr("thermal_wild_ns.training.auto_stop.held_back_score", lambda *args, **kwargs: next(calls))
    monkeypatch.setattr(WildThermalModel, "settled_step", property(lambda self: 0))
    trainer = seeded_trainer(config)
    trainer.train()
    run = trainer.config.get_base_dir()
    decisions = {d["part"]: d for d in json.loads((run / "decisions.json").read_text())}
    return trainer, json.loads((run / "auto_stop.json").read_text())["background"], decisions


def test_a_run_keeps_the_background_mlp_its_held_back_frames_gain_from(tmp_path, demo_scene_dir, monkeypatch):
    trainer, verdict, decisions = _run(tmp_path, demo_scene_dir, monkeypatch, [20.0, 30.0, 19.5, 30.0, 20.4, 21, 22])
    assert verdict["step"] == 3 and verdict["kept"] and verdict["with_constant"] == 19.5
    assert trainer.pipeline.model.background_constant is None
    assert decisions["background MLP"]["choice"] == "on" and decisions["alpha regulariser"]["choice"] == "on"
    assert (
        decisions["background MLP"]["decided_by"] == "data"
        and "20.00 dB with the background MLP" in (decisions["background MLP"]["why"])
    )


def test_a_run_leaves_the_background_mlp_its_held_back_frames_do_not_gain_from(tmp_path, demo_scene_dir, monkeypatch):
    trainer, verdict, decisions = _run(tmp_path, demo_scene_dir, monkeypatch, [20.0, 30.0, 19.99, 29.99, 20.4, 21, 22])
    model = trainer.pipeline.model
    assert not verdict["kept"] and model.background_constant == pytest.approx(verdict["value"])
    assert decisions["background MLP"]["decided_by"] == "data" and "constant" in decisions["background MLP"]["choice"]
    assert "alpha_loss" not in model.last_training_losses()[0]  # the steps after the verdict
    # a resumed run keeps the constant (its checkpoint holds it) and judges nothing again
    config = trainer.config
    config.load_dir, config.max_num_iterations = trainer.checkpoint_dir, 16
    calls = iter([23.0])
    monkeypatch.setattr("thermal_wild_ns.training.auto_stop.held_back_score", lambda *args, **kwargs: next(calls))
    resumed = seeded_trainer(config)
    resumed.train()
    assert resumed.pipeline.model.background_constant == pytest.approx(verdict["value"])
    assert resumed.auto_stop.background_verdict is not None and not resumed.auto_stop.background_verdict.kept


def test_nothing_is_judged_with_the_rule_off_or_without_a_background_mlp(tmp_path, demo_scene_dir):
    """Off (the default: the verdict at the first check lost 4.3 dB on a survey seed, docs/results/
    background_rule_cpu): the run scores as ever, no verdict; a model built without the MLP has nothing to judge."""
    from thermal_wild_ns.training.auto_stop import AutoStopConfig

    assert AutoStopConfig().decide_background is False
    config = demo_trainer_config(tmp_path, steps=8, max_gaussians=3000)
    config.pipeline.datamanager.dataparser.data = demo_scene_dir
    config.auto_stop.check_every = 4
    trainer = seeded_trainer(config)
    assert not trainer.auto_stop.decides_background
    config.auto_stop.decide_background, config.pipeline.model.use_background_mlp = True, False
    config.pipeline.model.alpha_lambda = 0.0
    trainer = seeded_trainer(config)
    assert not trainer.pipeline.model.has_background_mlp() and not trainer.auto_stop.decides_background


def test_the_decision_is_pending_until_the_first_scored_check_and_a_run_that_ends_before_it_keeps_the_mlp():
    from thermal_wild_ns.training.decisions import background_decision

    pending = SimpleNamespace(background_verdict=None)
    assert background_decision(pending).choice == "to be decided"
    ended = background_decision(pending, last_step=7)
    assert ended.choice == "on" and "ended at step 7" in ended.why and ended.decided_by == "data"


def test_trained_views_are_scored_at_their_own_states_and_the_backgrounds_level_read_from_both_sets(
    tmp_path, demo_scene_dir
):
    """`held_back_score(own=True)` renders trained images at their own training states: where every frame has
    one embedding it is the canonical state's score, where their embeddings differ it is not; the background's
    level is read from the held-back and the trained views' renders."""
    from thermal_wild_ns.training.held_back import held_back_background, held_back_score, share_images

    config = demo_trainer_config(tmp_path, steps=4, max_gaussians=3000)
    config.pipeline.datamanager.dataparser.data = demo_scene_dir
    trainer = seeded_trainer(config)
    trainer.train()
    pipeline, held = trainer.pipeline, trainer.pipeline.datamanager.held_back
    trained = share_images(len(pipeline.datamanager.train_dataset), held, count=4)
    weight = pipeline.model.frame_embed.weight
    with torch.no_grad():
        weight.copy_(torch.randn(weight.shape[1], generator=torch.Generator().manual_seed(0)).expand_as(weight))
    own, canonical = held_back_score(pipeline, trained, own=True), held_back_score(pipeline, trained, canonical=True)
    assert own == pytest.approx(canonical, abs=1e-4)
    with torch.no_grad():
        weight.copy_(3.0 * torch.randn(weight.shape, generator=torch.Generator().manual_seed(1)))
    own, canonical = held_back_score(pipeline, trained, own=True), held_back_score(pipeline, trained, canonical=True)
    assert abs(own - canonical) > 0.01, (own, canonical)
    level = held_back_background(pipeline, held, trained)
    assert np.isfinite(level)
