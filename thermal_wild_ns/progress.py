"""Progress of the long phases (reading frames, triangulation, preprocessing, scoring, export), one
way for every command: a rich progress bar on a terminal (rich is what nerfstudio's own commands
draw with), plain lines elsewhere (a log file, a pipe, CI), where a redrawn bar would only fill the
log with carriage returns. The lines say where the phase is at its start, about every tenth of the
way and at its end, so a long silent phase is never taken for a hang. They go to stderr: a command
whose stdout is its result (a score as JSON) stays parseable with its progress on."""

from __future__ import annotations

import math
import sys
import time
from typing import Iterable, Iterator, Optional, TypeVar

from nerfstudio.utils.rich_utils import CONSOLE
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

T = TypeVar("T")

LINES_PER_PHASE = 10
"""Off a terminal, a phase prints about this many progress lines (plus its first and last)."""


def track(items: Iterable[T], description: str, total: Optional[int] = None, min_items: int = 1) -> Iterator[T]:
    """Yield `items`, showing `description` and how many of `total` (default `len(items)`) are done.
    Phases of fewer than `min_items` items show nothing (a few frames need no bar)."""
    if total is None:
        total = len(items)  # type: ignore[arg-type]
    if total < min_items:
        yield from items
        return
    if CONSOLE.is_terminal:
        columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
        with Progress(*columns, console=CONSOLE, transient=True) as bar:
            task = bar.add_task(description, total=total)
            for item in items:
                yield item
                bar.advance(task)
        return
    every = max(1, math.ceil(total / LINES_PER_PHASE))
    start = time.monotonic()
    _line(f"{description}: 0/{total}")
    done = 0
    for item in items:
        yield item
        done += 1
        if done % every == 0 or done == total:
            _line(f"{description}: {done}/{total} ({time.monotonic() - start:.0f} s)")


def _line(text: str) -> None:
    print(text, file=sys.stderr, flush=True)
