"""How far a physics setting moves our env from Gymnasium's, and how much faster it runs.

    python benchmarks/physics_deviation.py env=hopper solver_iterations=4 ls_iterations=8
    python benchmarks/physics_deviation.py env=ant physics=warp

Steps ``transitions`` Gymnasium-visited states once with the given solver setting (the
parity check of tests/test_envs.py) and reports the largest observation and reward errors
and termination mismatches, then times a batched random rollout. Appends a record to
benchmarks/results/physics_deviation.jsonl. With no overrides it measures the default
(the XML's settings), for reference.
"""

from __future__ import annotations

import dataclasses
import time

import jax
import numpy as np

from admissable_jax.cli import check_at_least_one, parse_args
from admissable_jax.envs import make_env
from admissable_jax.envs.parity import gymnasium_transitions, step_from_states
from admissable_jax.rollout import random_rollout
from common import append_record, run_benchmark


@dataclasses.dataclass
class DeviationConfig:
    env: str = dataclasses.field(default="hopper", metadata={"help": "hopper, walker2d or ant"})
    solver_iterations: int = dataclasses.field(default=0, metadata={"help": "0 = the XML's (100)"})
    ls_iterations: int = dataclasses.field(default=0, metadata={"help": "0 = the XML's (50)"})
    transitions: int = dataclasses.field(default=200, metadata={"help": "Gymnasium transitions compared"})
    num_envs: int = dataclasses.field(default=64, metadata={"help": "batch of the timed rollout"})
    steps: int = dataclasses.field(default=50, metadata={"help": "steps of the timed rollout"})
    physics: str = dataclasses.field(default="auto", metadata={"help": "auto | jax | warp (the env's physics backend)"})


def _validate(bench: DeviationConfig) -> None:
    check_at_least_one(bench, ("transitions", "num_envs", "steps"))


def main(argv: list[str]) -> None:
    bench = parse_args(DeviationConfig, argv, "benchmarks/physics_deviation.py", __doc__.splitlines()[0], _validate)
    env = make_env(bench.env, solver_iterations=bench.solver_iterations or None, ls_iterations=bench.ls_iterations or None,
                   physics=bench.physics, max_batch=max(bench.transitions, bench.num_envs))
    gym = gymnasium_transitions(env.gymnasium_id, bench.transitions)
    ours = step_from_states(env, gym["qpos"], gym["qvel"], gym["action"], np.zeros(bench.transitions, np.int32))
    obs_error = np.abs(np.asarray(ours.obs) - gym["obs"])
    reward_error = np.abs(np.asarray(ours.reward) - gym["reward"])
    mismatches = int((np.asarray(ours.terminated) != gym["terminated"]).sum())

    rollout = jax.jit(random_rollout, static_argnums=(0, 1, 2))
    rng = jax.random.key(0)
    compiled = rollout.lower(env, bench.num_envs, bench.steps, rng).compile()
    start = time.perf_counter()
    jax.block_until_ready(compiled(rng))
    steps_per_s = bench.num_envs * bench.steps / (time.perf_counter() - start)

    record = {
        "env": env.gymnasium_id, "physics": env.physics_name, "solver_iterations": int(env.mj_model.opt.iterations),
        "ls_iterations": int(env.mj_model.opt.ls_iterations), "transitions": bench.transitions,
        "obs_max_error": float(obs_error.max()), "obs_p99_error": float(np.quantile(obs_error.max(1), 0.99)),
        "reward_max_error": float(reward_error.max()), "termination_mismatches": mismatches,
        "rollout_num_envs": bench.num_envs, "rollout_env_steps_per_s": round(steps_per_s, 1),
    }
    print(
        f"{env.gymnasium_id} ({env.physics_name} physics), solver {record['solver_iterations']}/{record['ls_iterations']}: "
        f"obs max error {record['obs_max_error']:.2e}, reward max error {record['reward_max_error']:.2e}, "
        f"{mismatches} termination mismatches in {bench.transitions}; {steps_per_s:,.0f} env steps/s "
        f"(random rollout, {bench.num_envs} envs)"
    )
    append_record("physics_deviation", record)


if __name__ == "__main__":
    run_benchmark(main)
