"""XLA:CPU settings on our programs: compile time, run time, same results.

    JAX_PLATFORMS=cpu python benchmarks/xla_cpu_compile.py programs=hopper,ant,point_mass repeats=2
    JAX_PLATFORMS=cpu python benchmarks/xla_cpu_compile.py programs=hopper,point_mass \
        'flag_sets=--xla_cpu_use_fusion_emitters=false|--xla_cpu_use_fusion_emitters=false --xla_backend_optimization_level=0'

``admissable_jax`` sets ``--xla_cpu_use_fusion_emitters=false`` (its ``__init__``) unless
XLA_FLAGS says otherwise; tests/conftest.py also lowers LLVM's optimisation level, since tests
compile far more than they run. For each program and each XLA_FLAGS setting of ``flag_sets``
(``|``-separated; the default compares the fusion emitters off and on, ``true`` being XLA's
default), a fresh process (XLA reads its flags once per process; no compilation cache)
compiles and runs it:

- ``hopper``, ``ant``: the parity program of tests/test_envs.py on the JAX backend: 4,096
  resets and 120 batched steps from Gymnasium's states, in one jit;
- ``point_mass``: tests/test_training.py's 6,000-step SAC run through ``train_fn`` (its
  compiles, its training and scoring).

It appends one record per (program, setting, repeat) to ``results/xla_cpu_compile.jsonl``
with the compile and run seconds and a checksum of the outputs (equal checksums: the same
numbers; close ones: float32 round-off).
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
import tempfile
import time

from admissable_jax.cli import parse_args
from common import append_record, measured_in_fresh_process, run_benchmark

PROGRAMS = ("hopper", "walker2d", "ant", "point_mass")
FLAG = "--xla_cpu_use_fusion_emitters"


@dataclasses.dataclass
class XlaCpuCompileConfig:
    programs: str = dataclasses.field(default="hopper,ant,point_mass", metadata={"help": f"comma list of {', '.join(PROGRAMS)}"})
    repeats: int = dataclasses.field(default=2, metadata={"help": "fresh processes per program and setting"})
    flag_sets: str = dataclasses.field(default=f"{FLAG}=false|{FLAG}=true",
                                       metadata={"help": "XLA_FLAGS settings to compare, separated by |"})


def _settings(bench: XlaCpuCompileConfig) -> list[str]:
    """The XLA_FLAGS settings ``flag_sets`` lists."""
    return [setting.strip() for setting in bench.flag_sets.split("|")]


def _validate(bench: XlaCpuCompileConfig) -> None:
    unknown = set(bench.programs.split(",")) - set(PROGRAMS)
    if unknown or bench.repeats < 1:
        raise ValueError(f"programs must be a comma list of {', '.join(PROGRAMS)} and repeats >= 1")
    if not all(_settings(bench)):
        raise ValueError("flag_sets must be XLA_FLAGS settings separated by |, none empty")


def _measure_in_this_process(program: str) -> dict:
    """Compile and run ``program`` here (XLA_FLAGS already set by the parent)."""
    import functools

    import jax
    import numpy as np

    if program == "point_mass":
        sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))
        from test_training import POINT_MASS

        from admissable_jax import train_fn

        start = time.perf_counter()
        result = train_fn(dataclasses.replace(POINT_MASS, logger="none", out=tempfile.mkdtemp() + "/run"))
        return {"total_s": round(time.perf_counter() - start, 2),
                "checksum": float(sum(row["clean_score"] for row in result.scores))}

    from admissable_jax import make_env
    from admissable_jax.envs.parity import gymnasium_transitions, step_from_state

    env = make_env(program, physics="jax", max_batch=4096)
    gym = gymnasium_transitions(env.gymnasium_id, 120)
    counts = np.zeros(120, np.int32)

    def resets_and_steps(keys, qpos, qvel, action, step_counts):
        step = jax.vmap(functools.partial(step_from_state, env))
        return jax.vmap(env.reset)(keys), step(qpos, qvel, action, step_counts)

    args = (jax.random.split(jax.random.key(0), 4096), gym["qpos"], gym["qvel"], gym["action"], counts)
    start = time.perf_counter()
    lowered = jax.jit(resets_and_steps).lower(*args)
    lower_s = time.perf_counter() - start
    start = time.perf_counter()
    compiled = lowered.compile()
    compile_s = time.perf_counter() - start
    jax.block_until_ready(compiled(*args))  # the first call pays one-off set-up
    start = time.perf_counter()
    resets, steps = jax.block_until_ready(compiled(*args))
    run_s = time.perf_counter() - start
    return {"lower_s": round(lower_s, 2), "compile_s": round(compile_s, 2), "run_s": round(run_s, 3),
            "checksum": float(np.abs(np.asarray(steps.obs)).sum() + np.abs(np.asarray(resets.obs)).sum())}


def main(argv: list[str]) -> None:
    if argv[:1] == ["--child"]:
        print(json.dumps(_measure_in_this_process(argv[1])))
        return
    bench = parse_args(XlaCpuCompileConfig, argv, "benchmarks/xla_cpu_compile.py", __doc__.strip().splitlines()[0], _validate)
    for program in bench.programs.split(","):
        for repeat in range(bench.repeats):
            for flags in _settings(bench):
                measured = measured_in_fresh_process(__file__, [program], {"XLA_FLAGS": flags})
                record = {"program": program, "xla_flags": flags, "repeat": repeat, **measured}
                append_record("xla_cpu_compile", record)
                print(json.dumps(record))


if __name__ == "__main__":
    run_benchmark(main)
