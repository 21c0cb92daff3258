"""A run's files: written so that none is ever half there, and checked before a command reads them.

A run may be killed at any moment (SIGKILL, a power cut, a full disk). Every file of a run
(checkpoint, config, the automatic stop's states and record) is written under a temporary name in
the run's `.partial/` folder, flushed to disk, then renamed into place in one step: a reader sees
the old file or the new one, never a part. The temporary folder sits outside `nerfstudio_models/`,
whose every name nerfstudio's loader parses as a step number.

A run given back to a command is checked before the command reads any data (reading and
preprocessing a dataset takes minutes and writes caches: a typo in `--load-config` should cost a
second): `check_trained_run` for the config, `check_checkpoint` for the checkpoint nerfstudio will
load (a damaged one stops the command with its path and what to do, not a traceback of torch's zip
reader).
"""

from __future__ import annotations

import errno
import os
import re
import zipfile
from pathlib import Path
from typing import Callable, List, Optional

import yaml
from nerfstudio.engine.trainer import TrainerConfig

from thermal_wild_ns.data.thermal_io import process_alive
from thermal_wild_ns.errors import InputError, raised_reading_yaml

PARTIAL_FOLDER = ".partial"
"""Beside a run's config: files being written, before their rename into place."""


class CheckpointNotSaved(InputError):
    """A file of the run could not be written (a full disk, a lost mount): not a bug, so it prints as
    one line; what was there before is intact, and the run can be resumed from it."""


def write_atomically(path: Path, write: Callable[[Path], None], partial_dir: Optional[Path] = None) -> None:
    """`write(tmp)` writes the whole file to a temporary path; it then replaces `path` in one rename.
    `partial_dir` (default: `path`'s folder) holds the temporary file: it must be on the same file
    system. On any failure the temporary file is removed and `path` is as it was; a failure to write
    (OSError: a full disk) raises `CheckpointNotSaved` naming the file and what is kept."""
    path = Path(path)
    folder = Path(partial_dir) if partial_dir is not None else path.parent
    folder.mkdir(parents=True, exist_ok=True)
    path.parent.mkdir(parents=True, exist_ok=True)
    for stale in folder.glob("*.partial"):  # left by a run killed while writing
        pid = stale.name[: -len(".partial")].rsplit(".", 1)[-1]
        if pid.isdigit() and not process_alive(int(pid)):
            stale.unlink(missing_ok=True)
    tmp = folder / f"{path.name}.{os.getpid()}.partial"
    try:
        write(tmp)
        with open(tmp, "rb+") as handle:  # on disk before the rename: a power cut leaves old or new
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except OSError as err:
        tmp.unlink(missing_ok=True)
        full = " (the disk is full: free some space)" if err.errno == errno.ENOSPC else ""
        kept = f"{path} is unchanged" if path.exists() else "nothing was written"
        raise CheckpointNotSaved(f"{path}: could not be written: {err.strerror or err}{full}; {kept}") from err
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_text_atomically(path: Path, text: str, partial_dir: Optional[Path] = None) -> None:
    write_atomically(path, lambda tmp: Path(tmp).write_text(text, encoding="utf8"), partial_dir)


_STEP = re.compile(r"^step-(\d+)\.ckpt$")


def checkpoints_in(folder: Path) -> List[Path]:
    """The nerfstudio checkpoints (`step-*.ckpt`) in `folder`, in step order; none if it is missing."""
    found = [(int(m.group(1)), p) for p in Path(folder).glob("step-*.ckpt") if (m := _STEP.match(p.name))]
    return [p for _, p in sorted(found)]


def checkpoint_problem(path: Path) -> Optional[str]:
    """What is wrong with a checkpoint file (truncated, corrupt, not a checkpoint), or None. torch
    writes checkpoints as zip archives: the archive's directory (at its end: truncation loses it)
    and every member's CRC are checked, which reads the file once."""
    try:
        with zipfile.ZipFile(path) as archive:
            bad = archive.testzip()
    except (zipfile.BadZipFile, EOFError) as err:
        return f"truncated or not a checkpoint ({err})"
    except OSError as err:
        return f"unreadable ({err.strerror or err})"
    if bad is not None:
        return f"corrupt (its part '{bad}' fails its checksum)"
    return None


def check_checkpoint(folder: Path, step: Optional[int] = None) -> Path:
    """The checkpoint nerfstudio loads from `folder` (that of `step`, else the latest), checked; an
    `InputError` naming it, what is wrong and what to do where it is damaged or missing."""
    checkpoints = checkpoints_in(folder)
    if not checkpoints:
        raise InputError(f"{folder}: no step-*.ckpt checkpoint in it (did the run save one?)")
    path = Path(folder) / f"step-{step:09d}.ckpt" if step is not None else checkpoints[-1]
    if not path.is_file():
        raise InputError(f"{path}: no such checkpoint (found: {', '.join(p.name for p in checkpoints)})")
    problem = checkpoint_problem(path)
    if problem is None:
        return path
    earlier = [p for p in checkpoints if p != path and checkpoint_problem(p) is None and p < path]
    what = (
        f"move it out of {folder} to use the previous one, {earlier[-1].name}"
        if earlier
        else "no earlier checkpoint of this run is intact: train again"
    )
    raise InputError(f"{path}: the checkpoint is {problem}; {what}")


def check_trained_run(load_config: Path) -> None:
    """`load_config` is a `wild-thermal*` run's config.yml with at least one checkpoint; otherwise
    exit with one line (a user's input error, not a bug: no traceback)."""

    path = Path(load_config)
    if not path.is_file():
        raise SystemExit(f"--load-config {path}: no such file (a run's config is RUN/config.yml)")
    try:
        config = yaml.load(path.read_text(), Loader=yaml.Loader)  # as nerfstudio's eval_setup reads it
    except Exception as err:
        if not raised_reading_yaml(err):
            raise
        raise SystemExit(
            f"--load-config {path}: the run's config is damaged or cut short, or not a config ({err})"
        ) from None
    if not isinstance(config, TrainerConfig) or config.method_name is None:
        raise SystemExit(f"--load-config {path}: not a nerfstudio run config (no method_name)")
    method = config.method_name
    if not str(method).startswith("wild-thermal"):
        raise SystemExit(f"--load-config {path}: a '{method}' run; this command needs a wild-thermal* run")
    try:
        check_checkpoint(Path(config.get_checkpoint_dir()), config.load_step)
    except InputError as err:
        raise SystemExit(f"--load-config {path}: {err}") from None
