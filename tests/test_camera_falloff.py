"""The camera's own fall-off (`model/camera_falloff.py`): fitted in training, rendered into what is
compared with recorded frames, left out of the scene's renders."""

from typing import NamedTuple, Optional, Tuple

import numpy as np
import pytest
import torch
from test_model import make_camera, make_model

from thermal_wild_ns.errors import InputError
from thermal_wild_ns.model.camera_falloff import (
    FALLOFF_ORDER,
    centred_cells,
    falloff_basis,
    flat_field_maps,
    off_axis_squared,
    respond,
)
from thermal_wild_ns.model.camera_views import ray_directions
from thermal_wild_ns.pipeline.photometric_state import as_recorded


def intrinsics(f=50.0, width=48, height=32):
    return torch.tensor([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])


def rho_of(K, width, height):
    """The off-axis grid [H, W, 1] of a camera with intrinsics `K` [3, 3], as the model builds it."""
    return off_axis_squared(ray_directions(K, torch.eye(3, 4), width, height))


def apply_falloff(image, coefficients, rho, flat_field=None):
    """The camera's response written out, apart from the model's `respond`: at the squared off-axis
    tangents `rho` [H, W, 1], gain (1 + sum_k g_k rho^k, plus the map's gain) times the image plus the
    offset (sum_k o_k rho^k, plus the map's offset)."""
    gain, offset = torch.ones_like(rho), torch.zeros_like(rho)
    for k in range(1, coefficients.shape[1] + 1):
        gain = gain + coefficients[0, k - 1] * rho**k
        offset = offset + coefficients[1, k - 1] * rho**k
    if flat_field is not None:
        maps = flat_field_maps(flat_field, image.shape[0], image.shape[1])  # [2, H, W]
        gain, offset = gain + maps[0][..., None], offset + maps[1][..., None]
    return image * gain + offset


def test_the_models_response_is_the_response_written_out():
    rho = rho_of(intrinsics(), 48, 32)
    image, coefficients, cells = torch.rand(32, 48, 1), torch.randn(2, FALLOFF_ORDER) * 0.3, torch.randn(2, 4, 4) * 0.1
    basis = falloff_basis(ray_directions(intrinsics(), torch.eye(3, 4), 48, 32))
    assert torch.allclose(respond(image, coefficients, basis), apply_falloff(image, coefficients, rho), atol=1e-6)
    assert torch.allclose(
        respond(image, coefficients, basis, cells), apply_falloff(image, coefficients, rho, cells), atol=1e-6
    )


def falloff_at_corner(coefficients, K, width, height):
    """(gain, offset) of the response at the camera's pixel farthest off-axis."""
    rho = rho_of(K, width, height).max()
    powers = torch.stack([rho**k for k in range(1, coefficients.shape[1] + 1)])  # [K]
    return float(1.0 + powers @ coefficients[0]), float(powers @ coefficients[1])


def test_no_falloff_is_the_identity_and_a_falloff_grows_towards_the_corners():
    rho = rho_of(intrinsics(), 48, 32)  # [H, W, 1]
    assert rho.shape == (32, 48, 1)
    assert float(rho.min()) == pytest.approx(2 * (0.5 / 50) ** 2)  # the four pixels around the principal point
    assert torch.allclose(rho, rho.flip(0)) and torch.allclose(rho, rho.flip(1))  # centred
    image = torch.rand(32, 48, 1)
    assert torch.equal(apply_falloff(image, torch.zeros(2, FALLOFF_ORDER), rho), image)
    darker = apply_falloff(torch.ones(32, 48, 1), torch.tensor([[-0.5, 0.0], [0.0, 0.0]]), rho)
    assert float(darker[16, 24]) == pytest.approx(1.0, abs=1e-3) and float(darker[0, 0]) < 0.9
    gain, offset = falloff_at_corner(torch.tensor([[-0.5, 0.0], [0.1, 0.0]]), intrinsics(), 48, 32)
    assert gain == pytest.approx(float(darker[0, 0])) and offset == pytest.approx(0.2 * (1 - gain))


def test_the_pattern_is_the_same_at_any_render_resolution():
    """The warm-up trains at a fraction of the resolution: the same fall-off at the same places."""
    full = rho_of(intrinsics(50.0, 48, 32), 48, 32)[..., 0]  # [32, 48]
    half = rho_of(intrinsics(25.0, 24, 16), 24, 16)[..., 0]  # [16, 24]
    blocks = full.reshape(16, 2, 24, 2).mean(dim=(1, 3))  # each half-resolution pixel's four
    assert torch.allclose(half, blocks, atol=(1 / 50) ** 2)


def test_training_renders_through_the_fitted_falloff_and_the_scenes_renders_do_not():
    camera = make_camera(1)
    model = make_model(camera_falloff=True)
    assert "camera_falloff" in model.get_param_groups()
    model.train()
    plain = model.get_outputs(camera)["thermal"].detach()
    model.eval()
    scene = model.get_outputs(camera)["thermal"].clone()
    coefficients = torch.tensor([[-0.4, 0.1], [0.05, 0.0]])
    with torch.no_grad():
        model.camera_falloff.copy_(coefficients)
    model.train()
    recorded = model.get_outputs(camera)["thermal"].detach()
    rho = rho_of(intrinsics(), 48, 32)
    assert not torch.allclose(recorded, plain)
    assert torch.allclose(recorded, apply_falloff(plain, coefficients, rho), atol=1e-6)
    model.eval()
    assert torch.allclose(model.get_outputs(camera)["thermal"], scene)  # the viewer's, ns-render's: the scene
    assert torch.allclose(as_recorded(model, scene, camera), apply_falloff(scene, coefficients, rho), atol=1e-6)
    assert torch.equal(as_recorded(object(), scene, camera), scene)  # a model without one (splatfacto)


def test_the_graphed_camera_response_is_the_same_function_on_any_device():
    """`graphed_camera` (on by default) sends training renders through `GraphedCalls`, which records CUDA
    graphs on a GPU (tests/test_gpu_parity.py) and runs the response itself elsewhere: the same images
    with it off; without a camera model there is nothing to graph."""
    camera = make_camera(1)
    torch.manual_seed(0)
    graphed = make_model(camera_falloff=True, camera_flat_field=4)
    torch.manual_seed(0)
    eager = make_model(camera_falloff=True, camera_flat_field=4, graphed_camera=False)
    assert graphed.parts.camera.graphed is not None and eager.parts.camera.graphed is None
    assert make_model(camera_falloff=False).parts.camera.graphed is None
    with torch.no_grad():
        for model in (graphed, eager):
            model.camera_falloff.copy_(torch.tensor([[-0.4, 0.1], [0.05, 0.0]]))
            model.camera_flat_field.normal_(0.0, 0.1, generator=torch.Generator().manual_seed(1))
    graphed.train()
    eager.train()
    assert torch.equal(graphed.get_outputs(camera)["thermal"], eager.get_outputs(camera)["thermal"])


def test_the_run_reports_the_fitted_falloff():
    model = make_model(camera_falloff=True)
    with torch.no_grad():
        model.camera_falloff.copy_(torch.tensor([[-0.4, 0.1], [0.05, 0.0]]))
    entries = {d.part: d.choice for d in model.decisions()}
    assert entries["camera fall-off"] == "on: gain 1 -0.400 rho +0.100 rho^2, offset +0.050 rho +0.000 rho^2"
    assert {d.part: d.choice for d in make_model().decisions()}["camera fall-off"] == "off"


def test_the_falloff_trains_and_is_found_from_frames_that_carry_it():
    """Gradient reaches the four coefficients in a training step; and fitted alone to frames that carry a
    known fall-off over the model's own renders, they converge to it."""
    camera = make_camera(1)
    model = make_model(camera_falloff=True)
    model.train()
    outputs = model.get_outputs(camera)
    losses = model.get_loss_dict(outputs, {"image": torch.rand(32, 48, 1), "image_idx": 1})
    sum(losses.values()).backward()
    assert model.camera_falloff.grad is not None and model.camera_falloff.grad.abs().sum() > 0
    truth = torch.tensor([[-0.3, 0.0], [0.02, 0.0]])
    fitted = fit_camera_model_alone(model, truth, lr=0.01, steps=1500).corner
    assert fitted == pytest.approx(falloff_at_corner(truth, intrinsics(), 48, 32), abs=0.02)


class CameraFit(NamedTuple):
    corner: Tuple[float, float]
    """(gain, offset) of the fitted fall-off at the corner (`falloff_at_corner`)."""
    map_spread: Optional[float]
    """The fitted flat-field map's largest gain deviation from its mean (None: no map fitted)."""


def fit_camera_model_alone(model, truth, lr: float, steps: int, map_lr: Optional[float] = None) -> CameraFit:
    """The model's four coefficients fitted alone (its Gaussians fixed) by Adam at `lr` for `steps` steps to
    three of its renders that carry the fall-off `truth` [2, 2]; with `map_lr`, an 8x8 flat-field map (zero at
    the start) fitted beside them at that rate, as training fits both."""
    rho = rho_of(intrinsics(), 48, 32)
    with torch.no_grad():
        model.camera_falloff.zero_()
        scenes = [model.get_outputs(make_camera(i))["thermal"] + 0.5 for i in range(3)]  # [H, W, 1] each
    frames = [apply_falloff(s, truth, rho) for s in scenes]
    cells = None if map_lr is None else torch.zeros(2, 8, 8, requires_grad=True)  # [2, n, n]
    groups = [{"params": [model.camera_falloff], "lr": lr}] + (
        [] if cells is None else [{"params": [cells], "lr": map_lr}]
    )
    optimizer = torch.optim.Adam(groups)
    for step in range(steps):
        optimizer.zero_grad()
        i = step % 3
        loss = (apply_falloff(scenes[i], model.camera_falloff, rho, cells) - frames[i]).abs().mean()
        loss.backward()
        optimizer.step()
    spread = None if cells is None else float(centred_cells(cells.detach())[0].abs().max())
    return CameraFit(falloff_at_corner(model.camera_falloff.detach(), intrinsics(), 48, 32), spread)


def test_the_methods_rate_lets_the_camera_take_a_strong_vignetting_early():
    """The full method's rate for the fall-off reaches a strong vignetting (35% at the corner, as the
    generated vignetting scene's) within a thousand steps of a fit alone, which the MLPs' rate (1e-3, the rate
    before docs/results/camera_rate_h200) cannot: where the camera is slow, the scene and a view term learn
    part of the camera's pattern first and keep it."""
    from thermal_wild_ns.method_configs import wild_thermal_optimizers

    rate = wild_thermal_optimizers()["camera_falloff"]["optimizer"].lr
    corner = rho_of(intrinsics(), 48, 32).max()
    truth = torch.tensor([[-0.35 / float(corner), 0.0], [0.0, 0.0]])  # gain 0.65 at the corner
    expected, _ = falloff_at_corner(truth, intrinsics(), 48, 32)
    assert expected == pytest.approx(0.65)
    model = make_model(camera_falloff=True)
    model.train()
    assert fit_camera_model_alone(model, truth, lr=rate, steps=1000).corner[0] == pytest.approx(expected, abs=0.03)
    assert abs(fit_camera_model_alone(model, truth, lr=1e-3, steps=1000).corner[0] - expected) > 0.1


def test_the_methods_map_rate_leaves_a_radial_vignetting_to_the_falloff():
    """The flat-field map's cells learn at a tenth of the fall-off's rate: fitted beside the fall-off to frames
    with a radial vignetting and no cell pattern (as the synthetic survey's sensor), they stay small, where at
    the fall-off's own rate they take a large share of it; on the GPU that share came with lower held-back
    scores and an earlier stop on the survey, and no scene gained (docs/results/map_rate_h200)."""
    from thermal_wild_ns.method_configs import wild_thermal_optimizers

    rates = wild_thermal_optimizers()
    falloff_rate = rates["camera_falloff"]["optimizer"].lr
    map_rate = rates["camera_flat_field"]["optimizer"].lr
    corner = rho_of(intrinsics(), 48, 32).max()
    truth = torch.tensor([[-0.35 / float(corner), 0.0], [0.0, 0.0]])
    model = make_model(camera_falloff=True)
    model.train()
    at_method_rate = fit_camera_model_alone(model, truth, lr=falloff_rate, steps=1000, map_lr=map_rate).map_spread
    at_falloff_rate = fit_camera_model_alone(model, truth, lr=falloff_rate, steps=1000, map_lr=falloff_rate).map_spread
    assert at_method_rate < 0.1 < 0.2 < at_falloff_rate, (at_method_rate, at_falloff_rate)


def test_a_checkpoint_with_or_without_the_falloff_is_refused_by_a_model_of_the_other_kind():
    with_falloff = make_model(camera_falloff=True).state_dict()
    with pytest.raises(ValueError, match=r"checkpoint has the camera fall-off \(camera_falloff\) but this config"):
        make_model().load_state_dict(dict(with_falloff))
    with pytest.raises(ValueError, match=r"checkpoint lacks the camera fall-off"):
        make_model(camera_falloff=True).load_state_dict(make_model().state_dict())
    make_model(camera_falloff=True).load_state_dict(dict(with_falloff))


def test_a_run_of_the_rule_that_decided_the_whole_camera_model_still_loads_and_renders_as_it_trained():
    """Before the fall-off was split from the map, a capture whose content moves too little for the map got no
    camera model at all. Its checkpoint loads with its own config.yml (today's rule would fit the fall-off there)
    and renders without one; where the map's rule would fit the map, or the config asks for the fall-off alone,
    a checkpoint without it is still refused."""
    rule = dict(camera_falloff=True, camera_flat_field=8, camera_pattern_min_motion=0.22)
    earlier = make_model(camera_falloff=False).state_dict()  # what the earlier rule trained at motion 0.15
    model = make_model(**rule, metadata={"content_motion": 0.15})
    assert model.camera_falloff is not None and model.camera_flat_field is None
    model.load_state_dict(dict(earlier))
    assert model.camera_falloff is None and model.parts.camera.graphed is None
    assert "checkpoint" in {d.part: d for d in model.decisions()}["camera fall-off"].why
    thermal = torch.rand(32, 48, 1)
    assert model.as_recorded(thermal, make_camera(1)) is thermal  # rendered as it trained: no camera model
    with pytest.raises(ValueError, match=r"checkpoint lacks the camera fall-off"):
        make_model(**rule, metadata={"content_motion": 0.3}).load_state_dict(dict(earlier))
    with pytest.raises(ValueError, match=r"checkpoint lacks the camera fall-off"):
        make_model(camera_falloff=True).load_state_dict(dict(earlier))


def test_a_clean_truth_is_scored_against_the_scene_and_a_recorded_frame_through_the_camera(tmp_path, demo_scene_dir):
    """The demo's held-out views are its clean truth (no camera recorded them): `novel` compares the scene
    with them, whatever the fitted fall-off; `time` compares with the frame as recorded, through it."""
    from thermal_wild_ns.demo import demo_trainer_config
    from thermal_wild_ns.pipeline.evaluation import evaluate
    from thermal_wild_ns.training.trainer import seeded_trainer

    config = demo_trainer_config(tmp_path, steps=1, max_gaussians=3000)
    config.pipeline.datamanager.dataparser.data = demo_scene_dir
    config.pipeline.model.camera_falloff = True
    config.pipeline.model.camera_pattern_min_motion = 0.0  # fitted here although the demo's content barely moves
    pipeline = seeded_trainer(config).pipeline
    dataset = pipeline.datamanager.eval_dataset
    assert all(dataset.is_clean_truth(i) for i in range(len(dataset)))
    assert not pipeline.datamanager.train_dataset.is_clean_truth(0)
    none = evaluate(pipeline, protocols=("novel", "time"))
    with torch.no_grad():
        pipeline.model.camera_falloff.copy_(torch.tensor([[-0.5, 0.0], [0.1, 0.0]]))
    strong = evaluate(pipeline, protocols=("novel", "time"))
    assert strong["psnr_novel"] == pytest.approx(none["psnr_novel"], abs=1e-9)
    assert abs(strong["psnr_time"] - none["psnr_time"]) > 0.1
    # nerfstudio's eval image during training (`time`) compares with the frame as recorded too
    metrics, images = pipeline.get_eval_image_metrics_and_images(0)
    frame = images["img"][..., 0].numpy()  # [H, 2W]: the frame | the render
    width = frame.shape[1] // 2
    recorded = [dataset.recorded_image(i).clip(0, 1) for i in range(len(dataset))]
    assert any(np.allclose(frame[:, :width], r, atol=1e-6) for r in recorded)
    assert not any(
        np.allclose(frame[:, :width], dataset.get_image_float32(i)[..., 0].numpy().clip(0, 1))
        for i in range(len(dataset))
    )


def test_a_flat_field_map_is_zero_mean_and_at_the_same_places_at_any_resolution():
    cells = torch.randn(2, 4, 4)
    maps = flat_field_maps(cells, 32, 48)  # [2, H, W]
    assert maps.shape == (2, 32, 48)
    assert torch.allclose(maps.mean(dim=(1, 2)), torch.zeros(2), atol=1e-5)  # no overall level or gain
    # a map that is constant is no map: a frame's level and gain are the photometric state's
    assert torch.allclose(flat_field_maps(torch.full((2, 4, 4), 0.3), 32, 48), torch.zeros(2, 32, 48), atol=1e-6)
    half = flat_field_maps(cells, 16, 24)
    blocks = maps.reshape(2, 16, 2, 24, 2).mean(dim=(2, 4))  # each half-resolution pixel's four
    assert torch.allclose(half, blocks, atol=0.15 * float(cells.abs().max()))
    # cell (0, 3) (top right) raised: the map is highest in the top right corner, lowest far from it
    raised = torch.zeros(2, 4, 4)
    raised[0, 0, 3] = 1.0
    gain = flat_field_maps(raised, 32, 48)[0]
    assert float(gain[0, -1]) == float(gain.max()) and float(gain[-1, 0]) == float(gain.min())


def test_the_flat_field_map_is_rendered_into_training_and_found_from_frames_that_carry_it():
    """A left-to-right offset no radial fall-off can hold: the map fits it, the scene's renders leave it out."""
    with pytest.raises(InputError, match="camera_flat_field -1: cells per image side"):
        make_model(camera_falloff=True, camera_flat_field=-1)
    # the camera model switched off switches its map off too (wild-thermal's default map needs no unsetting)
    unmodelled = make_model(camera_falloff=False, camera_flat_field=4)
    assert unmodelled.camera_flat_field is None and "camera_flat_field" not in unmodelled.get_param_groups()
    camera = make_camera(1)
    model = make_model(camera_falloff=True, camera_flat_field=4)
    assert "camera_flat_field" in model.get_param_groups()
    truth = torch.zeros(2, 4, 4)
    truth[1] = torch.linspace(-0.05, 0.05, 4)  # the offset grows from left to right
    with torch.no_grad():
        model.camera_flat_field.copy_(truth)
    model.train()
    recorded = model.get_outputs(camera)["thermal"]
    model.eval()
    scene = model.get_outputs(camera)["thermal"]
    assert torch.allclose(recorded - scene, flat_field_maps(truth, 32, 48)[1][..., None], atol=1e-5)
    decisions = {d.part: d for d in model.decisions()}
    assert decisions["camera flat-field map"].choice == "on: 4x4: gain +-0.000, offset +-0.050"
    assert decisions["camera flat-field map"].decided_by == "config"
    model.train()
    losses = model.get_loss_dict(model.get_outputs(camera), {"image": torch.rand(32, 48, 1), "image_idx": 1})
    sum(losses.values()).backward()
    assert model.camera_flat_field.grad is not None and model.camera_flat_field.grad.abs().sum() > 0
    rho = rho_of(intrinsics(), 48, 32)
    with torch.no_grad():
        model.camera_flat_field.zero_()
        scenes = [model.get_outputs(make_camera(i))["thermal"] + 0.5 for i in range(3)]  # [H, W, 1] each
    frames = [apply_falloff(s, torch.zeros(2, FALLOFF_ORDER), rho, truth) for s in scenes]
    radial_only = torch.zeros(2, FALLOFF_ORDER, requires_grad=True)
    optimizer = torch.optim.Adam([model.camera_flat_field, radial_only], lr=0.01)
    for step in range(600):
        optimizer.zero_grad()
        i = step % 3
        loss = (apply_falloff(scenes[i], radial_only, rho, model.camera_flat_field) - frames[i]).abs().mean()
        loss.backward()
        optimizer.step()
    fitted = flat_field_maps(model.camera_flat_field.detach(), 32, 48)
    assert torch.allclose(fitted, flat_field_maps(truth, 32, 48), atol=0.01)


def test_a_checkpoint_with_or_without_the_flat_field_map_is_refused_by_a_model_of_the_other_kind():
    with_map = make_model(camera_falloff=True, camera_flat_field=4).state_dict()
    with pytest.raises(ValueError, match=r"checkpoint has the camera flat-field map \(camera_flat_field\)"):
        make_model(camera_falloff=True).load_state_dict(dict(with_map))
    make_model(camera_falloff=True, camera_flat_field=4).load_state_dict(dict(with_map))


def test_content_motion_is_how_far_the_scene_points_move_across_the_frames_that_see_them():
    from nerfstudio.cameras.cameras import Cameras

    from thermal_wild_ns.data.content_motion import content_motion

    def cameras(x_positions):  # looking down -z (nerfstudio's axes) from 10 m above the origin, moved along x
        c2w = torch.zeros(len(x_positions), 3, 4)
        c2w[:, :, :3] = torch.eye(3)
        c2w[:, 0, 3] = torch.tensor(x_positions)
        c2w[:, 2, 3] = 10.0
        return Cameras(camera_to_worlds=c2w, fx=100.0, fy=100.0, cx=50.0, cy=50.0, width=100, height=100)

    points = torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [2.0, -1.0, 0.0]])
    assert content_motion(cameras([0.0, 0.0, 0.0]), points) == pytest.approx(0.0, abs=1e-6)  # the camera never moves
    # moved by 2 m at 10 m, focal 100 px over 100 px: each point moves 0.2 of the frame; two frames: spread 0.1
    assert content_motion(cameras([0.0, 2.0]), points) == pytest.approx(0.1, abs=1e-4)
    assert content_motion(cameras([0.0, 2.0, 4.0]), points) > content_motion(cameras([0.0, 1.0, 2.0]), points)
    assert content_motion(cameras([0.0, 100.0]), points) is None  # no point seen twice
    assert content_motion(cameras([0.0, 2.0]), None) is None


def test_the_flat_field_map_is_fitted_where_the_content_crosses_the_sensor_and_the_falloff_everywhere(
    tmp_path, demo_scene_dir
):
    """The full method's rule (`camera_pattern_min_motion`): a synthetic drone survey, whose ground crosses
    the frames, gets the radial fall-off and the map; the demo's orbit, which keeps its target in the middle,
    gets the fall-off alone (a fixed radial shape cannot take the scene in); the run's decisions say which and
    why."""
    from thermal_wild_ns.data.content_motion import content_motion
    from thermal_wild_ns.data.dataparsers import ThermalDemoDataParserConfig
    from thermal_wild_ns.method_configs import method_trainer

    config = method_trainer("wild-thermal").pipeline.model
    assert config.camera_falloff and config.camera_flat_field > 0 and config.camera_pattern_min_motion > 0
    assert not method_trainer("wild-thermal-emission-mlp").pipeline.model.camera_falloff  # the paper's rows
    verdicts = {}
    for name, parser in (
        ("survey", ThermalDemoDataParserConfig(data=tmp_path / "survey", scene="survey", survey_frames=9)),
        ("demo", ThermalDemoDataParserConfig(data=demo_scene_dir)),
    ):
        outputs = parser.setup().get_dataparser_outputs("train")
        motion = content_motion(outputs.cameras, outputs.metadata["points3D_xyz"])
        overrides = {
            f: getattr(config, f) for f in ("camera_falloff", "camera_flat_field", "camera_pattern_min_motion")
        }
        model = make_model(**overrides, metadata={"content_motion": motion})
        decisions = {d.part: d for d in model.decisions()}
        verdicts[name] = (motion, model.camera_falloff is not None, model.camera_flat_field is not None, decisions)
    motion, falloff, flat_field, decisions = verdicts["survey"]
    assert motion >= config.camera_pattern_min_motion and falloff and flat_field
    assert decisions["camera fall-off"].choice.startswith("on: gain 1")
    assert decisions["camera flat-field map"].choice.startswith("on: 8x8")
    assert decisions["camera flat-field map"].decided_by == "data"
    assert f"moves {motion:.2f} of the frame" in decisions["camera flat-field map"].why
    motion, falloff, flat_field, decisions = verdicts["demo"]
    assert motion < config.camera_pattern_min_motion and falloff and not flat_field
    assert decisions["camera fall-off"].choice.startswith("on: gain 1")
    no_map = decisions["camera flat-field map"]
    assert no_map.choice == "off" and no_map.decided_by == "data" and "not told apart" in no_map.why
    unknown = make_model(**overrides)  # no seed points seen twice: nothing says the map can be told apart
    unknown_map = {d.part: d for d in unknown.decisions()}["camera flat-field map"]
    assert unknown.camera_falloff is not None and unknown.camera_flat_field is None and "unknown" in unknown_map.why


def test_a_run_fitting_the_camera_pattern_trains_through_ns_train_and_loads_with_it(tmp_path):
    """The full method's defaults on a capture whose content crosses the sensor: the fall-off and the map
    are fitted in training (their own Adam groups), saved, and a loading command (ns-eval's `eval_setup`)
    decides the same from the same data and loads them."""
    from nerfstudio.utils.eval_utils import eval_setup

    from thermal_wild_ns.data.dataparsers import ThermalDemoDataParserConfig
    from thermal_wild_ns.demo import demo_trainer_config
    from thermal_wild_ns.training.trainer import seeded_trainer

    config = demo_trainer_config(tmp_path, steps=3, max_gaussians=3000)
    config.pipeline.datamanager.dataparser = ThermalDemoDataParserConfig(
        data=tmp_path / "survey", scene="survey", survey_frames=9
    )
    config.pipeline.datamanager.camera_res_scale_factor = 0.125  # 80 x 64 renders: a quick CPU run
    config.save_config()  # as ns-train does
    trainer = seeded_trainer(config)
    model = trainer.pipeline.model
    assert model.camera_flat_field is not None and "camera_flat_field" in trainer.optimizers.optimizers
    trainer.train()
    fitted = model.camera_flat_field.detach().clone()
    assert fitted.abs().sum() > 0  # trained: the map moved from flat
    _, pipeline, _, _ = eval_setup(config.get_base_dir() / "config.yml", test_mode="test")
    assert torch.equal(pipeline.model.camera_flat_field.detach().cpu(), fitted.cpu())
