"""Errors in what a user gave (data, poses, frames, options), told apart from bugs.

An `InputError` that reaches the top of an `ns-*` or `wild-thermal-*` command prints as one line
(`error: FILE: what is wrong`) and exits with status 1; set THERMAL_WILD_NS_DEBUG=1 for the
traceback. So does a run's damaged config.yml given to nerfstudio's loading commands
(`_upstream.explain_config_load_error`). Every other exception, a bug, still prints its traceback."""

from __future__ import annotations

import os
import struct
import sys
from contextlib import contextmanager
from typing import Any, Callable, List, Optional

DEBUG = "THERMAL_WILD_NS_DEBUG"


class InputError(ValueError):
    """Something wrong with the user's data or options; the message names the file (and frame)."""


class MissingInput(InputError, FileNotFoundError):
    """A file or folder the user's data or options point to is not there."""


class IncompleteConfig(InputError):
    """A run's config.yml lacks settings it was saved with (cut short: a copy or a disk that failed)."""


STRUCTURAL_FAULTS = (
    struct.error,
    IndexError,
    KeyError,
    ValueError,
    TypeError,
    AttributeError,
    OverflowError,
    ZeroDivisionError,
    UnicodeDecodeError,
    MemoryError,
)
"""What a reader meets in a damaged file: cut short, a count, a key, an offset or a value of the wrong kind."""


@contextmanager
def faults_named(path, what: str, *also: type):
    """Any structural fault met while reading `path` (`STRUCTURAL_FAULTS`, and the reader's own `also`) as an
    `InputError` naming the file and `what` could not be read; an `InputError` raised inside goes through as it
    is."""
    try:
        yield
    except InputError:
        raise
    except STRUCTURAL_FAULTS + also as err:
        raise InputError(f"{path}: {what} ({type(err).__name__}: {err})") from None


EXPLAINERS: List[Callable[[BaseException, Any], Optional[str]]] = []
"""Functions that turn an uncaught error (and its traceback) into the one line a user reads, or
None: `_upstream` adds the one for nerfstudio's config loading when it is imported (every command
that loads a run imports it), as only it knows that loader."""


def report_input_errors_briefly() -> None:
    """Make this process print an uncaught `InputError` as one line (the plugin's commands and its
    method registration, which every `ns-*` command imports, call this; importing the package does
    not). Idempotent."""
    previous = sys.excepthook
    if getattr(previous, "thermal_wild_ns", False):
        return

    def hook(kind, value, traceback):
        message = next((m for m in (explain(value, traceback) for explain in EXPLAINERS) if m is not None), None)
        if message is None and isinstance(value, InputError):
            message = str(value)
        if message is not None and not os.environ.get(DEBUG):
            print(f"error: {message}\n(the traceback: {DEBUG}=1)", file=sys.stderr)
            return
        previous(kind, value, traceback)

    hook.thermal_wild_ns = True
    sys.excepthook = hook


def raised_reading_yaml(error: BaseException, traceback=None) -> bool:
    """Whether `error` is PyYAML's, or rose while PyYAML built the objects a YAML file names (a run's
    config.yml cut inside a tag can name a module where a class was, `!!python/object:thermal_wild_ns.model`,
    and calling it fails with a TypeError): the file's fault, not the code's. `traceback`: the error's
    (default: its own)."""
    if type(error).__module__.split(".")[0] == "yaml" or isinstance(error, IncompleteConfig):
        return True
    traceback = traceback if traceback is not None else error.__traceback__
    while traceback is not None:
        if traceback.tb_frame.f_code.co_filename.endswith(os.path.join("yaml", "constructor.py")):
            return True
        traceback = traceback.tb_next
    return False
