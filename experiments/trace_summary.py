"""`python -m experiments.trace_summary TRACE`: where the host's time goes in a profiled timeline.

Reads a torch profiler trace (`profile_step --trace` writes `trace.json.gz`) and prints, per host thread
(the main thread runs the step; on a GPU the backward runs on autograd's device thread): the wall span,
the time inside top-level operations and the time between them (Python, the trainer's own work), the
operations that take the most of it, and the largest summed gaps by the operations around them; then the
CUDA runtime calls by total time (a synchronising call is time the host waits for the GPU) and the GPU's
busy time. A step much longer than its kernels is bound by what the host does between launches: this
says which.
"""

from __future__ import annotations

import collections
import gzip
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Tuple

import tyro
from typing_extensions import Annotated

HOST_CATEGORIES = ("cpu_op", "cuda_runtime", "cuda_driver")


@dataclass
class TraceArgs:
    trace: Annotated[Path, tyro.conf.Positional]
    """A chrome trace of torch.profiler (`.json` or `.json.gz`)."""
    steps: int = 10
    """Steps the trace holds (per-step numbers divide by it)."""
    top: int = 20
    """Rows per table."""


def top_level(events: List[dict]) -> List[dict]:
    """The events not inside another (by time) of one thread, in time order."""
    events = sorted(events, key=lambda e: (e["ts"], -e["dur"]))
    outer, end = [], float("-inf")
    for event in events:
        if event["ts"] >= end:
            outer.append(event)
            end = event["ts"] + event["dur"]
    return outer


def busy_time(events: List[dict]) -> float:
    """The time covered by any of `events` (overlaps counted once), microseconds."""
    total, end = 0.0, float("-inf")
    for event in sorted(events, key=lambda e: e["ts"]):
        start, stop = max(event["ts"], end), event["ts"] + event["dur"]
        if stop > start:
            total += stop - start
        end = max(end, stop)
    return total


def thread_summary(events: List[dict], steps: int, top: int) -> Dict:
    """Span, time in top-level operations and between them, the largest operations and gaps, per step (ms)."""
    outer = top_level(events)
    span = outer[-1]["ts"] + outer[-1]["dur"] - outer[0]["ts"]
    busy = sum(e["dur"] for e in outer)
    by_name: Dict[str, float] = collections.defaultdict(float)
    count: Dict[str, int] = collections.Counter()
    for event in outer:
        by_name[event["name"]] += event["dur"]
        count[event["name"]] += 1
    gaps: Dict[Tuple[str, str], float] = collections.defaultdict(float)
    for a, b in zip(outer, outer[1:]):
        gaps[(a["name"][:48], b["name"][:48])] += b["ts"] - (a["ts"] + a["dur"])
    per_step = lambda us: round(us / 1000 / steps, 4)
    return {
        "span_ms": per_step(span),
        "in_operations_ms": per_step(busy),
        "between_operations_ms": per_step(span - busy),
        "operations": len(outer) / steps,
        "largest": [
            (name, per_step(t), count[name] / steps) for name, t in sorted(by_name.items(), key=lambda kv: -kv[1])[:top]
        ],
        "gaps": [(a, b, per_step(t)) for (a, b), t in sorted(gaps.items(), key=lambda kv: -kv[1])[:top]],
    }


def summarize(args: TraceArgs) -> Dict:
    opener = gzip.open if args.trace.suffix == ".gz" else open
    with opener(args.trace, "rt") as f:
        events = [e for e in json.load(f)["traceEvents"] if e.get("ph") == "X" and "dur" in e]
    host = [e for e in events if e.get("cat") in HOST_CATEGORIES]
    threads = collections.Counter(e["tid"] for e in host if e.get("cat") == "cpu_op")
    runtime: Dict[str, float] = collections.defaultdict(float)
    runtime_count: Dict[str, int] = collections.Counter()
    for e in events:
        if e.get("cat") == "cuda_runtime":
            runtime[e["name"]] += e["dur"]
            runtime_count[e["name"]] += 1
    kernels = [e for e in events if e.get("cat") in ("kernel", "gpu_memcpy", "gpu_memset")]
    gpu_busy = busy_time(kernels)
    return {
        "threads": {
            str(tid): thread_summary([e for e in host if e["tid"] == tid], args.steps, args.top)
            for tid, _ in threads.most_common(3)
        },
        "runtime": [
            (name, round(t / 1000 / args.steps, 4), runtime_count[name] / args.steps)
            for name, t in sorted(runtime.items(), key=lambda kv: -kv[1])[: args.top]
        ],
        "gpu_busy_ms": round(gpu_busy / 1000 / args.steps, 4),
    }


def markdown(summary: Dict) -> str:
    lines = [f"GPU busy (kernels, copies, memsets; overlaps merged): {summary['gpu_busy_ms']:.3f} ms/step", ""]
    for tid, t in summary["threads"].items():
        lines += [
            f"## thread {tid}: {t['span_ms']:.3f} ms/step of wall time, {t['in_operations_ms']:.3f} in "
            f"{t['operations']:.0f} top-level operations, {t['between_operations_ms']:.3f} between them",
            "",
            "| operation | ms/step | calls/step |",
            "| --- | --- | --- |",
        ]
        lines += [f"| {name[:80]} | {ms:.3f} | {n:.1f} |" for name, ms, n in t["largest"]]
        lines += ["", "| gap after | gap before | ms/step |", "| --- | --- | --- |"]
        lines += [f"| {a} | {b} | {ms:.3f} |" for a, b, ms in t["gaps"]]
        lines.append("")
    lines += ["## CUDA runtime calls", "", "| call | ms/step | calls/step |", "| --- | --- | --- |"]
    lines += [f"| {name} | {ms:.3f} | {n:.1f} |" for name, ms, n in summary["runtime"]]
    return "\n".join(lines) + "\n"


def entrypoint() -> None:
    print(markdown(summarize(tyro.cli(TraceArgs))))


if __name__ == "__main__":
    entrypoint()
