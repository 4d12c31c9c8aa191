"""Shared by the benchmark scripts: the machine/version record and result files."""

from __future__ import annotations

import datetime
import json
import os
import platform
import resource
import subprocess
import sys
import time
from typing import Any, Callable

import jax
import mujoco

from admissable_jax.cli import exit_with, run_from_cli
from admissable_jax.provenance import package_versions, source_commit

# Where records go: benchmarks/results, or BENCHMARK_RESULTS_DIR (the campaign's smoke runs).
COMMITTED_RESULTS_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")
RESULTS_DIR = os.environ.get("BENCHMARK_RESULTS_DIR") or COMMITTED_RESULTS_DIR


def benchmark_commit() -> str:
    """The commit of the code that writes a benchmark record, ``+changes`` where it differs:
    the records and runs under benchmarks/results do not count (appending one, or redrawing a
    tracked figure, must not mark the next)."""
    return source_commit(exclude=("benchmarks/results",)) or "unknown"


def environment_record() -> dict:
    """Machine, device and library versions, for every result record."""
    device = jax.devices()[0]
    return {
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "machine": platform.node(),
        "cpu_count": os.cpu_count(),
        "platform": platform.platform(),
        "device": f"{device.platform}:{getattr(device, 'device_kind', '')}",
        "python": platform.python_version(),
        "jax": jax.__version__,
        "mujoco": mujoco.__version__,
        "warp": package_versions().get("warp-lang"),
        "command": " ".join([os.path.basename(sys.executable), *sys.argv]),
        "commit": benchmark_commit(),
    }


def timed(function: Callable, *args) -> tuple[Any, float]:
    """(``function(*args)`` once its arrays are ready, the seconds that took)."""
    start = time.perf_counter()
    out = jax.block_until_ready(function(*args))
    return out, time.perf_counter() - start


def peak_host_memory_mb() -> float:
    """Peak resident memory of this process (Linux reports kilobytes)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def append_record(name: str, record: dict) -> str:
    """Append one JSON line to ``<RESULTS_DIR>/<name>.jsonl``; returns the path."""
    os.makedirs(RESULTS_DIR, exist_ok=True)
    path = os.path.join(RESULTS_DIR, f"{name}.jsonl")
    with open(path, "a") as file:
        file.write(json.dumps({**environment_record(), **record}) + "\n")
    return path


def measured_in_fresh_process(script: str, args: list[str], environment: dict[str, str]) -> dict:
    """The JSON object ``script --child ARGS`` prints last, run in a fresh Python process on the
    CPU with ``environment`` added and no JAX compilation cache: compile times from scratch."""
    env = {**os.environ, "JAX_PLATFORMS": "cpu", **environment}
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    child = subprocess.run([sys.executable, script, "--child", *args], env=env, capture_output=True, text=True,
                           check=True)
    return json.loads(child.stdout.strip().splitlines()[-1])


def update_flops(update: Callable, state: Any, batch: Any) -> float:
    """XLA's FLOP count of one ``update(state, batch, key)``."""
    return float(jax.jit(update).lower(state, batch, jax.random.key(0)).compile().cost_analysis()["flops"])


def compiled_updates(update: Callable, state: Any, batch: Any, count: int) -> Callable[[], Any]:
    """A function that runs ``count`` updates ``update(state, batch, key) -> state`` (a scan,
    from ``state``, on the fixed ``batch``) and waits for them; compiled and run once here,
    so timing it times the updates alone."""
    many = jax.jit(lambda state, key: jax.lax.scan(
        lambda s, k: (update(s, batch, k), None), state, jax.random.split(key, count))[0])
    jax.block_until_ready(many(state, jax.random.key(1)))
    return lambda: jax.block_until_ready(many(state, jax.random.key(2)))


def run_benchmark(main: Callable[[list[str]], int | None]) -> None:
    """Run a benchmark's ``main`` on the command line's arguments as the package runs its
    commands (``run_from_cli``): bad input found past the keys' parsing (a bad value, a
    missing run directory) ends it with one line and exit status 2, not a traceback; the
    records it appended before stay."""
    result, status = run_from_cli(main, sys.argv[1:], interrupted="interrupted; the records appended so far stay")
    exit_with(status or result or 0)
