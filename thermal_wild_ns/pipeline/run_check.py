"""Checks on a trained run, made before a command reads any data (reading and preprocessing a
dataset takes minutes and writes caches: a typo in `--load-config` should cost a second)."""

from __future__ import annotations

from pathlib import Path


def checkpoints_in(folder: Path) -> list:
    """The nerfstudio checkpoints (`step-*.ckpt`) in `folder`, oldest first; none if it is missing."""
    return sorted(Path(folder).glob("step-*.ckpt"))


def check_trained_run(load_config: Path) -> None:
    """`load_config` is a `wild-thermal*` run's config.yml with at least one checkpoint; otherwise
    exit with one line (a user's input error, not a bug: no traceback)."""
    import yaml

    path = Path(load_config)
    if not path.is_file():
        raise SystemExit(f"--load-config {path}: no such file (a run's config is RUN/config.yml)")
    try:
        config = yaml.load(path.read_text(), Loader=yaml.Loader)  # as nerfstudio's eval_setup reads it
    except yaml.YAMLError as err:
        raise SystemExit(f"--load-config {path}: not a nerfstudio config ({err})") from None
    method = getattr(config, "method_name", None)
    if method is None:
        raise SystemExit(f"--load-config {path}: not a nerfstudio run config (no method_name)")
    if not str(method).startswith("wild-thermal"):
        raise SystemExit(f"--load-config {path}: a '{method}' run; this command needs a wild-thermal* run")
    checkpoints = Path(config.get_checkpoint_dir())
    if not checkpoints_in(checkpoints):
        raise SystemExit(f"--load-config {path}: no checkpoint in {checkpoints} (did the run save one?)")
