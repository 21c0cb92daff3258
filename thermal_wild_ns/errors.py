"""Errors in what a user gave (data, poses, frames, options), told apart from bugs.

An `InputError` that reaches the top of an `ns-*` or `wild-thermal-*` command prints as one line
(`error: FILE: what is wrong`) and exits with status 1; set THERMAL_WILD_NS_DEBUG=1 for the
traceback. Every other exception, a bug, still prints its traceback."""

from __future__ import annotations

import os
import sys

DEBUG = "THERMAL_WILD_NS_DEBUG"


class InputError(ValueError):
    """Something wrong with the user's data or options; the message names the file (and frame)."""


class MissingInput(InputError, FileNotFoundError):
    """A file or folder the user's data or options point to is not there."""


def report_input_errors_briefly() -> None:
    """Make this process print an uncaught `InputError` as one line (commands call this; importing
    the package does not). Idempotent."""
    previous = sys.excepthook
    if getattr(previous, "thermal_wild_ns", False):
        return

    def hook(kind, value, traceback):
        if isinstance(value, InputError) and not os.environ.get(DEBUG):
            print(f"error: {value}\n(the traceback: {DEBUG}=1)", file=sys.stderr)
            return
        previous(kind, value, traceback)

    hook.thermal_wild_ns = True
    sys.excepthook = hook
