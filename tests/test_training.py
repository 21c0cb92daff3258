"""End to end on CPU: the demo scene trains with nerfstudio's Trainer, the loss falls, the trained
model beats the untrained one on held-out views, and the checkpoint loads back (torch >= 2.6)."""

import json

import cv2
import numpy as np
import pytest
import torch
from real_data import DUNR

from thermal_wild_ns.demo import demo_trainer_config
from thermal_wild_ns.pipeline.evaluation import evaluate
from thermal_wild_ns.state_names import CANONICAL

pytestmark = pytest.mark.slow  # trains through nerfstudio: minutes on a CPU


def test_short_training_run_and_checkpoint_roundtrip(tmp_path, demo_scene_dir):
    from nerfstudio.utils.eval_utils import eval_setup

    config = demo_trainer_config(tmp_path, steps=120, max_gaussians=6000)
    config.pipeline.datamanager.dataparser.data = demo_scene_dir
    config.pipeline.eval_fit_steps = 10  # ns-eval's embedding fits: short, as the in-process evaluation below
    config.save_config()
    trainer = config.setup(local_rank=0, world_size=1)
    trainer.setup()
    # training cameras reach the model on the host, the datamanager's own (undistorted) cameras
    datamanager = trainer.pipeline.datamanager
    camera, batch = datamanager.next_train(0)
    idx = camera.metadata["cam_idx"]
    assert camera.device.type == "cpu" and torch.equal(
        camera.camera_to_worlds, datamanager.train_cameras[idx : idx + 1].camera_to_worlds.cpu()
    )
    assert torch.equal(camera.fx, datamanager.train_cameras[idx : idx + 1].fx.cpu()) and batch["image"].shape[:2] == (
        camera.height,
        camera.width,
    )
    # the viewer's colour bar: the demo scene documents its temperature bounds (-10..40 degC)
    bar = trainer.pipeline.model.viewer_controls.viewer_colour_bar.value
    values = [float(v) for v in bar.split(": ", 1)[1].removesuffix(" degC").split(", ")]
    assert (
        bar.startswith("iron 0->1")
        and len(values) == 5
        and values == sorted(values)
        and -10 <= values[0] < values[-1] <= 40
    )
    before = evaluate(trainer.pipeline, protocols=("time",))
    losses = []
    model = trainer.pipeline.model
    original = model.get_loss_dict

    def record(outputs, batch, metrics_dict=None):
        out = original(outputs, batch, metrics_dict)
        losses.append(float(sum(out.values())))
        return out

    model.get_loss_dict = record
    trainer.train()
    after = evaluate(trainer.pipeline, tmp_path / "after", fit_steps=10)
    first, last = sum(losses[:20]) / 20, sum(losses[-20:]) / 20
    assert last < 0.7 * first, (first, last)
    assert after["psnr_time"] > before["psnr_time"] + 5.0, (before["psnr_time"], after["psnr_time"])
    # every protocol scored; fitting on a half or on the frame's own state can only help the fit it scores
    assert {f"{m}_{p}" for m in ("psnr", "ssim") for p in ("novel", "time", "aligned", "half", "oracle")} <= set(after)
    assert after["psnr_aligned"] >= after["psnr_novel"] - 1e-6  # a least-squares fit never lowers PSNR
    assert len(list((tmp_path / "after").glob("test_??.png"))) == 5
    # the demo is calibrated (°C bounds): each view in °C too, beside the panel above with a label strip
    celsius_panels = sorted((tmp_path / "after").glob("test_??_celsius.png"))
    panel, celsius_panel = (cv2.imread(str(p)) for p in (tmp_path / "after" / "test_00.png", celsius_panels[0]))
    assert len(celsius_panels) == 5 and celsius_panel.shape == (panel.shape[0] + 22, *panel.shape[1:])

    # checkpoint -> load (as ns-eval/ns-render/ns-viewer do) -> identical render
    _, loaded, ckpt, step = eval_setup(config.get_base_dir() / "config.yml", test_mode="test")
    assert step == 119
    camera, _ = loaded.datamanager.fixed_indices_eval_dataloader[0]
    trainer.pipeline.eval()
    with torch.no_grad():
        a = trainer.pipeline.model.get_outputs_for_camera(camera.to(trainer.pipeline.device))["thermal"]
        b = loaded.model.get_outputs_for_camera(camera)["thermal"]
    torch.testing.assert_close(a, b)
    state = torch.load(ckpt, map_location="cpu")  # weights_only default of torch >= 2.6
    assert "pipeline" in state

    # ns-eval: the benchmark's protocol, saying which embedding mode it used
    from nerfstudio.scripts.eval import ComputePSNR

    ComputePSNR(load_config=config.get_base_dir() / "config.yml", output_path=tmp_path / "eval.json").main()
    results = json.loads((tmp_path / "eval.json").read_text())["results"]
    assert results["views"] == 5 and "psnr_oracle" in results and "oracle" in results["protocols"]
    # the headline is the time state; the cheap protocols match the in-process scores of the same model
    assert results["psnr"] == results["psnr_time"]
    for protocol in ("novel", "time", "aligned"):
        assert results[f"psnr_{protocol}"] == pytest.approx(after[f"psnr_{protocol}"], abs=1e-4), protocol

    # ns-export gaussian-splat: every Gaussian, grey DC colour = the emission as rendered (MLP included)
    from nerfstudio.models.splatfacto import RGB2SH
    from nerfstudio.scripts.exporter import ExportGaussianSplat
    from plyfile import PlyData

    ExportGaussianSplat(load_config=config.get_base_dir() / "config.yml", output_dir=tmp_path / "export").main()
    vertex = PlyData.read(str(tmp_path / "export" / "splat.ply"))["vertex"]
    names = vertex.data.dtype.names
    assert len(vertex) == loaded.model.num_points and {"x", "f_dc_0", "f_dc_2", "opacity", "scale_0", "rot_3"} <= set(
        names
    )
    with torch.no_grad():
        emission = loaded.model.gaussian_emission(loaded.model.state_embedding(CANONICAL))
        expected = RGB2SH(emission.clamp(0, 1))[:, 0].numpy()
    np.testing.assert_allclose(np.asarray(vertex["f_dc_0"]), expected, atol=1e-6)
    np.testing.assert_array_equal(np.asarray(vertex["f_dc_0"]), np.asarray(vertex["f_dc_2"]))  # grey

    # wild-thermal-export gaussian-splat: the same PLY plus the thermal values and what they mean
    from thermal_wild_ns.export.gaussian_splat import ExportThermalSplat, thermal_values

    ExportThermalSplat(load_config=config.get_base_dir() / "config.yml", output_dir=tmp_path / "export_thermal").main()
    ply = PlyData.read(str(tmp_path / "export_thermal" / "splat.ply"))
    thermal_vertex = ply["vertex"]
    assert len(thermal_vertex) == len(vertex) and set(names) | {"thermal"} == set(thermal_vertex.data.dtype.names)
    np.testing.assert_array_equal(np.asarray(thermal_vertex["f_dc_0"]), np.asarray(vertex["f_dc_0"]))
    np.testing.assert_allclose(np.asarray(thermal_vertex["thermal"]), thermal_values(loaded), rtol=1e-6)
    rng = loaded.datamanager.train_dataset.thermal_range
    assert rng.low - 1 <= float(np.median(thermal_vertex["thermal"])) <= rng.high + 1
    baked = "thermal_wild_ns frame_embedding canonical (typical; the emission MLP was baked with this frame embedding)"
    assert baked in ply.comments
    assert not list((tmp_path / "export_thermal").glob("*.partial*"))

    # ns-render (interpolated path) writes frames and a video, with the bundled ffmpeg if the system has none
    from nerfstudio.scripts.render import RenderInterpolated

    for fmt, out in (("images", tmp_path / "frames"), ("video", tmp_path / "path.mp4")):
        RenderInterpolated(
            load_config=config.get_base_dir() / "config.yml", output_path=out, interpolation_steps=2, output_format=fmt
        ).main()
    assert len(list((tmp_path / "frames").glob("*.jpg"))) == 2 * (len(loaded.datamanager.eval_dataset) - 1)
    assert (tmp_path / "path.mp4").stat().st_size > 1000

    # wild-thermal-render: the same command, plus radiometric frames in the dataset's units
    import imageio_ffmpeg

    from thermal_wild_ns.rendering.radiometric_render import RenderInterpolated as ThermalRenderInterpolated

    frames = 2 * (len(loaded.datamanager.eval_dataset) - 1)
    rng = loaded.datamanager.train_dataset.thermal_range
    renders = []
    for run in ("a", "b"):
        ThermalRenderInterpolated(
            load_config=config.get_base_dir() / "config.yml",
            output_path=tmp_path / f"path_{run}.mp4",
            interpolation_steps=2,
            output_format="video",
            radiometric="uint16",
        ).main()
        pngs = sorted((tmp_path / f"path_{run}_radiometric").glob("*.png"))
        renders.append([cv2.imread(str(f), cv2.IMREAD_UNCHANGED) for f in pngs])
    assert imageio_ffmpeg.count_frames_and_secs(str(tmp_path / "path_a.mp4"))[0] == frames == len(renders[0])
    assert all(im.dtype == np.uint16 and im.ndim == 2 for im in renders[0])
    assert all(
        rng.low <= int(im.min()) and int(im.max()) <= rng.high for im in renders[0]
    )  # back in the dataset's native range
    assert all(int(im.max()) - int(im.min()) > 100 for im in renders[0])  # an image, not a constant
    assert all(np.array_equal(a, b) for a, b in zip(*renders))  # two renders of one path are identical
    ThermalRenderInterpolated(
        load_config=config.get_base_dir() / "config.yml",
        output_path=tmp_path / "path_c.mp4",
        interpolation_steps=2,
        output_format="video",
        radiometric="celsius",
    ).main()
    celsius = [np.load(f) for f in sorted((tmp_path / "path_c_radiometric").glob("*.npy"))]
    assert len(celsius) == frames and all(c.dtype == np.float32 for c in celsius)
    assert all(rng.celsius_low <= c.min() and c.max() <= rng.celsius_high for c in celsius)
    np.testing.assert_allclose(
        celsius[0],
        rng.to_celsius(rng.normalize(renders[0][0])),
        atol=(rng.celsius_high - rng.celsius_low) / (rng.high - rng.low),
    )


def test_dunr_loads_with_dataset_level_normalisation():

    import pytest

    from thermal_wild_ns.data.dataparsers import ThermalDataParserConfig
    from thermal_wild_ns.pipeline.datamanager import ThermalDataset

    if not DUNR.is_dir():
        pytest.skip(f"real DUNR scene not found at {DUNR} (it sits in ../shared beside the checkout)")
    parser = ThermalDataParserConfig(data=DUNR, seed_points="random", num_random_points=100).setup()
    train = parser.get_dataparser_outputs("train")
    test = parser.get_dataparser_outputs("test")
    assert len(train.image_filenames) + len(test.image_filenames) == 45
    assert len(test.image_filenames) == 6  # every 8th frame
    rng = train.metadata["thermal_range"]
    # DUNR README: p0.5-p99.5 of all frames is 3835-4237; our p0.1-p99.9 range must contain it
    assert rng.dtype == "uint16" and 3000 < rng.low <= 3835 and 4237 <= rng.high < 4500
    dataset = ThermalDataset(train)
    a, b = dataset.get_image_float32(0), dataset.get_image_float32(20)
    assert a.shape == (512, 640, 1) and a.dtype == torch.float32
    # one range for every frame: the drift between frames survives normalisation
    assert abs(float(a.median()) - float(b.median())) > 0.05
    assert len(torch.unique(a)) > 256  # no 8-bit re-quantisation of 16-bit data
    # what training caches is 1-channel float; the viewer's thumbnails (dataset[idx]) are grey RGB
    assert dataset.get_data(0)["image"].shape == (512, 640, 1)
    thumb = dataset[0]["image"]
    assert thumb.shape == (512, 640, 3) and 0.0 <= float(thumb.min()) and float(thumb.max()) <= 1.0


@pytest.mark.parametrize(
    "method",
    [
        "wild-thermal",
        "wild-thermal-3dgs",
        "wild-thermal-3dgs-histeq",
        "wild-thermal-3dgs-bbhe",
        "wild-thermal-3dgs-stab",
        "wild-thermal-3dgs-stab-bbhe",
        "wild-thermal-emission-mlp",
        "wild-thermal-paper",
    ],
)
def test_every_ablation_variant_trains(method, tmp_path, demo_scene_dir):
    """Each registered variant runs a few steps on the demo scene and evaluates in the original
    radiometric space (renders of preprocessed variants mapped back through the inverse LUTs)."""
    config = demo_trainer_config(tmp_path, steps=8, max_gaussians=3000, method=method)
    config.pipeline.datamanager.dataparser.data = demo_scene_dir
    trainer = config.setup(local_rank=0, world_size=1)
    trainer.setup()
    trainer.train()
    model = trainer.pipeline.model
    assert (
        model.emission_mlp is not None
        if method in ("wild-thermal", "wild-thermal-emission-mlp", "wild-thermal-paper")
        else model.emission_mlp is None
    )
    preprocessing = config.pipeline.datamanager.preprocessing
    # the full method's rule trains the demo on its raw frames (they differ by level offsets alone)
    raw = preprocessing.variant == "none" or preprocessing.skip_when_stable
    assert (trainer.pipeline.datamanager.preprocessed is None) == raw
    result = evaluate(trainer.pipeline, fit_steps=2)
    assert all(
        np.isfinite(result[f"psnr_{p}"]) and result[f"psnr_{p}"] > 5.0
        for p in ("novel", "time", "aligned", "half", "oracle")
    )
    has_state = not raw or model.emission_mlp is not None
    # the demo drifts: a method with a photometric state renders a held-out frame differently at its
    # time state than at the state fitted to the frame; a method without renders the same image
    # (both scored against the recorded frame)
    assert (result["psnr_time"] != result["psnr_oracle"]) == has_state
    # the gap's LUT share: the time state with the frame's own LUT differs from it only where there are LUTs
    assert (result["psnr_oracle_lut"] != result["psnr_time"]) == (not raw)


def test_viewer_screenshot_shows_the_thermal_colormap(tmp_path, demo_scene_dir):
    """ns-viewer on a trained demo scene, looked at in headless Chromium: the 3D view shows the
    render in the iron colormap (setup_env.sh installs Debian's chromium)."""
    import shutil

    from scipy.spatial import cKDTree

    from thermal_wild_ns.analysis.viewer_screenshot import ScreenshotArgs, screenshot
    from thermal_wild_ns.data.palettes import palette_rgb

    if shutil.which("chromium") is None:
        pytest.skip("no chromium on PATH (setup_env.sh installs it where apt can)")
    config = demo_trainer_config(tmp_path, steps=30, max_gaussians=3000)
    config.pipeline.datamanager.dataparser.data = demo_scene_dir
    config.save_config()
    trainer = config.setup(local_rank=0, world_size=1)
    trainer.setup()
    trainer.train()
    png = screenshot(
        ScreenshotArgs(
            load_config=config.get_base_dir() / "config.yml", output=tmp_path / "viewer.png", width=1200, height=800
        )
    )
    image = cv2.imread(str(png))[..., ::-1]  # RGB
    view = image[80:-80, :600].reshape(-1, 3).astype(np.float32)
    distance, _ = cKDTree(palette_rgb("iron").astype(np.float32)).query(view)
    assert np.mean(distance < 30) > 0.8  # (almost) every pixel of the view is an iron colour
    assert len(np.unique(view, axis=0)) > 200  # and they form an image, not a flat fill


def test_the_pipeline_switches_to_training_only_the_modules_that_are_not(tmp_path, demo_scene_dir, monkeypatch):
    """nerfstudio's loop calls `pipeline.train()` before every step: where every module already trains
    it sets nothing; a module left in eval mode (e.g. by an evaluation) is switched back."""
    from demo_trainers import demo_trainer

    pipeline = demo_trainer(tmp_path, demo_scene_dir, steps=2, section="guard").pipeline
    pipeline.train()
    switched = []
    train = torch.nn.Module.train
    counted = lambda module, mode=True: switched.append(module) or train(module, mode)  # noqa: E731
    monkeypatch.setattr(torch.nn.Module, "train", counted)
    pipeline.train()
    assert switched == [] and all(module.training for module in pipeline.modules())
    pipeline.model.emission_mlp.eval()
    pipeline.train()
    assert switched and all(module.training for module in pipeline.modules())
    pipeline.eval()
    assert not any(module.training for module in pipeline.modules())


def test_a_run_is_named_after_its_data_folder(tmp_path, monkeypatch):
    """`ns-train wild-thermal thermal --data X` (the README's form) puts the run under `outputs/X/...`, not
    nerfstudio's 'unnamed' (every survey's runs in one folder); `--data` before the dataparser, a file given
    as the data and `--experiment-name` keep their meaning. Parsed as ns-train parses, nothing trained."""
    import tyro
    from nerfstudio.configs.method_configs import AnnotatedBaseConfigUnion

    flight = tmp_path / "flight_0412"
    flight.mkdir()
    (flight / "transforms.json").write_text("{}")
    monkeypatch.chdir(flight)

    def name(*args: str) -> str:
        config = tyro.cli(AnnotatedBaseConfigUnion, args=["wild-thermal", *args])
        if config.data is not None:  # nerfstudio's train main: the `--data` alias goes to the datamanager
            config.pipeline.datamanager.data = config.data
        return config.get_base_dir().parent.parent.name

    assert name("thermal", "--data", str(flight)) == "flight_0412"
    assert name("metashape-data", "--data", str(flight / "transforms.json")) == "flight_0412"  # a file: its folder
    assert name("thermal", "--data", ".") == "flight_0412"  # relative to where ns-train runs
    assert name("--data", str(tmp_path), "thermal", "--data", str(flight)) == tmp_path.name  # nerfstudio's alias
    assert name("--experiment-name", "roof", "thermal", "--data", str(flight)) == "roof"
