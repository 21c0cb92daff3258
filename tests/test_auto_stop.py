"""The automatic stop: it ends a run whose held-back score has plateaued, lets one that is still
improving train on, keeps the best model, and never trains on the frames it scores."""

import json

import numpy as np
import pytest
import torch
from demo_trainers import demo_trainer

from thermal_wild_ns.demo import demo_trainer_config
from thermal_wild_ns.model.wild_thermal import WildThermalModel
from thermal_wild_ns.training import auto_stop
from thermal_wild_ns.training.auto_stop import AutoStopConfig
from thermal_wild_ns.training.held_back import held_back_images
from thermal_wild_ns.training.stop_rules import HeldBackBudget, PlateauRule
from thermal_wild_ns.training.trainer import seeded_trainer


def test_the_rule_stops_a_plateau_and_not_a_rise():
    rising = PlateauRule(patience=3, min_improvement=0.05)
    for k, score in enumerate([20.0, 20.5, 21.0, 21.2, 21.3, 21.4, 21.5]):
        rising.update(k, score)
        assert not rising.plateaued, k
    flat = PlateauRule(patience=3, min_improvement=0.05)
    for k, score in enumerate([20.0, 22.0, 22.03, 21.5, 22.04]):  # rises under 0.05 dB count as none
        flat.update(k, score)
    assert flat.plateaued and flat.best == 22.0 and flat.best_step == 1
    assert not PlateauRule(3, 0.05, history=[]).plateaued


def test_a_shortened_schedule_checks_more_often_but_waits_at_least_the_floor():
    full = AutoStopConfig()
    full.scale_to(30_000)
    assert (full.check_every, full.patience) == (500, 4)  # the full schedule's wait (2,000 steps) is over the floor
    short = AutoStopConfig()
    short.scale_to(5_000)
    assert short.check_every == 83 and short.patience == 8 and short.patience * short.check_every >= 650
    tiny = AutoStopConfig()
    tiny.scale_to(300)  # the floor never asks more than the schedule
    assert tiny.check_every == 10 and tiny.patience == 30
    unfloored = AutoStopConfig(patience_floor_steps=0)
    unfloored.scale_to(5_000)
    assert (unfloored.check_every, unfloored.patience) == (83, 4)
    patient = AutoStopConfig(patience=12)
    patient.scale_to(5_000)
    assert patient.patience == 12  # a longer patience than the floor is kept


def test_a_non_finite_score_is_never_a_best():
    rule = PlateauRule(patience=2, min_improvement=0.0)
    assert not rule.update(0, float("nan"))
    assert rule.update(1, 10.0) and not rule.update(2, float("inf") * 0)


def test_the_budget_grows_at_a_plateau_at_the_budget_only_while_each_raise_gains():
    rule = HeldBackBudget(start=200, limit=1000)
    assert rule.next_budget(best_step=0, count=500, budget=1000, densifies=True) is None  # at the limit already
    assert rule.next_budget(best_step=0, count=100, budget=200, densifies=True) is None  # below its budget: room left
    assert rule.next_budget(best_step=0, count=200, budget=200, densifies=False) is None  # densification is over
    assert rule.next_budget(best_step=0, count=190, budget=200, densifies=True) == 400  # at it (90 %): a first raise
    rule.raised(3, 400)
    assert rule.next_budget(best_step=3, count=400, budget=400, densifies=True) is None  # no new best since the raise
    assert rule.next_budget(best_step=4, count=400, budget=400, densifies=True) == 800  # a new best after it
    rule.raised(5, 800)
    assert rule.next_budget(best_step=7, count=800, budget=800, densifies=True) == 1000  # never past the limit
    # the curve: a raising check's score is the budget's it raised, a NaN check counts for none
    history = [(1, 20.0), (3, 21.0), (4, 23.0), (5, 22.0), (6, float("nan")), (7, 22.5)]
    assert rule.best_per_budget(history) == [(200, 21.0), (400, 23.0), (800, 22.5)]


def test_a_run_whose_held_back_frames_plateau_at_its_budget_grows_it_and_stops_when_growth_stops_paying(
    tmp_path, demo_scene_dir, monkeypatch
):
    """Through a run: a plateau at the budget doubles it and training goes on; a raise followed by a new
    best earns the next one at the next plateau; a raise with no new best ends the run. The raises are
    recorded (auto_stop.json, decisions.json) and said to be the data's choice; a model kept from before a
    raise keeps the budget it trained under; a resumed run starts from the budget reached."""
    trainer = _trainer(tmp_path, demo_scene_dir, steps=40, check_every=4, patience=2, grow_budget=True)
    model = trainer.pipeline.model
    start = trainer.auto_stop.budget.start = model.num_points  # at its budget from the start
    model.config.view_term_above_budget = 3 * start  # the full method's view term, for a budget past 3x the start
    model.start_budget(start)
    assert model.has_view_term() and not model.renders_view_term()
    # the model fills each budget it is given (densification's growth has tests of its own)
    monkeypatch.setattr(WildThermalModel, "gaussian_budget", lambda m: (m.strategy.max_gaussians,) * 2)
    # checks at steps 3, 7, ...: a plateau at 11 (raise), a new best at 15, a plateau at 23 (raise), none after
    _scores(monkeypatch, [20.0, 20.0, 20.0, 25.0, 24.9, 24.9, 24.9, 24.9, 24.9])
    trainer.train()
    record = json.loads((trainer.config.get_base_dir() / "auto_stop.json").read_text())
    raises = record["budget_raises"]
    assert [(r["step"], r["budget"]) for r in raises] == [(11, 2 * start), (23, 4 * start)]
    assert record["last_step"] == 31 and record["kept_step"] == 15  # stopped: the second raise gained nothing
    decisions = json.loads((trainer.config.get_base_dir() / "decisions.json").read_text())
    budget = next(d for d in decisions if d["part"] == "Gaussian budget")
    assert budget["decided_by"] == "data" and f"{2 * start:,} at step 11" in budget["why"]
    # the held-back score against the model's size: each check's count, each budget's best score
    assert [c["step"] for c in record["checks"]] == [3, 7, 11, 15, 19, 23, 27, 31]
    assert all(isinstance(c["gaussians"], int) and c["gaussians"] > 0 for c in record["checks"])
    curve = f"{start:,}: 20.00 dB; {2 * start:,}: 25.00 dB; {4 * start:,}: 24.90 dB"
    assert budget["why"].endswith(f"best held-back PSNR per budget: {curve}")
    # the view term came in with the raise past 3x the start (step 23), after the model kept (step 15): the kept
    # model's budget is the one it trained under, and its view term, all zeros, is in no render
    assert model.gaussian_budget()[1] == 2 * start and budget["choice"].startswith(f"{2 * start:,} (")
    assert f"the model kept (step 15) trained under {2 * start:,}" in budget["why"]
    view = next(d for d in decisions if d["part"] == "view-dependent emission")
    assert view["choice"] == "off" and f"the Gaussian budget {2 * start:,}" in view["why"]
    assert not model.renders_view_term() and not model.gauss_params["view_sh"].any()
    # a resumed run starts from the budget the run had reached, not from its config's
    config = trainer.config
    config.load_dir, config.max_num_iterations = trainer.checkpoint_dir, 36
    config.auto_stop.budget_start = start
    resumed = seeded_trainer(config)
    assert resumed.pipeline.model.gaussian_budget()[1] == raises[-1]["budget"]
    assert resumed.pipeline.model.renders_view_term()


def test_by_default_the_held_back_frames_set_the_budget_from_its_start_and_the_fixed_one_applies_without_them(
    tmp_path, demo_scene_dir
):
    """The full method's defaults: the run starts at `budget_start`, not at the model's `max_gaussians`,
    and its decisions say the data sets the budget (no config entry beside it); with `grow_budget` off,
    or the stop off, the fixed `max_gaussians` holds."""
    assert AutoStopConfig().grow_budget  # the default
    config = demo_trainer_config(tmp_path / "grows", steps=12, max_gaussians=3000)
    config.pipeline.datamanager.dataparser.data = demo_scene_dir
    config.auto_stop.budget_start = 2800
    trainer = seeded_trainer(config)
    assert trainer.pipeline.model.gaussian_budget()[1] == 2800 and trainer.auto_stop.budget.start == 2800
    decisions = [d for d in trainer.decisions.collect(trainer) if d.part in ("Gaussians", "Gaussian budget")]
    assert [(d.part, d.decided_by) for d in decisions] == [("Gaussian budget", "data")]
    assert "not raised from its start (2,800)" in decisions[0].why
    assert decisions[0].choice == f"2,800 ({trainer.pipeline.model.num_points:,} Gaussians now)"
    # a start below the seed points would leave densification no room: the budget starts at the model's size
    small = demo_trainer_config(tmp_path / "small", steps=12, max_gaussians=3000)
    small.pipeline.datamanager.dataparser.data = demo_scene_dir
    small.auto_stop.budget_start = 100
    trainer = seeded_trainer(small)
    seeds = trainer.pipeline.model.num_points
    assert seeds > 100 and trainer.auto_stop.budget.start == trainer.pipeline.model.gaussian_budget()[1] == seeds
    trainer.train()
    record = json.loads((trainer.config.get_base_dir() / "auto_stop.json").read_text())
    assert record["budget_start"] == seeds  # what a resume restores
    for setting in ("grow_budget", "enabled"):
        fixed = demo_trainer_config(tmp_path / setting, steps=12, max_gaussians=3000)
        fixed.pipeline.datamanager.dataparser.data = demo_scene_dir
        fixed.auto_stop.budget_start = 2800
        setattr(fixed.auto_stop, setting, False)
        trainer = seeded_trainer(fixed)
        assert trainer.pipeline.model.gaussian_budget()[1] == 3000
        decisions = {d.part: d for d in trainer.decisions.collect(trainer)}
        assert "Gaussian budget" not in decisions and decisions["Gaussians"].why == "max_gaussians 3,000"


def test_held_back_images_are_interior_distinct_and_only_when_enough_remain():
    assert held_back_images(45, 2) == (15, 29)
    for n, k in [(20, 2), (40, 3), (200, 5)]:
        images = held_back_images(n, k)
        assert len(set(images)) == k and 0 < min(images) and max(images) < n - 1
    assert held_back_images(19, 2) == () and held_back_images(30, 0) == ()


def _trainer(tmp_path, demo_scene_dir, steps, preprocessed=False, **auto):
    return demo_trainer(tmp_path, demo_scene_dir, steps, "auto_stop", preprocessed, **auto)


def _scores(monkeypatch, values):
    """Make the held-back score follow `values`, one per call (the rule's input, decided here), from
    step 0 on (the schedule's own start-up has a test of its own)."""
    calls = iter(values)
    monkeypatch.setattr("thermal_wild_ns.training.auto_stop.held_back_score", lambda pipeline, images: next(calls))
    monkeypatch.setattr(WildThermalModel, "settled_step", property(lambda self: 0))


def test_no_check_before_the_schedules_start_up_is_over(tmp_path, demo_scene_dir, monkeypatch):
    calls = []
    monkeypatch.setattr(
        "thermal_wild_ns.training.auto_stop.held_back_score",
        lambda pipeline, images: calls.append(pipeline.model.step) or 20.0,
    )
    trainer = _trainer(tmp_path, demo_scene_dir, steps=40, check_every=4, patience=1)
    model = trainer.pipeline.model
    model.config.num_downscales, model.config.resolution_schedule = 1, 12  # full resolution from step 12
    model.strategy.reset_every = 20  # the first opacity reset at step 20
    assert model.settled_step == 20
    trainer.train()
    # checks at 23, 27, ...: a flat score from the first of them, so the run stops after patience 1
    assert calls[:2] == [23, 27]
    record = json.loads((trainer.config.get_base_dir() / "auto_stop.json").read_text())
    assert record["checks"][0]["step"] == 23 and record["stopped_early"] and record["last_step"] == 27


def test_a_plateaued_run_stops_says_why_and_keeps_its_best_model(tmp_path, demo_scene_dir, monkeypatch):
    trainer = _trainer(tmp_path, demo_scene_dir, steps=40, check_every=4, patience=2)
    kept = {}
    snapshot = auto_stop.snapshot

    def remember(pipeline, optimizers, step):
        kept[step] = {k: v.detach().clone() for k, v in pipeline.model.named_parameters()}
        return snapshot(pipeline, optimizers, step)

    monkeypatch.setattr(auto_stop, "snapshot", remember)  # what the automatic stop keeps
    _scores(monkeypatch, [20.0, 25.0, 24.0, 24.5, 23.0])  # best at the 2nd check (step 7), then two without a rise
    trainer.train()
    record = json.loads((trainer.config.get_base_dir() / "auto_stop.json").read_text())
    assert record["stopped_early"] and record["last_step"] == 15 and record["kept_step"] == 7
    assert "has not risen" in record["reason"] and "step 7" in record["reason"]
    assert [c["step"] for c in record["checks"]] == [3, 7, 11, 15]
    assert trainer.step == 15  # the final checkpoint is named after the last step trained
    for name, param in trainer.pipeline.model.named_parameters():  # the model of step 7 is what was saved
        if name in kept[7] and param.shape == kept[7][name].shape:
            assert torch.equal(param.detach(), kept[7][name]), name
    assert sorted(p.name for p in trainer.checkpoint_dir.glob("step-*.ckpt"))[-1] == "step-000000015.ckpt"


def test_an_improving_run_trains_every_step(tmp_path, demo_scene_dir, monkeypatch):
    trainer = _trainer(tmp_path, demo_scene_dir, steps=24, check_every=4, patience=2)
    _scores(monkeypatch, [20.0 + k for k in range(10)])
    trainer.train()
    record = json.loads((trainer.config.get_base_dir() / "auto_stop.json").read_text())
    assert not record["stopped_early"] and record["last_step"] == 23 and record["kept_step"] == 23
    assert record["reason"] is None


def test_held_back_frames_take_no_gradient_and_get_their_neighbours_state(tmp_path, demo_scene_dir):
    trainer = _trainer(tmp_path, demo_scene_dir, steps=30, check_every=10)
    datamanager, model = trainer.pipeline.datamanager, trainer.pipeline.model
    held = datamanager.held_back
    assert len(held) == 2
    trained = len(datamanager.train_dataset) - 2
    visited = {datamanager.train_order(epoch)[k] for epoch in range(3) for k in range(trained)}
    assert visited.isdisjoint(held) and len(visited) == trained
    trainer.train()
    weight = model.frame_embed.weight.detach()
    for row in held:  # linear between the trained neighbours (training images are in capture order)
        t = model.frame_times
        a, b = row - 1, row + 1
        w = (t[row] - t[a]) / (t[b] - t[a])
        assert torch.allclose(weight[row], (1 - w) * weight[a] + w * weight[b], atol=1e-6)
    assert weight[held[0] - 1].abs().sum() > 0  # trained rows moved away from their zero start


def test_the_score_is_the_aligned_time_render_of_the_held_back_frame(tmp_path, demo_scene_dir, monkeypatch):
    """PSNR in the original space, against the frame as captured, rendered with the embedding and
    LUT interpolated between its trained neighbours (never its own LUT, which its pixels made), after
    a gain + offset fit: a frame whose level jumped scores the same but for the gain's scale."""
    from thermal_wild_ns.pipeline.evaluation import fit_gain_offset
    from thermal_wild_ns.pipeline.photometric_state import PhotometricState, render
    from thermal_wild_ns.preprocessing.photometric import blend_luts

    trainer = _trainer(tmp_path, demo_scene_dir, steps=1, preprocessed=True)  # LUTs to interpolate
    pipeline = trainer.pipeline
    dataset, sequence, model = pipeline.datamanager.train_dataset, pipeline.datamanager.preprocessed, pipeline.model
    image = pipeline.datamanager.held_back[0]
    before, t, after = (dataset.frame_index(k) for k in (image - 1, image, image + 1))
    lut = blend_luts(sequence.lut(before), sequence.lut(after), (t - before) / (after - before))
    model.interpolate_embeddings(pipeline.datamanager.held_back)
    camera = dataset.cameras[image : image + 1]
    _, pred = render(pipeline, camera, PhotometricState("x", model.frame_embed.weight[image].detach(), lut))
    truth = dataset.original_image(image)
    a, b = fit_gain_offset(pred, truth)
    expected = -10 * np.log10(np.mean((a * pred + b - truth) ** 2))
    model.info = info = {"from": "the last training render"}
    score = auto_stop.held_back_score(pipeline, [image])
    assert score == pytest.approx(float(expected), abs=1e-3)
    assert model.training and model.info is info  # scoring leaves the model as it found it
    embedding = model.frame_embed.weight[image].detach()
    _, own = render(pipeline, camera, PhotometricState("own", embedding, sequence.lut(t)))
    a, b = fit_gain_offset(own, truth)
    assert abs(-10 * np.log10(np.mean((a * own + b - truth) ** 2)) - score) > 1e-3  # its own LUT scores otherwise
    # the frame recorded 1.3 times brighter and 0.1 higher: its errors are 1.3 times larger, nothing else
    captured = pipeline.datamanager.held_back_truth
    monkeypatch.setattr(pipeline.datamanager, "held_back_truth", lambda k: 1.3 * captured(k) + 0.1)
    jumped = auto_stop.held_back_score(pipeline, [image])
    assert jumped == pytest.approx(score - 20 * np.log10(1.3), abs=1e-3)
