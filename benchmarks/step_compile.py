"""Compile time of one batched physics step on the JAX backend: ``mjx.step`` against ours.

    python benchmarks/step_compile.py envs=hopper,walker2d,ant batch=8 steps=20

All three envs integrate with RK4. ``mjx.step`` unrolls RK4's last three stages, so its
compiled step holds four copies of ``mjx.forward``; ours (``Physics``'s step on the JAX
backend) runs the four stages as one scan with one copy (``envs/physics.py``). For each env
this compiles ``vmap`` of one ``mj_step`` both ways (fresh processes share nothing: no
compilation cache is enabled here), steps both ``steps`` times from the same states under
the same random controls, and appends the compile times and the largest differences to
``benchmarks/results/step_compile.jsonl``.
"""

from __future__ import annotations

import dataclasses
import time

import jax
import numpy as np
from mujoco import mjx

from admissable_jax.cli import parse_args
from admissable_jax.envs import canonical_env_name, make_env
from common import append_record, run_benchmark


@dataclasses.dataclass
class StepCompileConfig:
    envs: str = dataclasses.field(default="hopper,walker2d,ant", metadata={"help": "comma-separated envs"})
    batch: int = dataclasses.field(default=8, metadata={"help": "worlds stepped at once"})
    steps: int = dataclasses.field(default=20, metadata={"help": "steps compared after compiling"})


def _validate(bench: StepCompileConfig) -> None:
    for name in bench.envs.split(","):
        canonical_env_name(name.strip())
    if bench.batch < 1 or bench.steps < 1:
        raise ValueError("batch and steps must be >= 1")


def measure(name: str, batch: int, steps: int) -> dict:
    env = make_env(name, physics="jax", max_batch=batch)
    physics = env.physics
    data = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(0), batch)).data
    ctrl = jax.random.uniform(jax.random.key(1), (batch, env.action_size), minval=env.action_low,
                              maxval=env.action_high)
    steppers = {"mjx_step": lambda d, c: mjx.step(physics.model, d.replace(ctrl=c)),
                "ours": lambda d, c: physics._mj_step(d.replace(ctrl=c))}  # pylint: disable=protected-access
    record, finals = {"env": env.gymnasium_id, "batch": batch, "steps": steps}, {}
    for label, step in steppers.items():
        start = time.perf_counter()
        compiled = jax.jit(jax.vmap(step)).lower(data, ctrl).compile()
        record[f"compile_s_{label}"] = round(time.perf_counter() - start, 2)
        state = data
        for _ in range(steps):
            state = compiled(state, ctrl)
        finals[label] = state
    for field in ("qpos", "qvel"):
        difference = np.abs(np.asarray(getattr(finals["ours"], field)) - np.asarray(getattr(finals["mjx_step"], field)))
        record[f"max_abs_diff_{field}"] = float(difference.max())
    return record


def main(argv: list[str]) -> None:
    bench = parse_args(StepCompileConfig, argv, "benchmarks/step_compile.py", __doc__.strip().splitlines()[0], _validate)
    for name in bench.envs.split(","):
        record = measure(name.strip(), bench.batch, bench.steps)
        path = append_record("step_compile", record)
        print(f"{record['env']}: compile mjx.step {record['compile_s_mjx_step']} s, ours {record['compile_s_ours']} s; "
              f"after {bench.steps} steps max |dqpos| {record['max_abs_diff_qpos']:.1e}, "
              f"|dqvel| {record['max_abs_diff_qvel']:.1e} ({path})")


if __name__ == "__main__":
    run_benchmark(main)
