"""Warp's kernel optimization level on a CPU: the kernels' build time, their step time, same results.

    JAX_PLATFORMS=cpu python benchmarks/warp_cpu_compile.py env=hopper levels=0,2 repeats=2

MuJoCo Warp builds its kernels on their first launch, at the level ``warp.config.optimization_level``
holds (None: Warp's own, 2 on a CPU, which the package and its tests keep). For each level in
``levels`` a fresh process, with an empty Warp kernel cache and no JAX compilation cache, sets
it, makes the env on MuJoCo Warp for ``worlds`` worlds and calls one jitted program twice:
the worlds' resets, then ``steps`` batched steps under fixed random controls. The first call
builds every kernel the step launches and compiles XLA's program; the second times the steps
alone. It appends both seconds and a checksum of the last observations (equal checksums: the
same numbers) to ``results/warp_cpu_compile.jsonl``. Whether the tests, which build far more
than they step, should build at 0: ``benchmarks/NOTES.md``.
"""

from __future__ import annotations

import dataclasses
import json
import os
import tempfile
import time

from admissable_jax.cli import parse_args
from admissable_jax.envs import canonical_env_name
from common import append_record, measured_in_fresh_process, run_benchmark

LEVELS = ("0", "1", "2", "3")


@dataclasses.dataclass
class WarpCpuCompileConfig:
    env: str = dataclasses.field(default="hopper", metadata={"help": "the env (hopper, walker2d, ant, halfcheetah)"})
    levels: str = dataclasses.field(default="0,2", metadata={"help": "comma list of Warp optimization levels (0-3; 2 is "
                                                                      "Warp's own on a CPU)"})
    repeats: int = dataclasses.field(default=1, metadata={"help": "fresh processes per level"})
    worlds: int = dataclasses.field(default=4, metadata={"help": "worlds stepped at once"})
    steps: int = dataclasses.field(default=50, metadata={"help": "batched steps per call"})


def _validate(bench: WarpCpuCompileConfig) -> None:
    canonical_env_name(bench.env)
    if not set(bench.levels.split(",")) <= set(LEVELS):
        raise ValueError(f"levels must be a comma list of {', '.join(LEVELS)}, got {bench.levels!r}")
    if min(bench.repeats, bench.worlds, bench.steps) < 1:
        raise ValueError("repeats, worlds and steps must be >= 1")


def _measure_in_this_process(env_name: str, level: int, worlds: int, steps: int) -> dict:
    """Build and step the env here at Warp's optimization ``level`` (the empty caches set by the parent)."""
    import jax
    import numpy as np
    import warp

    from admissable_jax import make_env

    warp.config.optimization_level = level
    env = make_env(env_name, physics="warp", max_batch=worlds)
    actions = jax.random.uniform(jax.random.key(1), (worlds, env.action_size), minval=env.action_low,
                                 maxval=env.action_high)

    def resets_and_steps(keys):
        def step(states, _):
            return jax.vmap(env.step)(states, actions), None

        return jax.lax.scan(step, jax.vmap(env.reset)(keys), None, length=steps)[0].obs

    program, keys = jax.jit(resets_and_steps), jax.random.split(jax.random.key(0), worlds)
    start = time.perf_counter()
    jax.block_until_ready(program(keys))
    first_call_s = time.perf_counter() - start
    start = time.perf_counter()
    obs = jax.block_until_ready(program(keys))
    steps_s = time.perf_counter() - start
    return {"first_call_s": round(first_call_s, 2), "steps_s": round(steps_s, 2),
            "checksum": float(np.abs(np.asarray(obs)).sum())}


def main(argv: list[str]) -> None:
    if argv[:1] == ["--child"]:
        print(json.dumps(_measure_in_this_process(argv[1], *map(int, argv[2:5]))))
        return
    bench = parse_args(WarpCpuCompileConfig, argv, "benchmarks/warp_cpu_compile.py", __doc__.strip().splitlines()[0],
                       _validate)
    for repeat in range(bench.repeats):
        for level in bench.levels.split(","):
            with tempfile.TemporaryDirectory() as kernel_cache:
                measured = measured_in_fresh_process(__file__, [bench.env, level, str(bench.worlds), str(bench.steps)],
                                                     {"WARP_CACHE_PATH": kernel_cache})
            record = {"env": bench.env, "level": int(level), "repeat": repeat, "worlds": bench.worlds,
                      "steps": bench.steps, "xla_flags": os.environ.get("XLA_FLAGS", ""), **measured}
            append_record("warp_cpu_compile", record)
            print(json.dumps(record))


if __name__ == "__main__":
    run_benchmark(main)
