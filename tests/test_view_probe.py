"""The held-back frames decide the view term (`training/view_probe.py`): kept where the capture's
radiance changes with the view, off where what looks like it is each frame's own noise; through a
run, on trial until the first scored check, recorded, reported and replayed on resume."""

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from layout_fixtures import cameras as arc_poses
from layout_fixtures import opengl
from nerfstudio.cameras.cameras import Cameras
from test_model import make_model

from thermal_wild_ns.demo import demo_trainer_config
from thermal_wild_ns.errors import InputError
from thermal_wild_ns.model.view_emission import radial_part
from thermal_wild_ns.model.wild_thermal import WildThermalModel
from thermal_wild_ns.pipeline.evaluation import centre_r2, fit_gain_offset, fit_with_radial_falloff
from thermal_wild_ns.training.auto_stop import AutoStopConfig
from thermal_wild_ns.training.decisions import view_term_decision
from thermal_wild_ns.training.held_back import held_back_score, share_images
from thermal_wild_ns.training.trainer import seeded_trainer
from thermal_wild_ns.training.view_probe import judge_view_term, radial_share

WIDTH, HEIGHT = 48, 32
MAX_SHARE = AutoStopConfig().view_max_radial_share


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


def scalar_model(frames: int, camera_falloff: bool = False) -> WildThermalModel:
    """Plain scalar emission with a degree-2 view term (zero): the same Gaussians at every call; with
    the camera's radial fall-off fitted (`camera_falloff`) or not."""
    torch.manual_seed(0)  # their rotations are drawn from torch's generator
    return make_model(
        n=300,
        frames=frames,
        use_emission_mlp=False,
        use_background_mlp=False,
        view_sh_degree=2,
        camera_falloff=camera_falloff,
    )


def render(model, camera) -> torch.Tensor:
    model.eval()
    with torch.no_grad():
        return model.get_outputs(camera)["thermal"]


def trial_on(
    truth_view: bool, frame_noise: float, vignetting: float = 0.0, steps: int = 120, camera_model: bool = False
):
    """The rule on a model that has the truth's geometry and a wrong emission: trained (emission and
    view term, Adam) with the term on trial, then judged by held-back views between the training
    views, scored as the automatic stop scores them (after a gain, offset and radial fall-off fit to
    each), and by the share of what the term adds to the training views that is radial. The truth has a
    view term (`truth_view`) or not; each frame adds its own noise of `frame_noise`; the camera darkens
    toward the corners by `vignetting` (as the generated scenes' sensor); the model fits the camera's
    fall-off too where `camera_model` (as every capture's model by default)."""
    held = [3, 8, 13]  # between training views, as the automatic stop holds frames back
    train = [k for k in range(16) if k not in held]
    truth_model = scalar_model(16)
    if truth_view:
        with torch.no_grad():
            truth_model.gauss_params["view_sh"].normal_(0, 0.3, generator=torch.Generator().manual_seed(1))
    g = torch.Generator().manual_seed(2)
    cameras = arc_cameras(16)
    v, u = torch.meshgrid(torch.arange(HEIGHT) + 0.5, torch.arange(WIDTH) + 0.5, indexing="ij")
    r2 = ((u - WIDTH / 2) ** 2 + (v - HEIGHT / 2) ** 2) / ((WIDTH / 2) ** 2 + (HEIGHT / 2) ** 2)  # [H, W]
    falloff = (1.0 - vignetting * r2)[..., None]  # [H, W, 1]
    truth = [
        render(truth_model, c) * falloff + frame_noise * torch.randn(HEIGHT, WIDTH, 1, generator=g) for c in cameras
    ]
    model = scalar_model(16, camera_falloff=camera_model)
    assert torch.equal(model.quats, truth_model.quats)  # the truth's Gaussians exactly
    with torch.no_grad():
        model.gauss_params["emission"].fill_(0.5)
    model.try_view_term()
    params = [model.gauss_params["emission"], model.gauss_params["view_sh"]]
    params += [model.camera_falloff] if camera_model else []
    optimizer = torch.optim.Adam(params, lr=2e-2)
    order = torch.Generator().manual_seed(3)
    for step in range(steps):
        model.step = step  # odd steps render the term
        k = train[int(torch.randint(len(train), (1,), generator=order))]
        model.train()
        outputs = model.get_outputs(cameras[k])
        optimizer.zero_grad()
        sum(model.get_loss_dict(outputs, {"image": truth[k], "image_idx": k}).values()).backward()
        optimizer.step()
    assert model.gauss_params["view_sh"].abs().max() > 0  # trained on its steps

    def score():
        errors = []
        for k in held:
            pred, target = render(model, cameras[k])[..., 0].numpy(), truth[k][..., 0].numpy()  # [H, W]
            fitted = fit_with_radial_falloff(pred, target)
            errors.append(float(((fitted - target.reshape(-1)) ** 2).mean()))
        return float(sum(-10 * math.log10(e) for e in errors) / len(errors))

    def views():
        return [render(model, cameras[k])[..., 0].numpy() for k in train]  # the scene's, no camera response

    return judge_view_term(model, score, views, 0.05, MAX_SHARE, step=steps), model


def test_the_view_term_is_kept_where_the_radiance_changes_with_the_view():
    verdict, model = trial_on(truth_view=True, frame_noise=0.01)
    assert verdict.kept and verdict.with_term > verdict.without + 0.3, verdict
    assert verdict.radial_share < MAX_SHARE, verdict  # it follows the surfaces, not the sensor
    assert model.renders_view_term() and model.gauss_params["view_sh"].abs().max() > 0


def test_the_view_term_stays_off_where_the_training_views_differ_by_their_own_noise():
    verdict, model = trial_on(truth_view=False, frame_noise=0.05)
    assert not verdict.kept and verdict.with_term < verdict.without + 0.05, verdict
    assert not model.renders_view_term() and model.gauss_params["view_sh"].abs().max() == 0


def test_the_view_term_stays_off_where_the_camera_vignettes():
    """Vignetting is in every frame, the held-back ones too; the term must not be credited with it.
    (On this small scene a gain and offset alone also leave it off; on the generated vignetting scene
    they did not: docs/results/view_trial_gpu.)"""
    verdict, _ = trial_on(truth_view=False, frame_noise=0.01, vignetting=0.35)
    assert not verdict.kept, verdict
    # without a camera model the term takes the fall-off, and what it adds is radial: off for that too
    assert verdict.radial_share > MAX_SHARE, verdict
    verdict, _ = trial_on(truth_view=False, frame_noise=0.01, vignetting=0.35, camera_model=True)
    assert not verdict.kept and verdict.radial_share < MAX_SHARE, verdict  # the camera model took it


def test_the_view_term_is_kept_where_the_radiance_changes_with_the_view_and_the_camera_vignettes():
    """The camera model (on for every capture by default) takes the fall-off, the term the view."""
    verdict, _ = trial_on(truth_view=True, frame_noise=0.01, vignetting=0.35, camera_model=True)
    assert verdict.kept and verdict.with_term > verdict.without + 0.3 and verdict.radial_share < MAX_SHARE, verdict


def test_the_radial_share_is_what_one_camera_response_explains():
    """A camera's fall-off (the same gain and offset in r^2 in every view) is all radial; a pattern tied
    to each view's content is not; a term that adds nothing has nothing radial; bad input is named."""
    rng = np.random.default_rng(0)
    plain = [rng.random((32, 48)) for _ in range(4)]
    r2 = centre_r2(32, 48)
    vignetted = [p * (1 - 0.2 * r2) - 0.03 * r2**2 for p in plain]
    assert radial_share(plain, vignetted) == pytest.approx(1.0, abs=1e-9)
    content = [p + 0.1 * rng.standard_normal(p.shape) for p in plain]
    assert radial_share(plain, content) < 0.01
    mixed = [v + 0.1 * (c - p) for v, c, p in zip(vignetted, content, plain)]
    assert 0.2 < radial_share(plain, mixed) < 0.99
    assert radial_share(plain, plain) == 0.0
    with pytest.raises(ValueError, match="same views"):
        radial_share(plain, vignetted[:2])
    with pytest.raises(ValueError, match="rendered at"):
        radial_share(plain[:1], [np.zeros((16, 48))])


def test_a_radial_fall_off_and_a_level_are_fitted_exactly():
    rng = np.random.default_rng(0)
    pred = rng.random((32, 48))
    v, u = np.meshgrid(np.arange(32) + 0.5, np.arange(48) + 0.5, indexing="ij")
    r2 = ((u - 24) ** 2 + (v - 16) ** 2) / (24**2 + 16**2)
    target = (1.2 - 0.35 * r2) * pred + 0.1 + 0.05 * r2
    target[3, 4] = np.nan  # a pixel without a value is left out
    fitted = fit_with_radial_falloff(pred, target)
    assert fitted.shape == (32 * 48 - 1,) and np.allclose(fitted, target[np.isfinite(target)], atol=1e-9)
    a, b = fit_gain_offset(pred[np.isfinite(target)], target[np.isfinite(target)])
    assert not np.allclose(a * pred[np.isfinite(target)] + b, target[np.isfinite(target)], atol=1e-3)


def test_a_term_on_trial_renders_on_odd_training_steps_only():
    """On trial the Gaussians learn to render both ways: the term in odd training steps' renders,
    never outside training; `use_view_term(False)` zeroes it, the trial leaves it as trained."""
    model = scalar_model(16)
    with torch.no_grad():
        model.gauss_params["view_sh"].normal_(0, 0.3, generator=torch.Generator().manual_seed(1))
    camera = arc_cameras(1)[0]

    def train_render(step):
        model.train()
        model.step = step
        with torch.no_grad():
            return model.get_outputs(camera)["thermal"]

    model.try_view_term()
    with_term, without = train_render(1), train_render(2)
    assert not torch.allclose(with_term, without) and torch.equal(train_render(4), without)
    assert torch.equal(render(model, camera), without)  # outside training: left out
    assert model.gauss_params["view_sh"].abs().max() > 0
    model.use_view_term(True)
    assert torch.equal(train_render(2), with_term)
    model.use_view_term(False)
    assert model.gauss_params["view_sh"].abs().max() == 0 and torch.equal(train_render(1), without)


def _run(tmp_path, demo_scene_dir, monkeypatch, scores, steps=12, trial_checks=1, share=0.0):
    """The demo with a degree-2 view term decided by the held-back frames at scored check `trial_checks`
    (checks at steps 3, 7 and 11), whose scores follow `scores` (one per call: without the term and with
    it at the verdict, radial fall-off fitted; one per check otherwise, the verdict's check included), and
    the radial share of what the term adds to the training views is `share` (the views rendered both ways)."""
    config = demo_trainer_config(tmp_path, steps=steps, max_gaussians=3000)
    config.pipeline.datamanager.dataparser.data = demo_scene_dir
    config.pipeline.model.view_sh_degree = 2
    config.auto_stop.check_every, config.auto_stop.patience = 4, 10
    config.auto_stop.decide_view_term = True
    config.auto_stop.view_trial_checks = trial_checks
    calls = iter(scores)
    fits = []

    def scored(pipeline, images, radial=False):
        fits.append(radial)
        return next(calls)

    monkeypatch.setattr("thermal_wild_ns.training.auto_stop.held_back_score", scored)
    rendered = []

    def radial(without, with_term):
        moved = not all(np.array_equal(a, b) for a, b in zip(without, with_term))
        rendered.append((len(without), len(with_term), moved))
        return share

    monkeypatch.setattr("thermal_wild_ns.training.view_probe.radial_share", radial)
    monkeypatch.setattr(WildThermalModel, "settled_step", property(lambda self: 0))
    seen = []
    judge = judge_view_term

    def watched(model, *args, **kwargs):
        # before the verdict: on trial, the term trained on its steps and left out of the scoring renders
        seen.append((model.growth_state.view_term, bool(model.gauss_params["view_sh"].abs().max() > 0)))
        return judge(model, *args, **kwargs)

    monkeypatch.setattr("thermal_wild_ns.training.auto_stop.judge_view_term", watched)
    trainer = seeded_trainer(config)
    trainer.train()
    run = trainer.config.get_base_dir()
    decisions = json.loads((run / "decisions.json").read_text())
    entry = next(d for d in decisions if d["part"] == "view-dependent emission")
    # plain checks before the verdict, its pair with the fall-off fitted, then plain checks (3 in all: steps 3, 7, 11)
    assert fits == [False] * (trial_checks - 1) + [True, True] + [False] * (4 - trial_checks)
    assert rendered == [(12, 12, True)]  # twelve training views, each rendered without the term and with it
    return trainer, json.loads((run / "auto_stop.json").read_text())["view_term"], entry, seen


def test_a_run_keeps_the_view_term_its_held_back_frames_gain_from(tmp_path, demo_scene_dir, monkeypatch):
    trainer, verdict, entry, seen = _run(tmp_path, demo_scene_dir, monkeypatch, [20.0, 20.5, 20.4, 21.0, 22.0])
    assert seen == [("trial", True)] and verdict["step"] == 3 and verdict["kept"]
    assert entry["choice"] == "on" and entry["decided_by"] == "data" and "20.00 -> 20.50" in entry["why"]
    assert trainer.pipeline.model.gauss_params["view_sh"].abs().max() > 0  # trained on trial, then every step
    assert trainer.pipeline.model.renders_view_term()


def test_a_run_drops_a_view_term_that_does_what_the_camera_model_does(tmp_path, demo_scene_dir, monkeypatch):
    """The held-back frames gain with the term, but most of what it adds is one radial fall-off: off."""
    trainer, verdict, entry, _ = _run(tmp_path, demo_scene_dir, monkeypatch, [20.0, 20.5, 20.4, 21.0, 22.0], share=0.5)
    assert not verdict["kept"] and verdict["radial_share"] == 0.5 and verdict["max_share"] == MAX_SHARE
    assert entry["choice"] == "off" and "50% of what it adds" in entry["why"] and "camera model's part" in entry["why"]
    assert trainer.pipeline.model.gauss_params["view_sh"].abs().max() == 0


def test_a_run_drops_the_view_term_its_held_back_frames_do_not_gain_from(tmp_path, demo_scene_dir, monkeypatch):
    trainer, verdict, entry, seen = _run(tmp_path, demo_scene_dir, monkeypatch, [20.0, 20.01, 20.4, 21.0, 22.0])
    assert seen == [("trial", True)] and verdict["step"] == 3 and not verdict["kept"]
    assert entry["choice"] == "off" and entry["decided_by"] == "data"
    assert trainer.pipeline.model.gauss_params["view_sh"].abs().max() == 0  # zero after 8 more steps
    # a resumed run keeps the decision: its further steps leave the term at zero, no new trial
    config = trainer.config
    config.load_dir, config.max_num_iterations = trainer.checkpoint_dir, 16
    calls = iter([23.0])
    monkeypatch.setattr("thermal_wild_ns.training.auto_stop.held_back_score", lambda pipeline, images: next(calls))
    resumed = seeded_trainer(config)
    resumed.train()
    assert resumed.pipeline.model.gauss_params["view_sh"].abs().max() == 0
    assert resumed.auto_stop.view_verdict is not None and not resumed.auto_stop.view_verdict.kept


def test_the_canonical_score_renders_every_held_back_frame_at_the_canonical_state(tmp_path, demo_scene_dir):
    """`held_back_score(canonical=True)` scores at the state every novel view renders with: where every
    frame has the same embedding it is each held-back frame's own state too, and the two scores agree;
    where the frames' embeddings differ, they do not."""
    config = demo_trainer_config(tmp_path, steps=4, max_gaussians=3000)
    config.pipeline.datamanager.dataparser.data = demo_scene_dir
    trainer = seeded_trainer(config)
    trainer.train()
    pipeline, held = trainer.pipeline, trainer.pipeline.datamanager.held_back
    weight = pipeline.model.frame_embed.weight
    assert len(held) > 0
    with torch.no_grad():
        weight.copy_(torch.randn(weight.shape[1], generator=torch.Generator().manual_seed(0)).expand_as(weight))
    same = held_back_score(pipeline, held), held_back_score(pipeline, held, canonical=True)
    assert same[0] == pytest.approx(same[1], abs=1e-4)
    with torch.no_grad():
        weight.copy_(3.0 * torch.randn(weight.shape, generator=torch.Generator().manual_seed(1)))
    apart = held_back_score(pipeline, held), held_back_score(pipeline, held, canonical=True)
    assert abs(apart[0] - apart[1]) > 0.01, apart


def test_a_run_can_put_off_the_verdict_to_a_later_check(tmp_path, demo_scene_dir, monkeypatch):
    """`view_trial_checks` 2: the first check scores the model as every check does (the term on trial,
    left out of the render), the second decides; until then the term trains on its steps."""
    trainer, verdict, entry, seen = _run(
        tmp_path, demo_scene_dir, monkeypatch, [20.0, 20.1, 20.6, 20.5, 21.0], trial_checks=2
    )
    assert seen == [("trial", True)] and verdict["step"] == 7 and verdict["kept"]
    assert "until step 7" in entry["why"] and "20.10 -> 20.60" in entry["why"]


def test_a_run_that_ends_before_its_first_scored_check_leaves_the_term_off(tmp_path, demo_scene_dir):
    """No scored check (the schedule's start-up lasts past the run): the term, on trial all along, is
    zeroed at the end (the checkpoint renders as reported), and the run's decisions say it is off and why."""
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
    assert trainer.pipeline.model.gauss_params["view_sh"].abs().max() == 0  # trained on trial, zeroed at the end
    assert not trainer.pipeline.model.renders_view_term()


def test_the_pending_decision_names_the_check_that_will_decide():
    for checks, words in ((1, "the first scored check"), (3, "scored check 3")):
        pending = SimpleNamespace(view_verdict=None, config=SimpleNamespace(view_trial_checks=checks))
        decision = view_term_decision(pending)
        assert decision.choice == "to be decided" and decision.why.endswith(words), decision


def test_the_share_is_taken_on_trained_views_spread_over_the_capture():
    images = share_images(40, held_back=(13, 26))
    assert len(images) == 12 and images[0] == 0 and images[-1] == 39  # the capture's ends
    assert not {13, 26} & set(images) and list(images) == sorted(set(images))
    assert share_images(8, held_back=(3,)) == (0, 1, 2, 4, 5, 6, 7)  # a short capture: every trained view


def test_the_radial_part_of_the_view_term_is_what_one_camera_response_explains():
    """`radial_part`: a term that is a gain and offset fall-off of the Gaussians' place in the image is all
    radial (its whole mean square); one that does not follow the place has little; the loss reaches the term."""
    g = torch.Generator().manual_seed(0)
    centres = torch.rand(500, 2, generator=g) * torch.tensor([48.0, 32.0])  # [M, 2] pixels
    emission = torch.rand(500, 1, generator=g) + 0.5  # [M, 1]
    r2 = ((centres - torch.tensor([24.0, 16.0])).square().sum(-1, keepdim=True)) / (24.0**2 + 16.0**2)
    radial = -0.2 * emission * r2 + 0.05 * r2.square()
    assert radial_part(radial, emission, centres, 48, 32).item() == pytest.approx(
        radial.square().mean().item(), rel=1e-3
    )
    scattered = 0.1 * torch.randn(500, 1, generator=g)
    assert radial_part(scattered, emission, centres, 48, 32).item() < 0.02 * scattered.square().mean().item()
    term = radial.clone().requires_grad_(True)
    radial_part(term, emission, centres, 48, 32).backward()
    assert term.grad.abs().max() > 0


def test_a_training_render_carries_the_view_terms_radial_part_into_the_loss_where_asked():
    camera = arc_cameras(1)[0]
    batch = {"image": torch.full((HEIGHT, WIDTH, 1), 0.5), "image_idx": 0}
    for weight in (0.0, 10.0):
        torch.manual_seed(0)
        model = make_model(
            n=300,
            frames=16,
            use_emission_mlp=False,
            use_background_mlp=False,
            view_sh_degree=2,
            view_radial_penalty=weight,
        )
        with torch.no_grad():
            model.gauss_params["view_sh"].normal_(0, 0.3, generator=torch.Generator().manual_seed(1))
        model.train()
        outputs = model.get_outputs(camera)
        losses = model.get_loss_dict(outputs, batch)
        assert ("view_radial" in losses) == (weight > 0)
        if weight > 0:
            assert losses["view_radial"].item() == pytest.approx(weight * outputs["view_radial"].item())
            assert losses["view_radial"].item() > 0


def test_a_radial_penalty_without_a_view_term_is_refused():
    with pytest.raises(InputError, match="view_radial_penalty 10 penalises the view term, but view_sh_degree is 0"):
        make_model(n=50, frames=4, view_radial_penalty=10.0)


def test_the_view_term_joins_training_renders_at_its_step():
    """`view_term_from_step`: before it a training render is the one without the term and the term's
    coefficients get no gradient; from it on they are rendered and learn; outside training the term is
    rendered whatever the step."""
    camera = arc_cameras(1)[0]
    batch = {"image": torch.full((HEIGHT, WIDTH, 1), 0.5), "image_idx": 0}
    torch.manual_seed(0)
    model = make_model(
        n=300, frames=16, use_emission_mlp=False, use_background_mlp=False, view_sh_degree=2, view_term_from_step=5
    )
    with torch.no_grad():
        model.gauss_params["view_sh"].normal_(0, 0.3, generator=torch.Generator().manual_seed(1))
    renders = {}
    for step in (4, 5):
        model.train()
        model.step = step
        model.zero_grad(set_to_none=True)
        outputs = model.get_outputs(camera)
        sum(model.get_loss_dict(outputs, batch).values()).backward()
        renders[step] = outputs["thermal"].detach()
        grad = model.gauss_params["view_sh"].grad
        assert (grad is not None and grad.abs().max() > 0) == (step == 5)
    assert not torch.allclose(renders[4], renders[5])
    model.eval()
    model.step = 0
    with torch.no_grad():
        assert torch.allclose(model.get_outputs(camera)["thermal"], renders[5], atol=1e-5)


def test_a_view_term_step_without_a_view_term_is_refused():
    with pytest.raises(InputError, match="view_term_from_step 100 delays the view term, but view_sh_degree is 0"):
        make_model(n=50, frames=4, view_term_from_step=100)
    with pytest.raises(InputError, match="view_term_from_step -1: must be 0 or more"):
        make_model(n=50, frames=4, view_sh_degree=1, view_term_from_step=-1)
