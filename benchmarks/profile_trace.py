"""Where a program's device time goes, from a JAX profiler trace (``campaign.py profile``).

``jax.profiler.trace(folder)`` writes the run's XSpace (``*.xplane.pb``), which
``jax.profiler.ProfileData`` reads whole (the Perfetto JSON it can also write keeps only a
million events: a CPU training chunk of Hopper fills that). Within each annotated part of
the run (``jax.profiler.TraceAnnotation``) this sums the device's ops: how long the device
was busy (the union of its ops' intervals, over every stream), how many ops it ran per
step of the part, and which op kinds cost most. On a GPU the ops are the kernels and copies
on the ``/device:GPU:N`` planes' stream lines. A latency-bound program shows as wall time
well above busy time and many short ops per step: the gaps are the host's launches and its
waits on data-dependent loops. XLA:CPU has no device planes: there the ops are the thunks
its worker threads run (the events that name an HLO op), and a ``while`` thunk is left out
where the thunks it runs are counted.
"""

from __future__ import annotations

import collections
import dataclasses
import glob
import os
import re
from typing import Any

NUMBERED = re.compile(r"([._]\d+)+$")  # fusion.12, copy_3: one op kind


@dataclasses.dataclass(frozen=True)
class Op:
    track: str  # plane/line
    kind: str  # its HLO op (or kernel name), numbering dropped
    start_us: float
    end_us: float


def read_profile(folder: str) -> Any:
    """The newest ``*.xplane.pb`` under ``folder``, as ``jax.profiler.ProfileData``."""
    import jax  # only where a trace is read: the summaries below are plain Python

    paths = sorted(glob.glob(os.path.join(folder, "**", "*.xplane.pb"), recursive=True), key=os.path.getmtime)
    if not paths:
        raise ValueError(f"no *.xplane.pb under {folder}: trace it with jax.profiler.trace({folder!r})")
    return jax.profiler.ProfileData.from_file(paths[-1])


def _stat(event: Any, name: str) -> Any:
    return next((value for key, value in event.stats if key == name), None)


def device_ops(profile: Any) -> tuple[str, list[Op]]:
    """(where the ops ran, the ops): the ``/device:`` planes' stream lines (every line of a
    plane that has none), else the host's XLA worker threads' events that name an HLO op;
    none, said so, where the trace holds neither (a GPU traced without CUPTI)."""
    devices = [plane for plane in profile.planes if plane.name.startswith("/device:")]
    if devices:
        ops = []
        for plane in devices:
            lines = [line for line in plane.lines if "Stream" in line.name] or list(plane.lines)
            ops += [_op(f"{plane.name}/{line.name}", event) for line in lines for event in line.events]
        return ", ".join(plane.name for plane in devices), leaves(ops)
    ops = [_op(f"{plane.name}/{line.name}", event) for plane in profile.planes for line in plane.lines
           if line.name.startswith("tf_XLA") for event in line.events if _stat(event, "hlo_op") is not None]
    if not ops:
        return "no device ops in the trace (a GPU's need NVIDIA's CUPTI library)", []
    return "XLA:CPU worker threads", leaves(ops)


def _op(track: str, event: Any) -> Op:
    kind = NUMBERED.sub("", str(_stat(event, "hlo_op") or event.name))
    return Op(track, kind, event.start_ns / 1e3, (event.start_ns + event.duration_ns) / 1e3)


def leaves(ops: list[Op]) -> list[Op]:
    """The ops that hold no other op of their track: an XLA:CPU ``while`` or ``call`` thunk
    spans the thunks it runs, so counting both would count their time twice."""
    tracks: dict[str, list[Op]] = collections.defaultdict(list)
    for op in ops:
        tracks[op.track].append(op)
    kept = []
    for track in tracks.values():
        track.sort(key=lambda op: (op.start_us, -op.end_us))
        kept += [op for op, after in zip(track, track[1:] + [None]) if after is None or after.start_us >= op.end_us]
    return kept


def annotation(profile: Any, name: str) -> tuple[float, float]:
    """(start, end) in µs of the host's ``TraceAnnotation(name)``."""
    for plane in profile.planes:
        for line in plane.lines:
            for event in line.events:
                if event.name == name:
                    return event.start_ns / 1e3, (event.start_ns + event.duration_ns) / 1e3
    raise ValueError(f"the trace holds no annotation {name!r}")


def busy_us(intervals: list[tuple[float, float]]) -> float:
    """Length of the union of (start, end) intervals: time anything ran, overlaps counted once."""
    total, reach = 0.0, float("-inf")
    for start, end in sorted(intervals):
        if end > reach:
            total += end - max(start, reach)
            reach = end
    return total


def summarize_part(ops: list[Op], name: str, window: tuple[float, float], steps: int, top: int) -> dict:
    """The ops that ran within ``window`` (clipped to it), the part ``name`` of ``steps``
    sequential steps (loop steps of a scoring round, iterations of a training chunk)."""
    start, end = window
    inside = [(max(op.start_us, start), min(op.end_us, end), op.kind) for op in ops if op.start_us < end and op.end_us > start]
    busy = busy_us([(a, b) for a, b, _ in inside])
    kinds: dict[str, list] = collections.defaultdict(lambda: [0.0, 0])
    for a, b, kind in inside:
        kinds[kind][0] += b - a
        kinds[kind][1] += 1
    wall = end - start
    return {
        "part": name, "steps": steps, "wall_ms": round(wall / 1e3, 3), "busy_ms": round(busy / 1e3, 3),
        "busy_share": round(busy / wall, 4) if wall else 0.0, "ops": len(inside),
        "ops_per_step": round(len(inside) / steps, 1), "busy_us_per_step": round(busy / steps, 1),
        "idle_us_per_step": round((wall - busy) / steps, 1),
        "costliest": [{"op": kind, "ms": round(us / 1e3, 3), "share_of_busy": round(us / busy, 4) if busy else 0.0,
                       "count": count} for kind, (us, count) in sorted(kinds.items(), key=lambda item: -item[1][0])[:top]],
    }


def describe(part: dict) -> str:
    """A part's summary in lines, for the log."""
    lines = [f"{part['part']}: wall {part['wall_ms']:,.1f} ms, device busy {part['busy_ms']:,.1f} ms "
             f"({part['busy_share']:.0%}); {part['ops']:,} ops = {part['ops_per_step']:,.1f} per step over "
             f"{part['steps']:,} steps; per step {part['busy_us_per_step']:,.1f} µs busy, "
             f"{part['idle_us_per_step']:,.1f} µs idle"]
    lines += [f"  {row['ms']:10,.2f} ms {row['share_of_busy']:6.1%} {row['count']:9,}x  {row['op']}" for row in part["costliest"]]
    return "\n".join(lines)
