"""Commands that load a trained run check it before reading any data, and say what is wrong in
one line: no traceback, nothing written."""

import subprocess
import sys
from pathlib import Path

import pytest
import torch

from thermal_wild_ns.demo import demo_trainer_config
from thermal_wild_ns.pipeline.run_check import check_trained_run


def _saved_config(out: Path, method: str) -> Path:
    config = demo_trainer_config(out, steps=10, max_gaussians=100)
    config.method_name = method
    config.set_timestamp()
    config.save_config()
    return config.get_base_dir() / "config.yml"


def _command(name: str, *args: str, cwd: Path, env=None) -> subprocess.CompletedProcess:
    """One of the venv's commands, run to its end in `cwd`."""
    command = [str(Path(sys.executable).parent / name), *args]
    return subprocess.run(command, capture_output=True, text=True, timeout=300, cwd=cwd, env=env)


def test_trained_run_checks(tmp_path):
    with pytest.raises(SystemExit, match=r"nowhere\.yml: no such file"):
        check_trained_run(tmp_path / "nowhere.yml")
    (tmp_path / "bad.yml").write_text("key: [unclosed")
    with pytest.raises(SystemExit, match=r"bad\.yml: the run.s config is damaged or cut short"):
        check_trained_run(tmp_path / "bad.yml")
    # cut inside a tag, the file names a module where a class was: PyYAML calls it (a TypeError)
    text = _saved_config(tmp_path / "c", "wild-thermal").read_text()
    tag = "!!python/object:thermal_wild_ns.model"
    (tmp_path / "cut.yml").write_text(text[: text.index(tag + ".") + len(tag)] + "\n")
    with pytest.raises(SystemExit, match=r"cut\.yml: the run.s config is damaged or cut short.*not callable"):
        check_trained_run(tmp_path / "cut.yml")
    with pytest.raises(SystemExit, match=r"a 'splatfacto' run; this command needs a wild-thermal\* run"):
        check_trained_run(_saved_config(tmp_path / "a", "splatfacto"))
    untrained = _saved_config(tmp_path / "b", "wild-thermal")
    with pytest.raises(SystemExit, match=r"nerfstudio_models: no step-\*\.ckpt checkpoint in it"):
        check_trained_run(untrained)
    checkpoints = untrained.parent / "nerfstudio_models"
    checkpoints.mkdir()
    (checkpoints / "step-000000009.ckpt").write_bytes(b"")  # an empty file is no checkpoint
    with pytest.raises(SystemExit, match=r"step-000000009\.ckpt: the checkpoint is truncated.*train again"):
        check_trained_run(untrained)
    torch.save({"step": 9}, checkpoints / "step-000000009.ckpt")
    check_trained_run(untrained)  # a whole checkpoint passes


@pytest.mark.slow
@pytest.mark.parametrize("command", [["wild-thermal-export", "gaussian-splat"], ["wild-thermal-render", "spiral"]])
def test_loading_commands_fail_fast_and_leave_nothing(tmp_path, command):
    config = _saved_config(tmp_path / "run", "splatfacto")
    out = tmp_path / "out"
    where = ["--output-dir", str(out)] if command[0] == "wild-thermal-export" else ["--output-path", str(out / "v.mp4")]
    result = _command(command[0], *command[1:], "--load-config", str(config), *where, cwd=tmp_path)
    assert result.returncode == 1 and "a 'splatfacto' run" in result.stderr, result.stderr[-1500:]
    assert "Traceback" not in result.stderr
    assert not out.exists() and not (tmp_path / "outputs").exists()  # no output folder, no data cache


@pytest.mark.slow
def test_a_data_error_in_ns_train_is_one_line_unless_debugging(tmp_path):
    import json
    import os

    import layout_fixtures as fx

    fx.write_nerfstudio(tmp_path / "s")
    meta = json.loads((tmp_path / "s" / "transforms.json").read_text())
    meta["frames"][2]["transform_matrix"][0][3] = float("nan")
    (tmp_path / "s" / "transforms.json").write_text(json.dumps(meta))
    args = ["wild-thermal", "--vis", "tensorboard", "--output-dir", str(tmp_path / "out"), "thermal"]
    args += ["--data", str(tmp_path / "s")]
    env = {k: v for k, v in os.environ.items() if k != "THERMAL_WILD_NS_DEBUG"}
    result = _command("ns-train", *args, cwd=tmp_path, env=env)
    assert result.returncode == 1 and "Traceback" not in result.stderr, result.stderr[-2000:]
    assert "error: " in result.stderr and "frame images/0002.png: camera pose has non-finite values" in result.stderr
    debug = _command("ns-train", *args, cwd=tmp_path, env={**env, "THERMAL_WILD_NS_DEBUG": "1"})
    assert debug.returncode == 1 and "Traceback" in debug.stderr and "non-finite values" in debug.stderr


@pytest.mark.slow
def test_ns_eval_of_a_run_without_checkpoints_fails_before_reading_data(tmp_path):
    config = _saved_config(tmp_path / "run", "wild-thermal")
    result = _command(
        "ns-eval", "--load-config", str(config), "--output-path", str(tmp_path / "eval.json"), cwd=tmp_path
    )
    assert result.returncode == 1, result.stderr[-2000:]
    assert "nerfstudio_models: no step-*.ckpt checkpoint in it" in result.stderr, result.stderr[-2000:]
    assert "Traceback" not in result.stderr
    # the demo dataparser would have generated its scene, and preprocessing filled its cache
    assert not (tmp_path / "run" / "scene").exists() and not (tmp_path / "run" / ".thermal_cache").exists()
    assert not (tmp_path / "eval.json").exists()
