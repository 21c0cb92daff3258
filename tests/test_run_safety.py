"""Nothing a run made is lost, and every stop says why: a run killed while saving resumes from its
last whole checkpoint; a full disk keeps the previous checkpoint; a damaged checkpoint, config or
cache is named (a cache is rebuilt); two runs can share one triangulation cache; a run whose data
moved or changed says so; and scoring shows its progress."""

from __future__ import annotations

import errno
import json
import multiprocessing
import os
import re
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from demo_trainers import demo_trainer
from ns_runs import ns_train, run_args

from thermal_wild_ns.errors import InputError
from thermal_wild_ns.pipeline.run_check import (
    PARTIAL_FOLDER,
    CheckpointNotSaved,
    check_checkpoint,
    checkpoint_problem,
    checkpoints_in,
)

BIN = Path(sys.executable).parent


def _command(name: str, *args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / name), *args], capture_output=True, text=True, timeout=600, cwd=cwd)


@pytest.fixture(scope="module")
def trained_run(tmp_path_factory):
    """A 3-step `ns-train wild-thermal` run on a small nerfstudio-layout capture (its folder, its data)."""
    import layout_fixtures as fx

    root = tmp_path_factory.mktemp("run")
    data = root / "data"
    fx.write_nerfstudio(data, n=26)
    ns_train([*run_args(root / "out"), "thermal", "--data", str(data), "--cache-dir", str(root / "seeds")])
    return root / "out" / "x" / "wild-thermal" / "run", data


def _copy_run(run: Path, tmp_path: Path) -> Path:
    """A copy of the trained run whose config points at the copy's own checkpoints."""
    import yaml

    config = yaml.load((run / "config.yml").read_text(), Loader=yaml.Loader)
    config.output_dir, config.experiment_name = tmp_path, "copy"
    copy = config.get_base_dir()
    shutil.copytree(run, copy)
    config.pipeline.checkpoint_dir = copy / "nerfstudio_models"
    (copy / "config.yml").write_text(yaml.dump(config))
    return copy


# ------------------------------------------------------------------ killed while saving
KILLED_CHILD = """
import sys, time
from pathlib import Path
sys.path[:0] = {paths!r}
import thermal_wild_ns.training.checkpoints as checkpoints
from ns_runs import ns_train, run_args

marker, saves = Path({marker!r}), []
original = checkpoints.write_atomically

def slow_second_checkpoint(path, write, partial_dir=None):
    def writing(tmp):
        write(tmp)
        if path.suffix == ".ckpt":
            saves.append(path)
            if len(saves) == 2:  # half-way through the second save: written, not yet renamed
                marker.write_text(str(tmp))
                time.sleep(600)
    original(path, writing, partial_dir)

checkpoints.write_atomically = slow_second_checkpoint
ns_train([*run_args(Path({out!r}), 20), "--steps-per-save", "4", "thermal-demo-data", "--data", {data!r}])
"""


@pytest.mark.slow
def test_a_run_killed_while_saving_resumes_from_its_last_whole_checkpoint(tmp_path, demo_scene_dir):
    out, marker = tmp_path / "out", tmp_path / "saving"
    tests = str(Path(__file__).parent)
    script = KILLED_CHILD.format(
        paths=[tests, str(Path(tests).parent)], marker=str(marker), out=str(out), data=str(demo_scene_dir)
    )
    child = subprocess.Popen([sys.executable, "-c", textwrap.dedent(script)], cwd=tmp_path)
    try:
        deadline = time.monotonic() + 300
        while not marker.is_file():
            assert child.poll() is None, "the run ended before its second checkpoint"
            assert time.monotonic() < deadline, "no second checkpoint within 5 minutes"
            time.sleep(0.2)
        partial = Path(marker.read_text())
        assert partial.is_file() and partial.stat().st_size > 0  # killed with a checkpoint half-saved
    finally:
        os.kill(child.pid, signal.SIGKILL)
        child.wait()
    run = out / "x" / "wild-thermal" / "run"
    (kept,) = checkpoints_in(run / "nerfstudio_models")  # the first save only, and whole
    assert checkpoint_problem(kept) is None
    # resumed: it goes on from there to the total, and the killed save's leftovers are gone
    ns_train(
        [
            *run_args(out, 20),
            "--steps-per-save",
            "4",
            "--load-dir",
            str(run / "nerfstudio_models"),
            "thermal-demo-data",
            "--data",
            str(demo_scene_dir),
        ]
    )
    assert checkpoints_in(run / "nerfstudio_models")[-1].name == "step-000000019.ckpt"
    assert not list((run / PARTIAL_FOLDER).glob("*"))


# ------------------------------------------------------------------ full disk
def test_a_full_disk_during_a_save_keeps_the_previous_checkpoint(tmp_path, demo_scene_dir, monkeypatch):
    trainer = demo_trainer(tmp_path, demo_scene_dir, steps=10, section="auto_stop", enabled=False)
    trainer.save_checkpoint(0)
    (before,) = checkpoints_in(trainer.checkpoint_dir)
    content = before.read_bytes()
    real_save = torch.save

    def disk_fills(obj, path, *args, **kwargs):
        Path(path).write_bytes(b"PK" + b"\0" * 1000)  # part of the file made it to the disk
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(torch, "save", disk_fills)
    with pytest.raises(CheckpointNotSaved, match=r"step 1: .*the disk is full.*step-000000000\.ckpt, is whole"):
        trainer.save_checkpoint(1)
    monkeypatch.setattr(torch, "save", real_save)
    assert checkpoints_in(trainer.checkpoint_dir) == [before] and before.read_bytes() == content
    assert checkpoint_problem(before) is None
    assert not list(Path(trainer.config.get_base_dir(), PARTIAL_FOLDER).glob("*"))  # no partial file left


# ------------------------------------------------------------------ damaged files given back
def test_a_damaged_checkpoint_is_named_with_what_to_do(tmp_path):
    folder = tmp_path / "nerfstudio_models"
    folder.mkdir()
    torch.save({"step": 0}, folder / "step-000000000.ckpt")
    torch.save({"step": 5, "weights": torch.arange(1000.0)}, folder / "step-000000005.ckpt")
    assert check_checkpoint(folder).name == "step-000000005.ckpt"
    whole = (folder / "step-000000005.ckpt").read_bytes()
    (folder / "step-000000005.ckpt").write_bytes(whole[: len(whole) // 2])  # cut short
    with pytest.raises(InputError, match=r"step-000000005\.ckpt: the checkpoint is truncated.*step-000000000\.ckpt"):
        check_checkpoint(folder)
    flipped = bytearray(whole)
    at = whole.index(np.float32(500.0).tobytes())  # a byte of the stored weights
    flipped[at] ^= 0xFF
    (folder / "step-000000005.ckpt").write_bytes(bytes(flipped))
    with pytest.raises(InputError, match=r"step-000000005\.ckpt: the checkpoint is corrupt"):
        check_checkpoint(folder)
    (folder / "step-000000000.ckpt").unlink()
    with pytest.raises(InputError, match="no earlier checkpoint of this run is intact"):
        check_checkpoint(folder)


@pytest.mark.slow
def test_commands_given_a_damaged_run_say_which_file_in_one_line(trained_run, tmp_path):
    run, _ = trained_run
    copy = _copy_run(run, tmp_path)
    (checkpoint,) = checkpoints_in(copy / "nerfstudio_models")
    data = checkpoint.read_bytes()
    checkpoint.write_bytes(data[: len(data) // 3])
    config = str(copy / "config.yml")
    evaluated = _command("ns-eval", "--load-config", config, "--output-path", str(tmp_path / "e.json"), cwd=tmp_path)
    rendered = _command(
        "wild-thermal-render", "spiral", "--load-config", config, "--output-path", str(tmp_path / "s.mp4"), cwd=tmp_path
    )
    for result in (evaluated, rendered):
        assert result.returncode == 1, result.stderr[-2000:]
        assert "Traceback" not in result.stderr and f"{checkpoint}: the checkpoint is truncated" in result.stderr
    # --load-dir: the same check before any data is read
    resumed = _command(
        "ns-train",
        *run_args(tmp_path / "again"),
        "--load-dir",
        str(copy / "nerfstudio_models"),
        "thermal",
        "--data",
        str(tmp_path / "nowhere"),
        cwd=tmp_path,
    )
    assert resumed.returncode == 1 and "the checkpoint is truncated" in resumed.stderr
    assert "Traceback" not in resumed.stderr
    # a config cut short (mid-line, and at a line's end)
    checkpoint.write_bytes(data)
    text = (copy / "config.yml").read_text()
    for cut in (text[: len(text) // 2], "\n".join(text.splitlines()[: len(text.splitlines()) // 2]) + "\n"):
        (copy / "config.yml").write_text(cut)
        result = _command("ns-eval", "--load-config", config, "--output-path", str(tmp_path / "e.json"), cwd=tmp_path)
        assert result.returncode == 1 and "Traceback" not in result.stderr
        assert f"{config}: the run's config is damaged or cut short" in result.stderr


# ------------------------------------------------------------------ data moved or changed
@pytest.mark.slow
def test_a_run_whose_data_changed_or_moved_says_so(trained_run, tmp_path):
    from nerfstudio.utils.eval_utils import eval_setup

    from thermal_wild_ns.errors import MissingInput

    run, data = trained_run
    assert json.loads((run / "data.json").read_text())["frames"]  # what it was trained on, recorded
    copy = _copy_run(run, tmp_path)
    eval_setup(copy / "config.yml", test_mode="test")  # unchanged data loads
    moved = data.parent / "data-moved"
    frame = sorted((data / "images").glob("*"))[3]
    original = frame.read_bytes()
    try:
        data.rename(moved)
        with pytest.raises(MissingInput, match=rf"This run was trained on {data}.*set its new folder"):
            eval_setup(copy / "config.yml", test_mode="test")
        moved.rename(data)
        pixels = np.array(__import__("cv2").imread(str(frame), -1))
        pixels[:10, :10] = pixels.max()
        __import__("cv2").imwrite(str(frame), pixels)
        with pytest.raises(InputError, match=rf"the data changed since this run was trained.*changed.*{frame.name}"):
            eval_setup(copy / "config.yml", test_mode="test")
    finally:
        if moved.exists():
            moved.rename(data)
        frame.write_bytes(original)


# ------------------------------------------------------------------ caches
def _triangulating_slowly(frames, radiometric_range, work_dir, config):
    time.sleep(1.5)  # both runs are inside the build at once
    return np.ones((10, 3)), np.zeros(10), {"points": 10}


def _triangulate_into(cache: str, frames, rng) -> int:
    import thermal_wild_ns.data.triangulation as triangulation

    triangulation.triangulate = _triangulating_slowly
    xyz, _ = triangulation.cached_triangulation(frames, rng, Path(cache))
    return len(xyz)


def _capture(tmp_path):
    import layout_fixtures as fx

    from thermal_wild_ns.data.dataparsers import ThermalDataParserConfig

    fx.write_colmap(tmp_path / "scene", n=8)
    parser = ThermalDataParserConfig(data=tmp_path / "scene", seed_points="random").setup()
    return parser.capture().frames, parser.radiometric_range()


def test_two_runs_share_one_triangulation_cache_at_once(tmp_path):
    frames, rng = _capture(tmp_path)
    cache = tmp_path / "cache"
    context = multiprocessing.get_context("fork")
    with context.Pool(2) as pool:
        counts = pool.starmap(_triangulate_into, [(str(cache), frames, rng)] * 2)
    assert counts == [10, 10]
    (folder,) = cache.glob("triangulation-*")
    assert json.loads((folder / "report.json").read_text())["points"] == 10
    assert np.load(folder / "points.npy").shape == (10, 3)
    assert not [p for p in cache.iterdir() if p.name.startswith(".")]  # no work folder left behind


def test_a_damaged_cache_is_rebuilt_not_read(tmp_path, monkeypatch, demo_scene_dir):
    import thermal_wild_ns.data.triangulation as triangulation
    from thermal_wild_ns.data.dataparsers import ThermalDemoDataParserConfig
    from thermal_wild_ns.preprocessing.photometric import PhotometricConfig
    from thermal_wild_ns.preprocessing.stage import preprocess

    frames, rng = _capture(tmp_path)
    calls = []
    monkeypatch.setattr(triangulation, "triangulate", lambda *a: calls.append(1) or _triangulating_slowly(*a))
    triangulation.cached_triangulation(frames, rng, tmp_path / "cache")
    (folder,) = (tmp_path / "cache").glob("triangulation-*")
    (folder / "points.npy").write_bytes((folder / "points.npy").read_bytes()[:100])
    xyz, _ = triangulation.cached_triangulation(frames, rng, tmp_path / "cache")
    assert len(calls) == 2 and xyz.shape == (10, 3)

    parser = ThermalDemoDataParserConfig(data=demo_scene_dir).setup()
    demo_frames, demo_rng = parser.capture().frames, parser.radiometric_range()
    sequence = preprocess(demo_frames, demo_rng, PhotometricConfig(), tmp_path / "pre")
    expected = sequence.read_frame(5)
    path = sequence.frame_path(5)
    path.write_bytes(path.read_bytes()[:200])  # cut short
    again = preprocess(demo_frames, demo_rng, PhotometricConfig(), tmp_path / "pre")
    np.testing.assert_array_equal(again.read_frame(5), expected)


# ------------------------------------------------------------------ progress
@pytest.mark.slow
def test_ns_eval_shows_its_progress_through_scoring(trained_run, tmp_path):
    run, _ = trained_run
    result = _command(
        "ns-eval", "--load-config", str(run / "config.yml"), "--output-path", str(tmp_path / "e.json"), cwd=tmp_path
    )
    assert result.returncode == 0, result.stderr[-2000:]
    lines = [line for line in result.stderr.splitlines() if line.startswith("Scoring held-out views")]
    views = json.loads((tmp_path / "e.json").read_text())["results"]["views"]
    assert lines[0].endswith(f": 0/{views}") and lines[-1].split(": ")[1].startswith(f"{views}/{views}")
    assert "\r" not in result.stderr  # plain lines off a terminal, no redrawn bar


@pytest.mark.slow
def test_the_demo_shows_its_progress_through_scoring(tmp_path):
    """The README's main command: after training it scores the held-out views under five protocols, says
    where it is meanwhile and how long the scoring took."""
    demo = ("wild-thermal-demo", "--steps", "20", "--seed", "3", "--output-dir", str(tmp_path / "demo"))
    result = _command(*demo, cwd=tmp_path)
    assert result.returncode == 0, result.stderr[-2000:]
    lines = [line for line in result.stderr.splitlines() if line.startswith("Scoring held-out views")]
    assert any(line.startswith("Scoring held-out views (novel, time, aligned, half, oracle): 0/") for line in lines)
    done = lines[-1].split(": ")[1].split(" ")[0]
    assert done.split("/")[0] == done.split("/")[1]  # the last line says every view is scored
    metrics = json.loads((tmp_path / "demo" / "metrics.json").read_text())
    config = Path(metrics["config"]).read_text()
    # --seed: the random generators' (the machine's seed) and the order the frames are visited in
    assert re.search(r"^\s*seed: 3$", config, re.M) and re.search(r"^\s*train_order_seed: 3$", config, re.M)
    assert metrics["score_seconds"] > 0 and f"{len(metrics['per_view'])} held-out views scored in" in result.stdout
