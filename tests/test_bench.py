"""The benchmark command end to end on CPU (two variants, a few hundred steps): the files it
writes, not the numbers. Plus the evaluation protocol's pieces."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

pytestmark = pytest.mark.slow  # trains through nerfstudio: minutes on a CPU


def test_bench_runs_end_to_end_on_cpu(tmp_path):
    from experiments.bench import BenchArgs, main, markdown
    from thermal_wild_ns.pipeline.datamanager import NOT_PREPROCESSED

    out = tmp_path / "bench"
    main(
        BenchArgs(
            methods=("wild-thermal-3dgs", "wild-thermal"),
            steps=100,
            eval_at=(50, 100),
            seeds=2,
            fit_steps=3,
            fps_frames=2,
            output_dir=out,
        )
    )
    result = json.loads((out / "bench.json").read_text())
    assert [(r["method"], r["seed"]) for r in result["runs"]] == [
        ("wild-thermal-3dgs", 0),
        ("wild-thermal-3dgs", 1),
        ("wild-thermal", 0),
        ("wild-thermal", 1),
    ]
    for run in result["runs"]:
        assert [p["step"] for p in run["curve"]] == [50, 100]
        assert run["curve"][0]["seconds"] < run["curve"][1]["seconds"]
        assert {"psnr_novel", "psnr_time", "psnr_aligned"} <= set(run["curve"][0])
        for protocol in ("novel", "time", "aligned", "half", "oracle"):  # every protocol, PSNR and SSIM
            assert np.isfinite(run[f"psnr_{protocol}"]) and 0 < run[f"ssim_{protocol}"] <= 1, protocol
        assert run["ms_per_step"] > 0 and run["gaussians"] > 0 and run["model_mb"] > 0
        assert len(run["per_view"]) == 5
        assert Path(run["config"]).is_file()  # ns-eval / ns-render can load the trained run
    # seeds make different runs
    assert result["runs"][0]["psnr_novel"] != result["runs"][1]["psnr_novel"]
    # render speed: baked vs unbaked only where there is an emission MLP to bake
    made = {"baked", "baked_fast_slices", "baked_cameras_made"}
    assert set(result["runs"][0]["render_fps"]) == made | {"splat_only"}
    assert set(result["runs"][2]["render_fps"]) == made | {"unbaked", "splat_only"}
    assert all(v > 0 for v in result["runs"][2]["render_fps"].values())
    assert all(r["render_fast_slices_difference"] == 0.0 for r in result["runs"])  # the same renders
    table = (out / "bench.md").read_text()
    runs = result["runs"]
    mean = np.mean([r["psnr_aligned"] for r in runs[2:]])
    low, high = sorted(r["psnr_aligned"] for r in runs[2:])
    aligned_table = table.split("`aligned`")[1].split("PSNR / SSIM")[0]
    # mean (min-max) over the seeds; the range left out where both ends print the same
    spread = f" ({low:.2f}–{high:.2f})" if f"{low:.2f}" != f"{high:.2f}" else ""
    assert f"| wild-thermal | {mean:.2f}{spread} / " in aligned_table
    assert "upper bound, not a result" in table.split("`oracle`")[1].splitlines()[0]
    lut_table = table.split("`oracle_lut` —")[1].split("PSNR / SSIM")[0]  # the gap's split, labelled
    assert "not a result" in lut_table.splitlines()[0] and "| wild-thermal | " in lut_table
    # what the training frames went through: both methods train on the raw frames by their configs, so the
    # table lists no decision of the rule; a run whose rule decided (asked to preprocess) is listed
    assert runs[0]["preprocessing"] == runs[2]["preprocessing"] == NOT_PREPROCESSED
    assert "Preprocessing of the training frames" not in table
    decided = "none: the frames differ by level offsets, which the frame embeddings follow (...)"
    listed = markdown([dict(r, preprocessing=decided) if r["seed"] == 0 else r for r in runs], ["demo"])
    assert f"- wild-thermal on demo: {decided}" in listed and f"- wild-thermal-3dgs on demo: {decided}" in listed
    for name in ("speed_accuracy.png", "speed_time.png"):  # `aligned` (a fit) and `time` (none)
        chart = cv2.imread(str(out / name))
        assert chart is not None and chart.shape[1] > 400
    renders = out / "renders" / "demo" / "wild-thermal_seed1"
    assert len(list(renders.glob("test_??.png"))) == len(list(renders.glob("test_??_celsius.png"))) == 5

    # runs split over several commands merge into one table
    merged = main(BenchArgs(merge=(out / "bench.json",), output_dir=tmp_path / "merged"))
    assert len(merged["runs"]) == 4 and (tmp_path / "merged" / "bench.md").read_text() == table


def test_aligned_scores_an_affine_render_perfectly_and_half_never_reads_the_right_half():
    from thermal_wild_ns.pipeline.evaluation import fit_gain_offset, scores

    frame = np.random.default_rng(0).random((24, 32)).astype(np.float32)
    render = (frame - 0.3) / 1.7  # an exact affine map of the frame
    a, b = fit_gain_offset(render, frame)
    assert scores(a * render + b, frame)["psnr"] >= 60.0
    assert fit_gain_offset(np.full((4, 4), 0.2), frame[:4, :4]) == (0.0, pytest.approx(float(frame[:4, :4].mean())))


def test_the_celsius_panel_shows_the_error_where_it_is_on_one_fixed_scale(tmp_path):
    from thermal_wild_ns.pipeline.evaluation import CELSIUS_ERROR_SCALE, write_celsius_panel

    recorded = np.tile(np.linspace(5.0, 25.0, 64), (48, 1))  # [48, 64] °C
    pred = recorded.copy()
    pred[:, 32:] += 1.0  # the right half one degree warm
    pred[0, 0] = np.nan
    error = write_celsius_panel(tmp_path / "panel.png", recorded, pred, "frame 3")
    assert np.isnan(error[0, 0]) and np.allclose(error[1:, :32], 0) and np.allclose(error[:, 32:], 1.0)
    panel = cv2.imread(str(tmp_path / "panel.png"))
    scale = 384 // 48
    assert panel.shape == (22 + 48 * scale, 3 * 64 * scale, 3)
    error_tile = panel[22:, 2 * 64 * scale :].astype(int).sum(-1)
    # inferno: 0 is near black; 1 °C of a 2 °C scale is mid-palette, far brighter
    assert CELSIUS_ERROR_SCALE > 1.0
    assert error_tile[:, 40 * scale :].mean() > error_tile[scale:, : 30 * scale].mean() + 150


def test_a_run_past_the_time_limit_is_recorded_as_failed_and_the_bench_goes_on(tmp_path):
    from experiments.bench import BenchArgs, main

    # time is up from the first step; the limit is checked every 100 steps, before an evaluation
    result = main(
        BenchArgs(
            methods=("wild-thermal-3dgs",),
            steps=300,
            eval_at=(100,),
            fps_frames=0,
            time_limit=1e-9,
            output_dir=tmp_path,
        )
    )
    (run,) = result["runs"]
    assert run["failed"].startswith("RunTooSlow: --time-limit reached at step 100 (")
    assert "- wild-thermal-3dgs on demo (seed 0): RunTooSlow" in (tmp_path / "bench.md").read_text()


def test_runs_spread_over_gpus_one_process_each_and_merge(tmp_path):
    """--gpus N: one queue per GPU, one run at a time per queue, each in its own process (on a CPU
    machine the queues simply run side by side); the merged table has every run, in order."""
    from experiments.bench import BenchArgs, main

    methods = ("wild-thermal-3dgs", "wild-thermal-3dgs-bbhe", "wild-thermal-3dgs-stab")
    result = main(
        BenchArgs(methods=methods, steps=20, eval_at=(20,), fit_steps=2, fps_frames=0, gpus=2, output_dir=tmp_path)
    )
    assert [r["method"] for r in result["runs"]] == list(methods) and not any("failed" in r for r in result["runs"])
    for folder in (
        "gpu0/00_demo_wild-thermal-3dgs_seed0",
        "gpu1/01_demo_wild-thermal-3dgs-bbhe_seed0",
        "gpu0/02_demo_wild-thermal-3dgs-stab_seed0",
    ):
        assert (tmp_path / folder / "bench.json").is_file() and (tmp_path / folder / "log.txt").is_file()
    assert json.loads((tmp_path / "bench.json").read_text())["runs"] == result["runs"]
    # each worker's command line carries every setting of its job
    import tyro

    from experiments.bench import _command_line

    job = BenchArgs(
        methods=methods[:1],
        steps=20,
        schedule=30000,
        time_limit=9.5,
        cache_dir=tmp_path / "cache",
        output_dir=tmp_path / "x",
    )
    assert tyro.cli(BenchArgs, args=_command_line(job)[3:]) == job
    assert "| wild-thermal-3dgs-stab | " in (tmp_path / "bench.md").read_text()


def test_gpu_queues_keep_to_the_gpus_the_parent_may_see(monkeypatch):
    """Two benches on one host each take their own GPUs: a limited parent's queues use its devices, in order."""
    import pytest

    from experiments.bench import gpu_devices

    monkeypatch.delenv("CUDA_VISIBLE_DEVICES", raising=False)
    assert gpu_devices(2) == ["0", "1"]
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "2,3")
    assert gpu_devices(2) == ["2", "3"] and gpu_devices(1) == ["2"]
    with pytest.raises(ValueError, match="CUDA_VISIBLE_DEVICES=2,3"):
        gpu_devices(3)


def test_several_runs_per_gpu_share_the_cores_and_are_labelled(tmp_path, monkeypatch):
    """--runs-per-gpu K: K queues per GPU, each process with cores / queues torch threads (not
    torch's default of one per core), and the merged results say their timings were shared."""
    import os

    from experiments.bench import BenchArgs, main

    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.setattr(
        os, "cpu_count", lambda: 2
    )  # the parent's count sets the workers' share (torch caps it at the real cores)
    methods = ("wild-thermal-3dgs", "wild-thermal-3dgs-bbhe")
    result = main(
        BenchArgs(
            methods=methods, steps=20, eval_at=(20,), fit_steps=2, fps_frames=0, runs_per_gpu=2, output_dir=tmp_path
        )
    )
    assert [r["method"] for r in result["runs"]] == list(methods)
    assert all(r["runs_per_gpu"] == 2 and r["torch_threads"] == 1 for r in result["runs"])  # 2 cores / 2 queues
    assert (tmp_path / "gpu0/00_demo_wild-thermal-3dgs_seed0/bench.json").is_file() and (
        tmp_path / "gpu0/01_demo_wild-thermal-3dgs-bbhe_seed0/bench.json"
    ).is_file()
    assert "(2 runs per GPU)" in (tmp_path / "bench.md").read_text()
    assert json.loads((tmp_path / "bench.json").read_text())["runs"][0]["runs_per_gpu"] == 2


def test_resolution_warm_up_and_equalization_strength_are_set(tmp_path):
    from experiments.bench import BenchArgs, run_label, trainer_config

    for method in ("splatfacto", "wild-thermal"):
        assert (
            trainer_config(method, "demo", BenchArgs(output_dir=tmp_path), tmp_path).pipeline.model.num_downscales == 2
        )  # the configs' own
        config = trainer_config(method, "demo", BenchArgs(output_dir=tmp_path, num_downscales=0), tmp_path)
        assert config.pipeline.model.num_downscales == 0, method
        assert config.experiment_name == f"{method}_num-downscales_0_seed0"  # its own run folder beside the stock run's
    # a changed warm-up is part of the run's name, so stock and changed runs merge side by side
    assert run_label("splatfacto", BenchArgs()) == "splatfacto"
    assert run_label("splatfacto", BenchArgs(num_downscales=1)) == "splatfacto (num-downscales 1)"
    # so is a changed equalization strength, where the method has an equalization step to change
    assert (
        run_label("wild-thermal-3dgs-stab-bbhe", BenchArgs(equalization_strength=1.0, num_downscales=1))
        == "wild-thermal-3dgs-stab-bbhe (num-downscales 1, equalization-strength 1)"
    )
    assert (
        run_label("wild-thermal-3dgs-histeq", BenchArgs(equalization_strength=0.25))
        == "wild-thermal-3dgs-histeq (equalization-strength 0.25)"
    )
    for unchanged in (
        "splatfacto",
        "wild-thermal",
        "wild-thermal-3dgs",
        "wild-thermal-emission-mlp",
        "wild-thermal-3dgs-stab",
    ):
        assert run_label(unchanged, BenchArgs(equalization_strength=1.0)) == unchanged
    config = trainer_config("wild-thermal", "demo", BenchArgs(output_dir=tmp_path, equalization_strength=0.5), tmp_path)
    assert config.pipeline.datamanager.preprocessing.equalization_strength == 0.5


def test_a_run_stopped_between_checkpoints_counts_its_training_time_to_the_last_step(monkeypatch):
    """The automatic stop ends runs between the bench's checkpoints: their seconds (and ms/step)
    run to the last step trained, not to the last checkpoint."""
    import experiments.bench as bench

    clock = iter(range(100))  # a clock that moves one second per reading
    monkeypatch.setattr(bench.time, "perf_counter", lambda: float(next(clock)))
    recorder = bench.CurveRecorder(pipeline=None, checkpoints=[1000], time_limit=None, describe="run")
    recorder.start()  # t = 0
    for step in range(3):  # no checkpoint among them: nothing to evaluate
        recorder(step)  # t = 1, 2, 3
    assert recorder.trained_seconds == 3.0 and recorder.seconds == 0.0


def test_unknown_method_and_protocol_are_refused(tmp_path):
    from experiments.bench import BenchArgs, trainer_config
    from thermal_wild_ns.pipeline.evaluation import evaluate

    with pytest.raises(ValueError, match="unknown method 'nerfacto'"):
        trainer_config("nerfacto", "demo", BenchArgs(output_dir=tmp_path), tmp_path)
    with pytest.raises(ValueError, match="unknown protocol"):
        evaluate(None, protocols=("best",))


def test_a_survey_scene_is_the_synthetic_survey_of_that_many_frames_and_a_bad_count_is_refused(tmp_path):
    from experiments.scenes import scene_dataparser, scene_name

    config = scene_dataparser("survey:12", tmp_path, tmp_path / "cache")
    assert (config.scene, config.survey_frames) == ("survey", 12)
    assert config.data == tmp_path / "survey-12" and scene_name("survey:12") == "survey-12"
    with pytest.raises(ValueError, match="'survey:many'.*a number of frames"):
        scene_dataparser("survey:many", tmp_path, tmp_path / "cache")


def test_bench_on_a_stress_scene_scores_the_path(tmp_path):
    from experiments.bench import BenchArgs, main

    out = tmp_path / "bench"
    result = main(
        BenchArgs(
            scenes=("stress:outlier",),
            methods=("wild-thermal-3dgs",),
            steps=30,
            eval_at=(30,),
            fit_steps=2,
            fps_frames=0,
            output_dir=out,
        )
    )
    path = result["runs"][0]["path"]
    assert path["views"] == 60 and 0.0 <= path["floater_fraction"] <= 1.0 and path["flicker_pixel_excess"] >= 0.0
    assert 0.0 <= path["visible_floater_fraction"] <= path["floater_fraction"]
    assert "| wild-thermal-3dgs | " in (out / "bench.md").read_text().split("Stress scenes")[1]
    strip = cv2.imread(str(out / "stress-outlier_path_strip.png"))
    assert strip is not None and strip.shape[0] == 2 * 2 * 96  # ground truth + one method, each 2x 96 rows
    # runs from separate commands (e.g. one per GPU) merge with their strips
    main(BenchArgs(merge=(out / "bench.json",), output_dir=tmp_path / "merged"))
    merged = cv2.imread(str(tmp_path / "merged" / "stress-outlier_path_strip.png"))
    assert merged is not None and merged.shape == strip.shape


def test_budget_knee_is_the_smallest_budget_near_the_best_run():
    from experiments.budget_sweep import knee

    rows = [
        {"budget": b, "psnr": p, "gaussians": b or 400_000}
        for b, p in ((50_000, 29.0), (100_000, 29.85), (150_000, 30.1), (0, 30.0))
    ]
    assert knee(rows, 0.3)["budget"] == 100_000
    assert knee(rows, 0.2)["budget"] == 150_000
    # DUNR's sweep: the uncapped run is not the best; the knee is measured against the best (100k),
    # not picked as the 50k run that merely beats the uncapped one
    dunr = [{"budget": b, "psnr": p} for b, p in ((50_000, 30.92), (100_000, 31.39), (150_000, 30.46), (0, 30.41))]
    assert knee(dunr, 0.2)["budget"] == 100_000
    assert knee([{"budget": 5, "failed": "OutOfMemoryError"}], 0.2) is None


def test_budget_sweep_runs_end_to_end_on_cpu(tmp_path):
    from experiments.budget_sweep import SweepArgs, main

    out = tmp_path / "sweep"
    result = main(SweepArgs(method="wild-thermal-3dgs", budgets=(2500, 0), steps=40, output_dir=out))
    assert [r["budget"] for r in result["rows"]] == [2500, 100_000_000]
    assert all(r["gaussians"] > 0 and "psnr" in r for r in result["rows"])
    assert result["knee"] is not None and (out / "sweep.md").is_file()
    assert cv2.imread(str(out / "psnr_vs_gaussians.png")) is not None
    # runs made by separate commands merge into the same sweep
    merged = main(SweepArgs(merge=tuple(sorted(out.glob("budget_*/bench.json"))), output_dir=tmp_path / "merged"))
    assert merged["rows"] == result["rows"]


def test_budget_sweep_spreads_budgets_over_gpus(tmp_path):
    from experiments.budget_sweep import SweepArgs, main

    result = main(SweepArgs(method="wild-thermal-3dgs", budgets=(2500, 0), steps=20, gpus=2, output_dir=tmp_path))
    assert [r["budget"] for r in result["rows"]] == [2500, 100_000_000] and all("psnr" in r for r in result["rows"])
    assert (tmp_path / "budget_2500" / "log.txt").is_file() and (tmp_path / "budget_uncapped" / "bench.json").is_file()


@pytest.mark.skipif(torch.cuda.is_available(), reason="splatfacto trains where CUDA is")
def test_a_bench_of_only_skipped_runs_still_writes_its_table(tmp_path):
    """Stock splatfacto needs CUDA: on a CPU its run is skipped, and a bench of it alone writes an
    empty record and table instead of dying while drawing a chart with no scenes."""
    from experiments.bench import BenchArgs, main

    result = main(
        BenchArgs(methods=("splatfacto",), steps=20, eval_at=(20,), fit_steps=2, fps_frames=0, output_dir=tmp_path)
    )
    assert result["runs"] == []
    assert json.loads((tmp_path / "bench.json").read_text())["runs"] == []
    assert (tmp_path / "bench.md").is_file() and not (tmp_path / "speed_accuracy.png").exists()
    assert not (tmp_path / "speed_time.png").exists()


def _trained_demo_pipeline(tmp_path, demo_scene_dir, steps: int, preprocessed: bool = False):
    """The full method's pipeline after `steps` steps on the demo scene (a small Gaussian budget);
    `preprocessed`: its frames preprocessed whatever the full method's rule decides (raw, for the demo)."""
    from thermal_wild_ns.demo import demo_trainer_config
    from thermal_wild_ns.preprocessing.photometric import PhotometricConfig

    config = demo_trainer_config(tmp_path, steps=steps, max_gaussians=2000)
    config.pipeline.datamanager.dataparser.data = demo_scene_dir
    if preprocessed:
        config.pipeline.datamanager.preprocessing = PhotometricConfig()
    trainer = config.setup(local_rank=0, world_size=1)
    trainer.setup()
    trainer.train()
    return trainer.pipeline


def test_half_protocol_never_reads_a_right_half_pixel(tmp_path, demo_scene_dir, monkeypatch):
    """The NeRF-W prediction of a view is the same whatever the right halves of the held-out frames
    hold (noise here), while the score, which is of the right half, changes."""
    import thermal_wild_ns.pipeline.evaluation as evaluation

    pipeline = _trained_demo_pipeline(tmp_path, demo_scene_dir, steps=8)
    predictions = []
    original = evaluation.half_prediction

    def recording(pipeline, camera, left, state):
        predictions.append(original(pipeline, camera, left, state))
        return predictions[-1]

    monkeypatch.setattr(evaluation, "half_prediction", recording)
    first = evaluation.evaluate(pipeline, protocols=("half",), fit_steps=3)
    clean = [p.copy() for p in predictions]
    predictions.clear()
    dataset = pipeline.datamanager.eval_dataset
    recorded = dataset.recorded_image  # the protocol's target: the frame as recorded

    def noisy_right_half(image_idx):
        image = recorded(image_idx).copy()
        half = image.shape[1] // 2
        image[:, half:] = np.random.default_rng(image_idx).random(image[:, half:].shape, dtype=np.float32)
        return image

    monkeypatch.setattr(dataset, "recorded_image", noisy_right_half)
    second = evaluation.evaluate(pipeline, protocols=("half",), fit_steps=3)
    assert len(predictions) == len(clean) == 5
    assert all(np.array_equal(a, b) for a, b in zip(clean, predictions))
    assert second["psnr_half"] < first["psnr_half"] - 3.0


def test_an_embedding_fit_finds_what_the_full_backward_finds_and_leaves_the_model_as_it_was(tmp_path, demo_scene_dir):
    """`fit_embeddings` (the `half` and `oracle` protocols) holds the model's parameters constant and renders
    through the view's splat weights, computed once (`model.fitting_views`): the same Adam steps as with every
    parameter in the graph and a full render each step give the same embedding (the embedding's gradient does
    not depend on the geometry getting one), no gradient lands in the model, and every parameter is trainable
    again after the fit, also after a fit that fails."""
    from thermal_wild_ns.pipeline.evaluation import Fit, fit_embeddings
    from thermal_wild_ns.pipeline.photometric_state import as_recorded, thermal_output
    from thermal_wild_ns.state_names import CANONICAL

    pipeline = _trained_demo_pipeline(tmp_path, demo_scene_dir, steps=4)
    model = pipeline.model
    model.eval()
    camera = pipeline.datamanager.eval_dataset.cameras[0:1].to(model.device)
    target = torch.full((int(camera.height), int(camera.width)), 0.3)
    start = model.state_embedding(CANONICAL) + 0.1
    trainable = [name for name, parameter in model.named_parameters() if parameter.requires_grad]

    embedding = start.detach().clone().requires_grad_(True)  # the fit with the whole graph, as before
    optimizer = torch.optim.Adam([embedding], lr=1e-2)
    with torch.enable_grad():
        for _ in range(3):
            optimizer.zero_grad()
            pred = as_recorded(model, thermal_output(model.get_outputs(camera, frame_embedding=embedding)), camera)
            (pred[..., 0] - target).abs().mean().backward()
            optimizer.step()
    model.zero_grad(set_to_none=True)

    fit = Fit(camera, target, slice(None), start)
    (fitted,) = fit_embeddings(model, [fit], 3, 1e-2)
    assert not torch.equal(fitted, start) and torch.allclose(fitted, embedding.detach(), atol=1e-6)
    assert all(parameter.grad is None for parameter in model.parameters())
    assert [name for name, parameter in model.named_parameters() if parameter.requires_grad] == trainable

    def broken(*args, **kwargs):
        raise RuntimeError("a render that fails")

    model.fitting_views = lambda cameras: broken
    with pytest.raises(RuntimeError, match="a render that fails"):
        fit_embeddings(model, [fit], 3, 1e-2)
    assert [name for name, parameter in model.named_parameters() if parameter.requires_grad] == trainable


@pytest.mark.parametrize("rasterized", [False, True])
def test_several_views_rendered_for_a_fit_in_one_pass_are_each_views_own_render(
    tmp_path, demo_scene_dir, monkeypatch, rasterized
):
    """`model.fitting_views` renders several views at their own states in one pass (the MLPs once for every
    state, one rasterization or each view's splat weights): each view is the render `get_outputs` gives it at its
    state, as the camera records it, and each view's gradient reaches its own state alone."""
    import thermal_wild_ns.model.renders as renders
    from thermal_wild_ns.pipeline.photometric_state import as_recorded, thermal_output
    from thermal_wild_ns.state_names import CANONICAL

    pipeline = _trained_demo_pipeline(tmp_path, demo_scene_dir, steps=8)
    if rasterized:
        monkeypatch.setattr(renders, "resolve_backend", lambda backend, device: "gsplat")
    model = pipeline.model
    model.eval()
    cameras = [pipeline.datamanager.eval_dataset.cameras[i : i + 1].to(model.device) for i in range(3)]
    generator = torch.Generator().manual_seed(0)
    start = model.state_embedding(CANONICAL).detach()
    embeds = start + 0.3 * torch.randn(3, start.shape[0], generator=generator).to(start.device)  # [3, Df]: one per view
    with torch.enable_grad():  # a render under autograd outside training: the fitting render, one view at a time
        each = [
            as_recorded(model, thermal_output(model.get_outputs(c, frame_embedding=e)), c)[..., 0].detach()
            for c, e in zip(cameras, embeds)
        ]
    together = model.fitting_views(cameras)(embeds)  # [3, H, W]
    assert together.shape == (3, *each[0].shape)
    for b in range(3):
        assert torch.allclose(together[b], each[b], atol=1e-5), (b, (together[b] - each[b]).abs().max())
    assert not torch.allclose(together[0], together[1], atol=1e-3)  # the states differ, and so do the views
    leaf = embeds.clone().requires_grad_(True)
    with torch.enable_grad():
        (grad,) = torch.autograd.grad(model.fitting_views(cameras)(leaf)[1].sum(), leaf)
    assert grad[1].abs().sum() > 0 and grad[0].abs().sum() == 0 and grad[2].abs().sum() == 0


@pytest.mark.parametrize("rasterized", [False, True])
def test_held_out_fits_of_several_views_in_one_render_end_where_each_would_alone(
    tmp_path, demo_scene_dir, monkeypatch, rasterized
):
    """`half` and `oracle` fit several views' states per render (`fit_views`): each view's fitted state, and so
    every score, is the one its fit alone gives (to float rounding), through each view's splat weights (a CPU's
    way) and through one rasterization of every camera (a GPU's way: on a CPU the pure-torch rasterizer, on a GPU
    gsplat's kernels in both cases); the fits move the scores."""
    import thermal_wild_ns.model.renders as renders
    import thermal_wild_ns.pipeline.evaluation as evaluation

    pipeline = _trained_demo_pipeline(tmp_path, demo_scene_dir, steps=8, preprocessed=True)
    if rasterized:
        monkeypatch.setattr(renders, "resolve_backend", lambda backend, device: "gsplat")
    batches, original = [], evaluation.fit_embeddings

    def recording(model, fits, steps, lr):
        batches.append(len(fits))
        return original(model, fits, steps, lr)

    monkeypatch.setattr(evaluation, "fit_embeddings", recording)
    protocols = ("half", "oracle")
    alone = evaluation.evaluate(pipeline, protocols=protocols, fit_steps=5, fit_views=1)
    assert batches == [1] * 10  # 5 held-out views, two fits each
    batches.clear()
    together = evaluation.evaluate(pipeline, protocols=protocols, fit_steps=5, fit_views=4)
    assert batches == [4, 4, 2]
    # the same up to float rounding: one rasterization of 4 cameras sums in another order than 4 of one, and on a
    # GPU cuBLAS picks its kernels by the batch's size and gsplat's backward adds atomically
    rel = 1e-5 if pipeline.model.device.type == "cpu" else 1e-4
    for one, many in zip(alone["per_view"], together["per_view"]):
        assert one.keys() == many.keys()
        assert all(one[key] == pytest.approx(many[key], rel=rel, abs=1e-6) for key in one), (one, many)
    unfitted = evaluation.evaluate(pipeline, protocols=protocols, fit_steps=0)
    # 5 steps of a model trained 8 move the score little (on a GPU less than 1e-3 dB), but well past rounding
    assert unfitted["psnr_oracle"] != pytest.approx(alone["psnr_oracle"], abs=1e-5)


@pytest.mark.parametrize("preprocessed", [False, True])
def test_state_protocols_score_the_recorded_frame_and_view_protocols_the_scene(
    tmp_path, demo_scene_dir, monkeypatch, preprocessed
):
    """On a generated scene the held-out view's truth is fault-free while the camera recorded it under
    its drifting sensor state: `novel` and `aligned` are scored against the truth, `time`, `half` and
    `oracle` (the frame's state) against the recorded frame, and so is `oracle_lut` (oracle's split),
    which has a render of its own only where the frames have LUTs (else it is the `time` render)."""
    import thermal_wild_ns.pipeline.evaluation as evaluation

    pipeline = _trained_demo_pipeline(tmp_path, demo_scene_dir, steps=4, preprocessed=preprocessed)
    assert (pipeline.datamanager.preprocessed is not None) == preprocessed
    targets = []
    original = evaluation.scores

    def recording(pred, gt, to_celsius=None, device="cpu"):
        targets.append(gt)
        return original(pred, gt, to_celsius, device)

    monkeypatch.setattr(evaluation, "scores", recording)
    result = evaluation.evaluate(pipeline, fit_steps=1)
    dataset = pipeline.datamanager.eval_dataset
    # each view's novel, time, aligned; after the fits each view's half, oracle (, oracle_lut)
    fitted = 3 if preprocessed else 2
    assert len(targets) == 5 * (3 + fitted)
    cheap, after_fits = targets[:15], targets[15:]
    for view, (_, batch) in enumerate(pipeline.datamanager.fixed_indices_eval_dataloader):
        truth = batch["image"].float().mean(dim=-1).cpu().numpy()
        recorded = dataset.recorded_image(int(batch["image_idx"]))
        assert np.abs(truth - recorded).mean() > 1e-3  # the demo's sensor drifts: the two differ
        novel, time, aligned = cheap[3 * view : 3 * (view + 1)]
        half, oracle, *oracle_lut = after_fits[fitted * view : fitted * (view + 1)]
        assert np.array_equal(novel, truth) and np.array_equal(aligned, truth)
        assert np.array_equal(time, recorded) and np.array_equal(oracle, recorded)
        assert all(np.array_equal(target, recorded) for target in oracle_lut)
        assert np.array_equal(half, recorded[:, recorded.shape[1] // 2 :])
    assert (result["psnr_oracle_lut"] == result["psnr_time"]) == (not preprocessed)


def test_settings_reach_nested_and_frozen_config_fields(tmp_path):
    from experiments.bench import BenchArgs, apply_setting, run_label, trainer_config
    from thermal_wild_ns.method_configs import method_trainer

    config = method_trainer("wild-thermal")
    apply_setting(config, "pipeline.datamanager.preprocessing.variant=stab+bbhe")  # a frozen dataclass
    apply_setting(config, "pipeline.model.heat_aware_ssim=False")
    apply_setting(config, "pipeline.model.loss_space=original")
    assert config.pipeline.datamanager.preprocessing.variant == "stab+bbhe"
    assert config.pipeline.model.heat_aware_ssim is False and config.pipeline.model.loss_space == "original"
    assert method_trainer("wild-thermal").pipeline.datamanager.preprocessing.variant == "none"  # a copy
    with pytest.raises(ValueError, match="has no field 'nope'"):
        apply_setting(config, "pipeline.model.nope=1")
    with pytest.raises(ValueError, match="expected path.to.field=value"):
        apply_setting(config, "pipeline.model.alpha_lambda")
    args = BenchArgs(set=("pipeline.model.heat_aware_ssim=False",))
    assert run_label("wild-thermal", args) == "wild-thermal (heat_aware_ssim=False)"
    # an optimizer's settings, through the trainer's dict of parameter groups
    apply_setting(config, "optimizers.emission.optimizer.lr=7e-4")
    assert config.optimizers["emission"]["optimizer"].lr == 7e-4
    assert method_trainer("wild-thermal").optimizers["emission"]["optimizer"].lr != 7e-4  # a copy was set
    with pytest.raises(ValueError, match="has no field 'features_dc'"):
        apply_setting(config, "optimizers.features_dc.optimizer.lr=1e-3")
    args = BenchArgs(set=("optimizers.emission.optimizer.lr=7e-4",))
    assert run_label("wild-thermal", args) == "wild-thermal (emission.optimizer.lr=7e-4)"
    # stock splatfacto's settings too (what its lead on the stress scenes comes from)
    args = BenchArgs(set=("pipeline.model.sh_degree=0",), output_dir=tmp_path)
    assert trainer_config("splatfacto", "demo", args, tmp_path).pipeline.model.sh_degree == 0
    assert run_label("splatfacto", args) == "splatfacto (sh_degree=0)"
    args = BenchArgs(set=("pipeline.model.view_sh_degree=2", "pipeline.model.densify_grad_thresh=0.0004"))
    assert run_label("wild-thermal", args) == "wild-thermal (view_sh_degree=2, densify_grad_thresh=0.0004)"


def test_full_vs_ablations_compares_the_full_method_with_the_best_other_per_scene(tmp_path):
    from experiments.full_vs_ablations import Args, main

    def run(method, scene, aligned, time, steps=100, stop=None):
        return {
            "method": method,
            "scene": scene,
            "psnr_aligned": aligned,
            "psnr_time": time,
            "steps": steps,
            "ms_per_step": 10.0,
            "auto_stop": stop,
        }

    def bench(name, *runs):
        path = tmp_path / name
        path.write_text(json.dumps({"runs": list(runs)}))
        return path

    stop = {"steps_asked": 500}
    first = bench("first.json", run("wild-thermal", "a", 10.0, 10.0), run("wild-thermal", "b", 30.0, 30.0, 200, stop))
    later = bench("later.json", run("wild-thermal (x=1)", "a", 20.0, 19.0), run("wild-thermal (x=1)", "a", 22.0, 19.0))
    others = bench(
        "others.json",
        run("splatfacto", "a", 21.2, 18.0),
        run("splatfacto", "a", 21.25, 17.0, steps=30000),  # another schedule: a rival of its own, not pooled
        run("wild-thermal-3dgs", "a", 19.0, 19.5, stop=stop),  # stopped: its label alone
        run("wild-thermal", "a", 99.0, 99.0),  # the full method's runs among the others are not rivals
        run("wild-thermal-3dgs", "b", 31.0, 29.0),
    )
    rows = main(Args(full=(first, later), others=(others,), output=tmp_path / "out.md"))
    got = {(r["scene"], r["protocol"]): r for r in rows}
    # scene a: the later file's runs (mean 21.0 aligned, 19.0 time) replace the first file's
    assert got[("a", "aligned")]["best"] == "splatfacto, 30000 steps"
    assert got[("a", "aligned")]["margin"] == pytest.approx(-0.25)  # pooled, the two schedules: -0.225
    assert got[("a", "aligned")]["met"] and got[("a", "aligned")]["seeds"] == 2
    assert got[("a", "time")]["best"] == "wild-thermal-3dgs" and got[("a", "time")]["margin"] == pytest.approx(-0.5)
    assert not got[("a", "time")]["met"]  # 0.5 dB short: past the 0.3 dB tolerance
    assert not got[("b", "aligned")]["met"] and got[("b", "time")]["met"]
    text = (tmp_path / "out.md").read_text()
    assert "**no**, 1.00 dB short" in text and "| b | 1 | 200 | 500 | 300 | 3.00 |" in text
    # --pool: the later file's runs add to the first file's (mean 17.33 aligned over three seeds)
    pooled_args = Args(full=(first, later), others=(others,), output=tmp_path / "pooled.md", pool=True)
    pooled = {(r["scene"], r["protocol"]): r for r in main(pooled_args)}
    assert pooled[("a", "aligned")]["seeds"] == 3 and pooled[("a", "aligned")]["full"] == pytest.approx(52 / 3)
    assert not pooled[("a", "aligned")]["met"] and pooled[("b", "aligned")]["seeds"] == 1


def test_variant_table_marks_a_change_bold_only_where_the_seeds_ranges_are_apart(tmp_path):
    from experiments.variant_table import baseline_rows, table

    def bench(name, runs):
        path = tmp_path / name
        path.write_text(json.dumps({"runs": [dict(scene=s, psnr_time=t, psnr_oracle=o) for s, t, o in runs]}))
        return path

    base = bench("base.json", [("a", 30.0, 31.0), ("a", 31.0, 33.0), ("b", 20.0, 25.0), ("b", 22.0, 25.0)])
    # a: 32/33 against 30/31, apart (its gaps 0-1 against 1-2 touch: not apart); b: inside 20-22, overlapping;
    # c: no baseline, left out
    variant_runs = [("a", 32.0, 33.0), ("a", 33.0, 33.0), ("b", 21.5, 25.0), ("b", 21.9, 25.0), ("c", 1.0, 2.0)]
    variant = bench("variant.json", variant_runs)
    rows = table([base], variant, ["time", "gap"]).splitlines()
    assert rows[2] == "| a | 32.50 (32.00–33.00) | **+2.00** | 0.50 (0.00–1.00) | -1.00 |"
    assert rows[3] == "| b | 21.70 (21.50–21.90) | +0.70 | 3.30 (3.10–3.50) | -0.70 |"
    assert len(rows) == 4
    # the baseline pooled with another call's runs of it: a's seeds now reach 32.5, so the ranges overlap
    more = bench("more.json", [("a", 32.5, 33.0)])
    pooled = table([base, more], variant, ["time"]).splitlines()
    assert pooled[2] == "| a | 32.50 (32.00–33.00) | +1.33 |"
    own = baseline_rows([base, more], ["time"]).splitlines()
    assert own[0] == "| a (baseline, 3 runs) | 31.17 (30.00–32.50) |  |"
    assert own[1] == "| b (baseline, 2 runs) | 21.00 (20.00–22.00) |  |" and len(own) == 2


def test_budget_curve_gives_each_budgets_best_held_back_score_and_the_kept_models_budget(tmp_path):
    from experiments.budget_curve import doubling_summary, main, run_curves

    checks = [(3, 30.0), (7, 30.5), (11, 30.4), (15, 31.2), (19, 31.0)]  # a raise at 7, another at 15
    record = dict(
        checks=[dict(step=s, psnr=p, gaussians=100 * s) for s, p in checks],
        budget_raises=[dict(step=7, budget=2000), dict(step=15, budget=4000)],
        last_step=19,
        kept_step=15,
    )
    runs = [dict(scene="a", seed=0, gaussians=1900, auto_stop=record), dict(scene="a", seed=1, failed="Boom")]
    path = tmp_path / "bench.json"
    path.write_text(json.dumps(dict(args=dict(max_gaussians=1000), runs=runs)))
    (found,) = run_curves(path, start=12_500)  # the bench's --max-gaussians is the start; a failed run is left out
    assert found["curve"] == [(1000, 30.5), (2000, 31.2), (4000, 31.0)] and found["chosen"] == 2000
    assert found["counts"] == [700, 1500, 1900]  # the model's size at each budget's best check
    # a run's recorded start (since the seed points may raise it) wins over the bench's --max-gaussians
    record["budget_start"] = 1500
    path.write_text(json.dumps(dict(args=dict(max_gaussians=1000), runs=runs)))
    (recorded,) = run_curves(path, start=12_500)
    assert recorded["curve"] == [(1500, 30.5), (2000, 31.2), (4000, 31.0)]
    assert (
        doubling_summary([recorded])
        == "each raise moved the best held-back PSNR by -0.20 to +0.70 dB; within ±0.2 dB on 1 of 2"
    )
    chart = tmp_path / "curve.png"
    (again,) = main([str(path), "--chart", str(chart)])
    assert again["curve"] == recorded["curve"] and chart.stat().st_size > 0


def test_the_schedule_profile_times_a_runs_events_apart_from_its_steps_and_leaves_nerfstudio_as_it_was(tmp_path):
    import importlib

    import thermal_wild_ns.training.trainer as trainer_module
    from experiments.schedule_profile import ScheduleArgs, main

    writer = importlib.import_module("nerfstudio.utils.writer")  # after the above: alone it imports in a circle

    originals = (writer.write_out_storage, trainer_module.snapshot)
    result = main(ScheduleArgs(steps=40, window=20, output_dir=tmp_path / "profile"))
    events = result["events"]
    assert events["log writes"]["calls"] == 41  # every step, and once more at the end
    assert events["checkpoints written"]["calls"] >= 2  # at least SAVES_PER_RUN's, and the final one
    assert 0 < result["ms_per_step_steps_only"] < result["ms_per_step_all"]
    assert [w["last_step"] for w in result["windows"]] == [19, 39]
    assert (writer.write_out_storage, trainer_module.snapshot) == originals
    assert "ms/step" in (tmp_path / "profile" / "schedule.md").read_text()


def test_state_bound_finds_the_unpredictable_frames_of_a_generated_scene(tmp_path):
    """A perfect model with the frame's own state reproduces the recorded frame to its rounding; the
    flat-field scene's offset is a ramp between frames 15 and 17 (frame 16 predicted exactly by its
    neighbours) but frame 0 has only frame 1 after it (15 counts off); a measured run is split into
    the data's share and the model's."""
    from experiments import state_bound

    bench = tmp_path / "bench.json"
    views = [{"frame": f, "psnr_time": 35.0, "psnr_oracle": 40.0} for f in (0, 8, 16, 24, 32)]
    bench.write_text(json.dumps({"runs": [{"scene": "stress-ffc", "method": "wild-thermal", "per_view": views}]}))
    args = state_bound.Args(scenes=("stress:ffc",), output=tmp_path / "bound.md", work_dir=tmp_path, bench=(bench,))
    rows = {r["frame"]: r for r in state_bound.main(args)["stress:ffc"]}
    assert all(r["own"] > 65 for r in rows.values())  # only the uint16 rounding is left
    assert rows[16]["neighbours"] == pytest.approx(rows[16]["own"], abs=0.5)
    assert rows[0]["neighbours"] < 40  # frame 1's offset, 15 counts above frame 0's
    table = (tmp_path / "bound.md").read_text()
    row = next(line for line in table.splitlines() if line.startswith("| stress:ffc | wild-thermal"))
    data_share, model_share = (float(cell.split(" (")[0]) for cell in row.split("|")[7:9])
    assert data_share > 0.3 and model_share > 3.0  # 5 dB of gap, one view of five losing to the data
    # the data-only `time` of each view: its `oracle` error (40 dB) plus the perfect model's state error
    state_error = {f: 10 ** (-r["neighbours"] / 10) - 10 ** (-r["own"] / 10) for f, r in rows.items()}
    data_only = np.mean([-10 * np.log10(1e-4 + e) for e in state_error.values()])
    assert data_share == pytest.approx(40.0 - data_only, abs=0.01)
    assert model_share == pytest.approx(data_only - 35.0, abs=0.01)


def test_few_view_gaussians_counts_the_frames_that_may_draw_each_gaussian():
    from nerfstudio.cameras.cameras import Cameras

    from experiments.few_view_gaussians import frames_seeing, summary

    # two cameras 2 apart on x at z=0, looking down -z (OpenGL axes), 100x100 px, focal 100: at depth d each sees
    # |x - cx| < d/2 (and |y| < d/2), a Gaussian's projected extent widening that
    c2w = torch.eye(4)[:3].repeat(2, 1, 1)
    c2w[1, 0, 3] = 2.0
    cameras = Cameras(camera_to_worlds=c2w, fx=100.0, fy=100.0, cx=50.0, cy=50.0, width=100, height=100)
    means = torch.tensor(
        [
            [1.0, 0.0, -10.0],  # in front of both
            [0.0, 0.0, -1.0],  # in front of camera 0 only (camera 1 sees |x - 2| < 0.5 at this depth)
            [0.0, 0.0, 1.0],  # behind both
            [0.0, 3.0, -1.0],  # in front of camera 0, far outside its image
            [0.0, 0.6, -1.0],  # its centre just outside camera 0's image, its extent reaching in
        ]
    )
    log_scales = torch.full((5, 3), -7.0)  # about a thousandth: the centre decides
    log_scales[4] = -2.3  # a tenth: 3 sigma covers 0.3 at depth 1
    assert frames_seeing(means, log_scales, cameras).tolist() == [2, 1, 0, 0, 1]
    small = torch.full((5, 3), -7.0)
    assert frames_seeing(means, small, cameras).tolist() == [2, 1, 0, 0, 0]
    nearest = torch.tensor([101.0, 1.0, 1.0, 10.0]).sqrt()
    out = summary(torch.tensor([2, 1, 0, 0]), nearest, torch.tensor([1.0, 0.5, 0.25, 0.25]), frames=2)
    assert out["share_seen_by_at_most_1"] == 0.75 and out["opacity_share_seen_by_at_most_1"] == 0.5
    assert out["share_seen_by_at_most_3"] == 1.0 and "nearest_camera_seen_by_more_over_median" not in out


def test_few_view_gaussians_takes_the_same_gaussians_out_of_every_parameter():
    from experiments.few_view_gaussians import keep_gaussians

    class Model(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.gauss_params = torch.nn.ParameterDict(
                {
                    "means": torch.nn.Parameter(torch.arange(12.0).view(4, 3)),
                    "opacities": torch.nn.Parameter(torch.arange(4.0)[:, None]),
                }
            )

    model = Model()
    keep_gaussians(model, torch.tensor([True, False, True, False]))
    assert model.gauss_params["means"].tolist() == [[0.0, 1.0, 2.0], [6.0, 7.0, 8.0]]
    assert model.gauss_params["opacities"].view(-1).tolist() == [0.0, 2.0]
    assert isinstance(model.gauss_params["means"], torch.nn.Parameter)


def test_the_batched_cameras_probe_renders_a_batch_as_its_cameras_alone_and_times_every_batch_size(tmp_path):
    """`experiments.batched_cameras` on the demo scene (CPU, the torch rasterizer): a batch of cameras renders what
    each camera renders alone, every batch size gets a row, and the files are written."""
    from experiments.batched_cameras import BatchedArgs, main

    args = BatchedArgs(gaussians=500, batch_sizes=(1, 3), steps=1, warmup_steps=0, downscale=8, output_dir=tmp_path)
    result = main(args)
    assert result["batch_difference"] < 1e-5
    assert [row["cameras"] for row in result["rows"]] == [1, 3]
    assert all(row["ms_per_camera"] * row["cameras"] == pytest.approx(row["ms_per_step"]) for row in result["rows"])
    assert json.loads((tmp_path / "batched_cameras.json").read_text()) == result
    assert "| 3 |" in (tmp_path / "batched_cameras.md").read_text()


def test_the_step_floor_times_both_arms_alternated_and_its_floor_step_trains(tmp_path):
    """The floor is a real training step (its L1 loss falls from the frames' mean level), measured in
    every round beside the method's own steps on the same model."""
    from experiments.step_floor import FloorArgs, main

    result = main(FloorArgs(warmup=30, steps=8, rounds=2, cameras=3, output_dir=tmp_path / "floor"))
    rounds = result["rounds"]
    assert [r["last_step"] for r in rounds] == [37, 45]
    for r in rounds:
        assert r["method_ms_per_step"] > 0 and r["floor_ms_per_step"] > 0
        first, last = r["floor_loss_first_last"]
        assert last < first
    assert "floor ms/step" in (tmp_path / "floor" / "step_floor.md").read_text()


def test_profile_step_with_the_stop_on_trains_as_the_bench_does(tmp_path):
    """`--auto-stop` builds the trainer with the stop (its held-back frames, the budget they set), without
    it none, and the files say which."""
    from experiments.profile_step import ProfileArgs, full_schedule_trainer, profile

    off = full_schedule_trainer("demo", "wild-thermal", (), tmp_path / "off", None)
    assert off.auto_stop is None
    result = profile(
        ProfileArgs(warmup=30, steps=4, profile_steps=2, python_steps=0, auto_stop=True, output_dir=tmp_path / "p")
    )
    assert result["auto_stop"] is True and result["ms_per_step"] > 0
    assert "the automatic stop on" in (tmp_path / "p" / "profile.md").read_text().splitlines()[0]
    on = full_schedule_trainer("demo", "wild-thermal", (), tmp_path / "on", None, auto_stop=True)
    assert on.auto_stop is not None and on.auto_stop.held_back_frames


def test_step_ops_counts_each_part_inside_the_step_and_puts_the_methods_back(tmp_path):
    """`experiments.step_ops` counts the operations of every part of the counted steps alone (a part
    inside the step no more than the step), writes its files, and leaves the counted methods as they were."""
    from experiments.step_ops import StepOpsArgs, count, markdown
    from thermal_wild_ns.training.divergence import DivergenceGuard

    verdict = DivergenceGuard.verdict
    args = StepOpsArgs(warmup=20, steps=2, output_dir=tmp_path / "out", runs_dir=tmp_path / "runs")
    result = count(args)
    ops = result["ops_per_step"]
    assert all(ops[part] > 0 for part in ("step", "render", "losses", "verdict", "adam", "statistics")), ops
    assert max(ops["render"], ops["losses"], ops["verdict"], ops["adam"]) < ops["step"]
    assert result["by_operation"]["adam"]["aten._fused_adam_.default"] >= 1  # one per parameter group
    assert DivergenceGuard.verdict is verdict
    assert "| verdict |" in markdown(result) and (tmp_path / "runs" / "runs").is_dir()


def test_the_trace_summary_splits_a_threads_time_into_operations_and_the_gaps_between_them(tmp_path):
    """`experiments.trace_summary` on a made-up timeline of two steps: top-level operations (a nested one
    is inside its parent, not counted twice), the time between them named by its neighbours, runtime
    calls and the GPU's busy time (overlapping kernels merged), each per step."""
    import gzip

    from experiments.trace_summary import TraceArgs, markdown, summarize

    def op(name, ts, dur, cat="cpu_op", tid=1):
        return {"ph": "X", "name": name, "ts": ts, "dur": dur, "cat": cat, "tid": tid}

    events = [
        op("aten::mm", 0, 100),
        op("aten::addmm", 10, 50),  # inside aten::mm
        op("cudaLaunchKernel", 20, 10, "cuda_runtime"),
        op("aten::add", 300, 100),
        op("cudaStreamSynchronize", 500, 400, "cuda_runtime"),
        op("kernel_a", 0, 200, "kernel", 7),
        op("kernel_b", 100, 200, "kernel", 7),  # overlaps kernel_a: 300 us busy in all
        {"ph": "i", "name": "marker", "ts": 0},
    ]
    path = tmp_path / "trace.json.gz"
    with gzip.open(path, "wt") as f:
        json.dump({"traceEvents": events}, f)
    summary = summarize(TraceArgs(trace=path, steps=2))
    thread = summary["threads"]["1"]
    assert thread["span_ms"] == 0.45  # 0..900 us over 2 steps
    assert thread["in_operations_ms"] == 0.3  # mm 100, add 100, sync 400 (addmm and the launch are inside)
    assert thread["between_operations_ms"] == 0.15
    assert thread["operations"] == 1.5
    assert thread["gaps"][0] == ("aten::mm", "aten::add", 0.1)
    assert ("cudaStreamSynchronize", 0.2, 0.5) in summary["runtime"]
    assert summary["gpu_busy_ms"] == 0.15
    assert "between them" in markdown(summary)


def test_the_best_checkpoint_is_the_highest_scored_point_and_time_to_quality_is_against_it():
    from experiments.bench import best_checkpoint, best_checkpoint_lines, strongest_baseline

    def run(method, seed, points, final):
        curve = [{"step": s, "seconds": s / 100, "psnr_time": p} for s, p in points]
        return {
            "method": method,
            "scene": "s",
            "seed": seed,
            "steps": 3000,
            "train_seconds": 30.0,
            "curve": curve,
            "psnr_time": final,
        }

    # splatfacto peaks early and falls; its final is its worst point
    falling = [run("splatfacto", seed, [(1000, 25.0 + seed), (2000, 24.0)], 20.0) for seed in (0, 1)]
    assert best_checkpoint(falling[1], "time") == {"psnr": 26.0, "step": 1000, "seconds": 10.0}
    assert best_checkpoint(run("m", 0, [(1000, 20.0)], 22.0), "time")["step"] == 3000  # the final model counts
    assert best_checkpoint({"curve": [], "steps": 1}, "time") is None
    grid = [run("splatfacto (use_bilateral_grid=True)", seed, [(1000, 24.0), (2000, 26.0)], 26.0) for seed in (0, 1)]
    # the strongest row is the one whose best is highest on average: the bilateral grid's 26.0 over stock's 25.5
    assert strongest_baseline(falling + grid, "s", "time") == ("splatfacto (use_bilateral_grid=True)", 26.0, 20.0)
    ours = [run("wild-thermal", seed, [(1000, 25.8), (2000, 26.1)], 26.1) for seed in (0, 1)]
    table = "\n".join(best_checkpoint_lines(falling + grid + ours, ["s"]))
    assert "oracle choice" in table
    # stock splatfacto's best 25.50 (26.00 at most) at step 1,000, its final 20.00 beside it
    assert "| splatfacto | s | `time` | 25.50 (25.00–26.00) | 1,000, 1,000 | 20.00 |" in table
    # the full method's mean reaches the strongest best (26.0) at step 2,000, not at 1,000 (25.8)
    assert "| s | `time` | splatfacto (use_bilateral_grid=True), 26.00 | 20.0 | wild-thermal | 2,000 | 20.0 |" in table
