"""One scene across GPUs (`thermal_wild_ns.multi_gpu`), tested on CPU: two processes joined by the gloo
backend, rendering through the pure-torch rasterizer's distributed mode (gsplat's needs CUDA)."""

import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import yaml
from multi_gpu_worker import scene
from nerfstudio.utils.eval_utils import eval_setup

from thermal_wild_ns.multi_gpu import join_process_group
from thermal_wild_ns.pipeline.ranks import RankGroup
from thermal_wild_ns.rendering.torch_rasterizer import rasterization
from thermal_wild_ns.training.held_back import held_back_images, held_back_score

ROOT = Path(__file__).resolve().parents[1]
TORCHRUN = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "2"]


def test_rank_shares_cover_everything_once():
    rows = torch.arange(11)[:, None]
    shares = [RankGroup(r, 3).own_rows({"x": rows})["x"] for r in range(3)]
    assert sorted(torch.cat(shares).flatten().tolist()) == list(range(11))
    # each step trains `world` consecutive images of the order, one per rank, and no image twice
    slots = [RankGroup(r, 2).image_slot(step) for step in range(4) for r in range(2)]
    assert slots == list(range(8))


def test_adams_moment_rates_are_a_setting_and_a_config_saved_without_them_keeps_torchs():
    """Adam's betas are a setting of the fused Adam config (the launcher sets them, with lr and eps,
    for its images per step); a config.yml written before the setting existed loads with torch's rates."""
    from thermal_wild_ns.training.optimizers import FusedAdamOptimizerConfig

    param = torch.nn.Parameter(torch.zeros(3))
    scaled = FusedAdamOptimizerConfig(lr=2e-3, eps=1e-15, betas=(0.8, 0.998)).setup([param])
    assert scaled.defaults["betas"] == (0.8, 0.998) and scaled.defaults["lr"] == 2e-3
    lines = yaml.dump(FusedAdamOptimizerConfig(lr=1e-3)).splitlines()
    start = lines.index("betas: !!python/tuple")
    older = yaml.load("\n".join(lines[:start] + lines[start + 3 :]), Loader=yaml.Loader)  # no betas saved
    assert "betas" not in vars(older) and older.setup([param]).defaults["betas"] == (0.9, 0.999)


def test_the_launcher_sets_every_adam_for_its_images_per_step():
    """Across N GPUs every Adam takes gsplat's settings for N images per step, from the one-image
    settings the user gave (the method's or the command line's); one process keeps them as given."""
    import math

    from thermal_wild_ns.method_configs import method_trainer
    from thermal_wild_ns.multi_gpu import multi_gpu_config

    config = method_trainer("wild-thermal")
    config.optimizers["means"]["optimizer"].lr = 1e-3  # as from the command line
    two, one = multi_gpu_config(config, 2), multi_gpu_config(config, 1)
    for name, group in config.optimizers.items():
        given, scaled = group["optimizer"], two.optimizers[name]["optimizer"]
        assert scaled.lr == pytest.approx(given.lr * math.sqrt(2)) and scaled.eps == pytest.approx(
            given.eps / math.sqrt(2)
        )
        assert scaled.betas == pytest.approx((0.8, 0.998))
        assert one.optimizers[name]["optimizer"] == given
    assert two.optimizers["means"]["optimizer"].lr == pytest.approx(1e-3 * math.sqrt(2))
    assert config.optimizers["means"]["optimizer"].lr == 1e-3  # the parsed config is not changed
    with pytest.raises(ValueError, match="betas"):  # 1 - 20 (1 - 0.9) < 0: no Adam for that batch
        config.optimizers["means"]["optimizer"].for_images(20)


def test_one_decision_for_all_ranks(tmp_path_factory):
    """What the guard and the automatic stop decide across GPUs: a flag any rank raises, every rank
    sees; a step one rank rejects (on the device) every rank rejects; rank 0's score is every rank's.
    And a checkpoint's gather of shares of unequal size."""
    out = split_render_run(tmp_path_factory)
    rows = torch.tensor([0.0, 1, 2, 3, 4, 100, 101, 102])[:, None].repeat(1, 2)  # rank 0's rows, then rank 1's
    for rank in range(2):
        decisions = torch.load(out / f"rank{rank}-decisions.pt")
        gathered = decisions.pop("gathered")
        assert decisions == {"any": True, "from_rank_0": 10.0, "all_agree": False}
        # a checkpoint's Gaussians: whole on rank 0, in host memory, gathered a few rows at a time
        assert torch.equal(gathered, rows if rank == 0 else rows[:0])


def split_render_run(tmp_path_factory):
    """The folder of one two-process run of `multi_gpu_worker.py` (made once for the session's tests)."""
    out = tmp_path_factory.getbasetemp() / "split_render"
    if not out.exists():
        out.mkdir()
        run = subprocess.run([*TORCHRUN, str(ROOT / "tests" / "multi_gpu_worker.py"), str(out)], cwd=ROOT)
        assert run.returncode == 0
    return out


@pytest.mark.parametrize("packed", [False, True])
def test_split_render_and_gradients_equal_one_process(tmp_path_factory, packed):
    """Each rank renders its camera with its half of the Gaussians; the render, every Gaussian's
    gradient and the densification statistics' inputs must be one process's with all of them."""
    out = split_render_run(tmp_path_factory)  # one two-process run writes both layouts
    params, viewmats, Ks, weights = scene()
    full = {k: v.clone().requires_grad_() for k, v in params.items()}
    render, alpha, meta = rasterization(**full, viewmats=viewmats, Ks=Ks, width=48, height=32, packed=packed)
    meta["means2d"].retain_grad()
    ((render * weights).sum() + alpha.sum()).backward()
    assert alpha.sum() > 10  # the Gaussians are seen: the comparison is not of empty images
    for rank in range(2):
        split = torch.load(out / f"rank{rank}-packed{packed}.pt")
        assert split["n_cameras"] == 1
        torch.testing.assert_close(split["render"][0], render[rank].detach(), atol=1e-5, rtol=1e-5)
        for name, param in full.items():
            torch.testing.assert_close(split[name], param.grad[rank::2], atol=1e-5, rtol=1e-4)
        # this rank's Gaussians in both cameras: what the densification statistics read
        if packed:  # [nnz]: camera ids global, Gaussian ids the rank's own
            mine = meta["gaussian_ids"] % 2 == rank
            assert torch.equal(split["gaussian_ids"] * 2 + rank, meta["gaussian_ids"][mine])
            assert torch.equal(split["camera_ids"], meta["camera_ids"][mine])
        else:  # [cameras, N]
            mine = (slice(None), slice(rank, None, 2))
        torch.testing.assert_close(split["means2d_grad"], meta["means2d"].grad[mine], atol=1e-6, rtol=1e-4)
        assert torch.equal(split["radii"], meta["radii"][mine])


@pytest.mark.slow
def test_two_process_run_gives_one_checkpoint_that_loads_on_one_device(tmp_path):
    """The launcher end to end (two CPU processes): one config.yml that a one-device command loads,
    one checkpoint with every rank's Gaussians, the shared networks equal on both ranks (checked at
    every save: the run fails otherwise), the automatic stop's score rendered by both ranks together,
    and a resume across two processes."""
    args = [
        "-m",
        "thermal_wild_ns.multi_gpu",
        "wild-thermal",
        "--output-dir",
        str(tmp_path / "out"),
        "--max-num-iterations",
        "70",  # refinement pauses for the first 45 steps after the opacity reset at 0
        "--machine.device-type",
        "cpu",
        "--pipeline.model.num-downscales",
        "0",
        "--pipeline.model.warmup-length",
        "10",
        "--pipeline.model.refine-every",
        "10",
        "--pipeline.model.densify-grad-thresh",
        "0.00005",  # grows within 40 steps, so the gathered count is more than the seeds
        "thermal-demo-data",
        "--data",
        str(tmp_path / "scene"),
    ]
    run = subprocess.run([*TORCHRUN, *args], cwd=tmp_path, capture_output=True, text=True)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    configs = list((tmp_path / "out").rglob("config.yml"))
    assert len(configs) == 1
    saved = yaml.load(configs[0].read_text(), Loader=yaml.Loader)
    assert not saved.pipeline.model.distributed and not saved.pipeline.datamanager.distributed
    assert not saved.pipeline.model.use_absgrad  # a resumed run grows as this one did
    assert saved.optimizers["emission_mlp"]["optimizer"].betas == pytest.approx((0.8, 0.998))  # what trained
    checkpoints = sorted(configs[0].parent.rglob("*.ckpt"))
    state = torch.load(checkpoints[-1], map_location="cpu", weights_only=False)
    gathered = state["pipeline"]["_model.gauss_params.means"].shape[0]
    assert "means" not in state["optimizers"] and "emission_mlp" in state["optimizers"]

    _, pipeline, _, _ = eval_setup(configs[0], test_mode="test")
    model = pipeline.model
    assert model.num_points == gathered
    assert gathered > len(pipeline.datamanager.train_dataparser_outputs.metadata["points3D_xyz"])
    camera = pipeline.datamanager.eval_dataset.cameras[0:1]
    outputs = model.get_outputs_for_camera(camera)
    assert torch.isfinite(outputs["thermal"]).all() and outputs["accumulation"].mean() > 0.5

    # the automatic stop's last score was rendered by both ranks together: one process renders the same
    record = json.loads((configs[0].parent / "auto_stop.json").read_text())
    images = held_back_images(len(pipeline.datamanager.train_dataset), 2)
    assert len(images) == 2 and record["final_psnr"] is not None
    assert abs(held_back_score(pipeline, images) - record["final_psnr"]) < 1e-3
    assert not list((configs[0].parent / "auto_stop").glob("*rank*"))  # no check before the schedule settles

    # resumed across GPUs: each rank takes its share of the checkpoint's Gaussians (none twice)
    resume = [*args[: args.index("thermal-demo-data")], "--load-dir", str(checkpoints[-1].parent)]
    resume += ["--pipeline.model.refine-every", "1000", *args[args.index("thermal-demo-data") :]]
    resume[resume.index("70")] = "76"  # six more steps, no densification in them
    run = subprocess.run([*TORCHRUN, *resume], cwd=tmp_path, capture_output=True, text=True)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    latest = max((tmp_path / "out").rglob("*.ckpt"), key=lambda path: path.stat().st_mtime)  # the resumed run's
    resumed = torch.load(latest, map_location="cpu", weights_only=False)
    assert resumed["step"] == 75
    assert resumed["pipeline"]["_model.gauss_params.means"].shape[0] == gathered


def test_more_processes_than_gpus_stop_with_the_reason(monkeypatch):
    monkeypatch.setenv("RANK", "1")
    monkeypatch.setenv("LOCAL_RANK", "1")
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    with pytest.raises(SystemExit, match="more processes than this host has GPUs \\(1\\)"):
        join_process_group("cuda")
