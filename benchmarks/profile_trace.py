"""Where a program's device time goes, from a JAX profiler trace (``campaign.py profile``).

``jax.profiler.trace(folder)`` writes the run's XSpace (``*.xplane.pb``), which
``jax.profiler.ProfileData`` reads whole (the Perfetto JSON it can also write keeps only a
million events: a CPU training chunk of Hopper fills that). Within each annotated part of
the run (``jax.profiler.TraceAnnotation``) this sums the device's ops: how long the device
was busy (the union of its ops' intervals, over every stream), how many ops it ran per
step of the part, and which op kinds and which scopes of ours cost most (shares of the
ops' summed time, which exceeds the busy time where streams or threads overlap). On a GPU
the ops are the kernels and copies on the ``/device:GPU:N`` planes' stream lines. A latency-bound program shows as wall time
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
# Name-stack segments that JAX's transformations add, once unwrapped (WRAPPER: a scope entered
# under a transformation carries it around its name); the others are named scopes (ours
# below, Flax's modules, MJX's functions), and the last segment of an op's name is its primitive.
WRAPPER = re.compile(r"^(?:vmap|pmap|transpose|jvp)\((.*)\)$")
TRANSFORMATION = re.compile(r"^(\w*jit\(.*\)|while|body|cond|closed_call|branch_\d+_fun|checkpoint|remat|custom_jvp_call|"
                            r"custom_vjp_call|shard_map)$")
# The scopes admissable_jax's programs name (training.Trainer.iteration and the scoring
# rollout's step): an op is counted under the longest of these its name stack starts with.
OUR_SCOPES = ("act", "env_step", "replay_insert", "episode_starts", "learn", "learn/minibatches", "learn/updates",
              "score_policy", "score_env_step")
SOURCE_KINDS = 3  # the op kinds listed per source: the ones it runs most often
NOT_LAUNCHED_BY_XLA = "(kernels that name no HLO op: a library's, such as MuJoCo Warp's)"
NO_SOURCE = "(no JAX source: ops XLA added where nothing names one)"
UNSCOPED = "(outside our scopes: the loops' own bookkeeping)"


@dataclasses.dataclass(frozen=True)
class Op:
    track: str  # plane/line
    kind: str  # its HLO op (or kernel name), numbering dropped
    start_us: float
    end_us: float
    hlo_op: str | None = None  # the HLO instruction it ran, where the trace names one


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
        return "no device ops in the trace (a GPU's are traced through NVIDIA's CUPTI library)", []
    return "XLA:CPU worker threads", leaves(ops)


def _op(track: str, event: Any) -> Op:
    hlo_op = _stat(event, "hlo_op")
    hlo_op = None if hlo_op is None else str(hlo_op)
    return Op(track, NUMBERED.sub("", hlo_op or event.name), event.start_ns / 1e3,
              (event.start_ns + event.duration_ns) / 1e3, hlo_op)


def op_sources(hlo_text: str) -> dict[str, str]:
    """Each instruction of a compiled program's HLO (``compiled.as_text()``) by the scope of
    ours its metadata's name stack starts with (``OUR_SCOPES``). Ops that XLA added or rewrote
    without a name (copies, reduce-windows) count under the source most common in the
    computation they sit in (a solver's loop body: ``env_step``). A program
    from JAX's persistent cache keeps the names of the code that compiled it: metadata is
    not part of the cache key."""
    members: dict[str, list[tuple[str, str | None]]] = collections.defaultdict(list)
    computation = ""
    for line in hlo_text.splitlines():
        header = re.match(r"^(?:ENTRY )?%?([\w.\-]+) .*\{$", line)
        if header:
            computation = header.group(1)
            continue
        instruction = re.match(r"^\s+(?:ROOT )?%?([\w.\-]+) = ", line)
        if instruction:
            op_name = re.search(r'op_name="([^"]*)"', line)
            members[computation].append((instruction.group(1), op_name and _scope(op_name.group(1))))
    sources = {}
    for instructions in members.values():
        named = collections.Counter(source for _, source in instructions if source)
        fallback = named.most_common(1)[0][0] if named else NO_SOURCE
        sources.update((name, source or fallback) for name, source in instructions)
    return sources


def _unwrapped(segment: str) -> str:
    """A name-stack segment without the transformations wrapped around it: a scope entered
    inside ``jax.vmap`` reads ``vmap(score_env_step)``, a gradient's ``transpose(jvp(Actor))``."""
    while wrapped := WRAPPER.match(segment):
        segment = wrapped.group(1)
    return segment


def _scope(op_name: str) -> str:
    """The longest scope of ours that an op's name stack (transformations left out) starts with."""
    segments = (_unwrapped(segment) for segment in op_name.split("/")[:-1])
    path = "/".join(segment for segment in segments if segment and not TRANSFORMATION.match(segment))
    ours = [scope for scope in OUR_SCOPES if path == scope or path.startswith(scope + "/")]
    return max(ours, key=len) if ours else UNSCOPED


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


def summarize_part(ops: list[Op], name: str, window: tuple[float, float], steps: int, top: int,
                   sources: dict[str, str] | None = None) -> dict:
    """The ops that ran within ``window`` (clipped to it), the part ``name`` of ``steps``
    sequential steps (loop steps of a scoring round, iterations of a training chunk); with
    the program's ``sources`` (:func:`op_sources`), also its device time by JAX source."""
    start, end = window
    inside = [(max(op.start_us, start), min(op.end_us, end), op) for op in ops if op.start_us < end and op.end_us > start]
    busy = busy_us([(a, b) for a, b, _ in inside])
    kinds: dict[str, list] = collections.defaultdict(lambda: [0.0, 0])
    by_source: dict[str, list] = collections.defaultdict(lambda: [0.0, 0])
    source_kinds: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
    for a, b, op in inside:
        kinds[op.kind][0] += b - a
        kinds[op.kind][1] += 1
        source = NOT_LAUNCHED_BY_XLA if op.hlo_op is None else (sources or {}).get(op.hlo_op, NO_SOURCE)
        by_source[source][0] += b - a
        by_source[source][1] += 1
        source_kinds[source][op.kind] += 1
    wall, summed = end - start, sum(b - a for a, b, _ in inside)
    return {
        "part": name, "steps": steps, "wall_ms": round(wall / 1e3, 3), "busy_ms": round(busy / 1e3, 3),
        "busy_share": round(busy / wall, 4) if wall else 0.0, "ops": len(inside),
        "ops_per_step": round(len(inside) / steps, 1), "busy_us_per_step": round(busy / steps, 1),
        "idle_us_per_step": round((wall - busy) / steps, 1),
        "costliest": [{"op": kind, "ms": round(us / 1e3, 3), "share": round(us / summed, 4) if summed else 0.0,
                       "count": count} for kind, (us, count) in sorted(kinds.items(), key=lambda item: -item[1][0])[:top]],
        "by_source": [] if sources is None else [
            {"source": source, "ms": round(us / 1e3, 3), "share": round(us / summed, 4) if summed else 0.0,
             "ops_per_step": round(count / steps, 1),
             "most_run": [{"op": kind, "per_step": round(n / steps, 1)} for kind, n in source_kinds[source].most_common(SOURCE_KINDS)]}
            for source, (us, count) in sorted(by_source.items(), key=lambda item: -item[1][0])],
    }


def names_our_scopes(parts: list[dict]) -> bool:
    """Whether any op of these parts ran in a scope of ours: not when the programs came from
    a persistent cache that code without those scopes filled (metadata is no part of its key)."""
    return any(row["source"] in OUR_SCOPES for part in parts for row in part["by_source"])


def _most_run(source_row: dict) -> str:
    return ", ".join(f"{kind['per_step']:,.1f} {kind['op']}" for kind in source_row["most_run"])


def describe(part: dict) -> str:
    """A part's summary in lines, for the log."""
    lines = [f"{part['part']}: wall {part['wall_ms']:,.1f} ms, device busy {part['busy_ms']:,.1f} ms "
             f"({part['busy_share']:.0%}); {part['ops']:,} ops = {part['ops_per_step']:,.1f} per step over "
             f"{part['steps']:,} steps; per step {part['busy_us_per_step']:,.1f} µs busy, "
             f"{part['idle_us_per_step']:,.1f} µs idle"]
    lines.append("  costliest op kinds (ms, share of the ops' summed time, count):")
    lines += [f"  {row['ms']:10,.2f} ms {row['share']:6.1%} {row['count']:9,}x  {row['op']}" for row in part["costliest"]]
    if part["by_source"]:
        lines.append("  by JAX source (ms, share of the ops' summed time, ops per step; its most run op kinds per step):")
        lines += [f"  {row['ms']:10,.2f} ms {row['share']:6.1%} {row['ops_per_step']:9,.1f}   {row['source']}"
                  f"    ({_most_run(row)})"
                  for row in part["by_source"]]
    return "\n".join(lines)
